"""The one loop every explicit solver plugs into.

A `lax.while_loop` over chunks; each chunk is a `lax.scan` of ``chunk``
explicit steps, so loop control costs one check per chunk. After each chunk
the stop test runs on the static force residual (no velocity terms):

* ``nonfinite`` if any coordinate or velocity is NaN or infinite,
* ``diverged`` if a node moved further than ``divergence_bound`` (m) from
  its mounted position,
* ``converged`` if ``||R_free||_2 / (p A) <= rtol`` and the kinetic test of
  the solver passes,
* ``max_steps_reached`` once ``max_chunks`` chunks have run.

The solver supplies ``step(state) -> state`` and ``at_rest(state) -> bool``;
the state is any pytree with ``x`` and ``v`` leaves (a NamedTuple).
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from .solution import Result

__all__ = ["LoopOutput", "run_chunks"]


class LoopOutput(NamedTuple):
    state: object
    result: jnp.ndarray  # int32 Result code
    chunks: jnp.ndarray  # chunks run
    residual: jnp.ndarray  # final relative residual
    history: object  # per-chunk records (leading axis max_chunks), rows past `chunks` are zero


def run_chunks(
    state,
    step: Callable,
    relative_residual: Callable,
    at_rest: Callable,
    x0: jnp.ndarray,
    rtol,
    divergence_bound,
    chunk: int,
    max_chunks: int,
    record: Callable | None = None,
    n_record: int = 0,
    begin_chunk: Callable | None = None,
) -> LoopOutput:
    """Run ``step`` in chunks until the state is at rest, fails, or hits the cap.

    Args:
        state: initial solver state (NamedTuple with fields ``x`` and ``v``).
        step: one explicit step, ``state -> state``.
        relative_residual: ``x -> ||R_free|| / (p A)`` (static residual).
        at_rest: ``(state, residual) -> bool``, the solver's convergence test.
        x0: mounted shape, for the divergence test.
        rtol: relative residual tolerance.
        divergence_bound: largest displacement (m) before ``diverged``.
        chunk: steps per chunk (static).
        max_chunks: chunk cap (static).
        record: ``state -> pytree of scalars`` recorded after every chunk.
        n_record: number of records kept (static, ``max_chunks`` or 0).
        begin_chunk: ``(state, residual) -> state`` run before each chunk with
            the relative residual after the previous one (inf before the
            first), e.g. to rescale fictitious masses, or None.
    """
    dtype = x0.dtype
    history0 = None
    if record is not None:
        template = jax.eval_shape(record, state)
        history0 = jax.tree_util.tree_map(
            lambda s: jnp.zeros((n_record,) + s.shape, s.dtype), template
        )

    def scan_body(s, _):
        return step(s), None

    def cond(carry):
        _, code, k, _, _ = carry
        return (code < 0) & (k < max_chunks)

    def body(carry):
        s, _, k, last, hist = carry
        if begin_chunk is not None:
            s = begin_chunk(s, last)
        s, _ = jax.lax.scan(scan_body, s, None, length=chunk)
        res = relative_residual(s.x)
        finite = jnp.all(jnp.isfinite(s.x)) & jnp.all(jnp.isfinite(s.v)) & jnp.isfinite(res)
        moved = jnp.max(jnp.abs(s.x - x0))
        code = jnp.where(
            ~finite,
            Result.nonfinite,
            jnp.where(
                moved > divergence_bound,
                Result.diverged,
                jnp.where((res <= rtol) & at_rest(s, res), Result.converged, -1),
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
