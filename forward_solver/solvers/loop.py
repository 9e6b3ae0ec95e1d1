"""The one loop every explicit solver plugs into.

A `lax.while_loop` over chunks; each chunk is a `lax.scan` of ``chunk``
explicit steps, so the residual test costs one evaluation per chunk.

The steps are guarded every `GUARD_STEPS` steps: if a node has moved
further than ``divergence_bound`` (m) from its mounted position, or a
coordinate is NaN or infinite, the state goes back to the last guarded
state (which was inside the bound) and the run ends ``diverged`` (or
``nonfinite``). An unstable iteration crosses the bound (metres) while still
finite, so a blow-up returns finite nodes and the code that says what
happened, never NaN. Measured need: a relaxation whose masses were too
light went from a 1 m displacement to overflow in about eight steps (the
stiffness grows with the stretch, so the growth is faster than
exponential); guarding every step instead costs 4-7% of a step on the
default bay.

After each chunk the stop test runs on the static force residual (no
velocity terms):

* ``nonfinite`` if any coordinate or velocity is NaN or infinite,
* ``diverged`` if the step guard fired or a node moved further than
  ``divergence_bound`` from its mounted position,
* ``converged`` if ``||R_free||_2 / (p A) <= rtol`` and the kinetic test of
  the solver passes,
* ``stalled`` if the solver's ``give_up`` test says the residual stopped
  falling (a hopeless run ends early instead of spending its step cap),
* ``max_steps_reached`` once ``max_chunks`` chunks have run.

The solver supplies its step and tests as a `Stepper`; the state is any
pytree with ``x`` and ``v`` leaves (a NamedTuple).
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from ..solution import Result

__all__ = ["LoopOutput", "Stepper", "run_chunks", "GUARD_STEPS", "check_stop"]

#: Steps between two checks of the divergence guard (a chunk whose length is
#: not a multiple of it is guarded every ``gcd(chunk, GUARD_STEPS)`` steps).
GUARD_STEPS = 5


def check_stop(rtol=None, **counts) -> None:
    """Refuse an ``rtol`` outside (0, 1), and each of ``counts`` (``max_steps=...``) not a positive integer."""
    if rtol is not None and not (isinstance(rtol, float | int) and 0 < rtol < 1):
        raise ValueError(f"rtol must lie in (0, 1), got {rtol!r}")
    for name, value in counts.items():
        if not (isinstance(value, int) and value >= 1):
            raise ValueError(f"{name} must be a positive integer, got {value!r}")


class LoopOutput(NamedTuple):
    state: object
    result: jnp.ndarray  # int32 Result code
    chunks: jnp.ndarray  # chunks run
    residual: jnp.ndarray  # final relative residual
    history: object  # per-chunk records (leading axis max_chunks), rows past `chunks` are zero


class Stepper(NamedTuple):
    """What a solver plugs into the loop (`run_chunks`): its step and its tests.

    Attributes:
        step: one explicit step, ``state -> state``.
        relative_residual: ``x -> ||R_free|| / (p A)`` (static residual).
        at_rest: ``(state, residual) -> bool``, the solver's convergence test
            beside ``residual <= rtol``.
        begin_chunk: ``(state, residual) -> state`` run before each chunk with
            the relative residual after the previous one (inf before the
            first), e.g. to rescale fictitious masses, or None.
        give_up: ``(state, residual) -> bool`` after each chunk that has not
            converged: True ends the run ``stalled``; or None.
        record: ``state -> pytree of scalars`` recorded after every chunk
            (``max_chunks`` records), or None.
    """

    step: Callable
    relative_residual: Callable
    at_rest: Callable
    begin_chunk: Callable | None = None
    give_up: Callable | None = None
    record: Callable | None = None


def run_chunks(state, stepper: Stepper, x0: jnp.ndarray, rtol, divergence_bound, chunk: int,
               max_chunks: int) -> LoopOutput:
    """Run ``stepper.step`` in chunks until the state is at rest, fails, or hits the cap.

    Args:
        state: initial solver state (NamedTuple with fields ``x`` and ``v``).
        stepper: the solver's step and tests (`Stepper`).
        x0: mounted shape, for the divergence test.
        rtol: relative residual tolerance.
        divergence_bound: largest displacement (m) before ``diverged``.
        chunk: steps per chunk (static).
        max_chunks: chunk cap (static).
    """
    step, relative_residual, at_rest, begin_chunk, give_up, record = stepper
    dtype = jax.eval_shape(relative_residual, state.x).dtype  # float64 even for a float32 state
    history0 = None
    if record is not None:
        template = jax.eval_shape(record, state)
        history0 = jax.tree_util.tree_map(
            lambda s: jnp.zeros((max_chunks,) + s.shape, s.dtype), template
        )

    guard = math.gcd(chunk, GUARD_STEPS)

    def scan_body(s, _):
        return step(s), None

    def guarded_body(carry, _):
        s, stop = carry
        new, _ = jax.lax.scan(scan_body, s, None, length=guard)
        inside = jnp.all(jnp.abs(new.x - x0) <= divergence_bound)  # False for NaN too
        code = jnp.where(inside, -1,
                         jnp.where(jnp.all(jnp.isfinite(new.x)), Result.diverged, Result.nonfinite))
        take = (stop < 0) & (code < 0)
        s = jax.tree_util.tree_map(lambda a, b: jnp.where(take, a, b), new, s)
        return (s, jnp.where(stop < 0, code, stop).astype(jnp.int32)), None

    def cond(carry):
        _, code, k, _, _ = carry
        return (code < 0) & (k < max_chunks)

    def body(carry):
        s, _, k, last, hist = carry
        if begin_chunk is not None:
            s = begin_chunk(s, last)
        (s, stop), _ = jax.lax.scan(guarded_body, (s, jnp.int32(-1)), None, length=chunk // guard)
        res = relative_residual(s.x)
        finite = jnp.all(jnp.isfinite(s.x)) & jnp.all(jnp.isfinite(s.v)) & jnp.isfinite(res)
        moved = jnp.max(jnp.abs(s.x - x0))
        code = jnp.where(
            stop >= 0,
            stop,
            jnp.where(
                ~finite,
                Result.nonfinite,
                jnp.where(
                    moved > divergence_bound,
                    Result.diverged,
                    jnp.where((res <= rtol) & at_rest(s, res), Result.converged,
                              -1 if give_up is None else jnp.where(give_up(s, res), Result.stalled, -1)),
                ),
            ),
        ).astype(jnp.int32)
        if hist is not None:
            rec = record(s)
            hist = jax.tree_util.tree_map(lambda h, r: h.at[k].set(r), hist, rec)
        return s, code, k + 1, res, hist

    init = (state, jnp.int32(-1), jnp.int32(0), jnp.asarray(jnp.inf, dtype), history0)
    s, code, k, res, hist = jax.lax.while_loop(cond, body, init)
    code = jnp.where(code < 0, Result.max_steps_reached, code).astype(jnp.int32)
    return LoopOutput(s, code, k, res, hist)
