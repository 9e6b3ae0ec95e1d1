"""Floating-point precision: float64 without touching the caller's JAX, and the float32 rule.

The package computes in float64 (`float64_scope`). The explicit solvers
(relaxation and the paper's scheme) can iterate in float32 on request
(``precision="float32"``), under one rule:

* Their stop test evaluates the residual in float64 at the current nodes, so
  a float32 solve that reports "converged" returned a shape that meets the
  tolerance, and one that cannot get there ends ``max_steps_reached`` (or
  ``diverged``), never a false "converged".
* A tolerance below what float32 can reach is refused up front: rounding the
  coordinates to float32 alone leaves a residual of up to
  `forces.rounding_residual_floor` (with float32's machine epsilon), so
  ``rtol`` below that raises a ValueError that says to use float64 or a
  looser tolerance (`precision_extra`). The floors measured on the default
  bay, how close float32 shapes come to float64 ones and what a float32 step
  saves: docs/design_problem.md, "Precision and failures".

Newton's method and the implicit derivatives stay in float64 (sparse LU,
quadratic convergence, finite-difference checks).
"""

from __future__ import annotations

import threading
from contextlib import contextmanager
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from . import forces as fk

__all__ = ["FLOAT32_EPS", "PRECISIONS", "check_precision", "device_arrays", "float32_floor", "float64_scope",
           "precision_extra"]

#: The floating-point types an explicit solver's iteration may run in.
PRECISIONS = ("float64", "float32")

#: Relative rounding precision of a float32 coordinate (its machine epsilon).
FLOAT32_EPS = float(np.finfo(np.float32).eps)


@contextmanager
def float64_scope(*traced_inputs):
    """Run the enclosed JAX work with float64 available, without touching global config.

    The package never flips ``jax_enable_x64`` globally (importing it changes
    nothing for other JAX code). A concrete call enters the thread-local
    ``jax.enable_x64(True)`` context for its own duration. Under a caller's
    JAX transformation (``jax.grad``, ``jax.jit``) the caller's setting wins,
    and float64 must already be on.

    Raises:
        RuntimeError: when traced by a caller whose JAX runs in float32 mode.
    """
    if any(isinstance(v, jax.core.Tracer) for v in jax.tree_util.tree_leaves(traced_inputs)):
        if not jax.config.jax_enable_x64:
            raise RuntimeError("forward_solver computes in float64 but is being transformed by JAX in float32 "
                               "mode: call jax.config.update('jax_enable_x64', True) first, or wrap the "
                               "transformation in `with jax.enable_x64(True):`")
        yield
        return
    with jax.enable_x64(True):
        yield


def residual_rounding_floor(geometry, params, physics, eps):
    """`forces.rounding_residual_floor` of a bay at its reference state (`forces.prepare`): the relative
    residual that rounding its coordinates to machine epsilon ``eps`` alone leaves."""
    physics = fk.static_physics(physics)
    return fk.rounding_residual_floor(fk.prepare(geometry, params, physics), params, physics, eps)


rounding_floor = partial(jax.jit, static_argnames=("physics",))(residual_rounding_floor)


def float32_floor(geometry, params, physics) -> float:
    """`forces.rounding_residual_floor` for float32 coordinates (float64 inputs, in a float64 scope)."""
    return float(rounding_floor(geometry, params, physics, FLOAT32_EPS))


def check_precision(precision: str) -> None:
    """Refuse a precision not in `PRECISIONS`."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {sorted(PRECISIONS)}, got {precision!r}")


def precision_extra(precision: str, rtol: float, geometry, params, physics) -> dict:
    """The `Solution.extra` entries of a solve in ``precision``: ``{"precision": ...}``, plus
    ``"float32_floor"`` (`float32_floor`) for float32.

    Raises:
        ValueError: float32 with ``rtol`` below its floor, saying what to change.
    """
    extra = {"precision": precision}
    if precision == "float32":
        floor = float32_floor(geometry, params, physics)
        if rtol < floor:
            raise ValueError(f"precision='float32' cannot reach rtol={rtol:.2e} on this scene: rounding the "
                             f"coordinates to float32 alone leaves a relative residual of up to {floor:.2e} "
                             "(short edges on a fine grid and a stiff fabric under low pressure raise it); use "
                             f"precision='float64', or rtol >= {floor:.2e}")
        extra["float32_floor"] = floor
    return extra


#: Concrete values last sent by `device_arrays`, by their bytes: the solvers ask for the same
#: parameters over and over (a bay's Newton iterations, its tangents), about 0.45 ms a transfer.
#: Lists of at most `_SENT_BYTES` only (a bay's parameters are some hundred bytes; its geometry, which
#: grows with the grid, is kept by the bay itself), so the entries hold at most 16 MiB.
_SENT: dict = {}
_SENT_ENTRIES = 256
_SENT_BYTES = 65536
_SENT_LOCK = threading.Lock()


def device_arrays(values, dtype=None) -> list:
    """``[jnp.asarray(v, dtype=dtype) for v in values]``, concrete values in one transfer.

    Concrete values travel in one ``jax.device_put`` of the whole list
    instead of one transfer (and conversion) each (`Scene.params`,
    `Bay.geometry`); a warm re-solve of the default bay spent about a quarter
    of its 4 ms on them. Values all concrete and sent already (the same
    bytes, dtype and float64 setting: `_SENT`) are, outside ``jax.jit``, the
    arrays sent then (JAX arrays do not change): the 40-cell wing's design
    sent them some 2,400 times, 1.1 s of its threads' time. Traced values (under a JAX
    transformation) are converted each on its own, the concrete ones beside
    them still in one transfer.
    """
    traced = [isinstance(v, jax.core.Tracer) for v in values]
    hosted = [np.asarray(v, dtype=dtype) for v, t in zip(values, traced) if not t]
    if any(traced) or sum(a.nbytes for a in hosted) > _SENT_BYTES:
        concrete = iter(jax.device_put(hosted))
        return [_traced_as(v, dtype) if t else next(concrete) for v, t in zip(values, traced)]
    key = (jax.config.jax_enable_x64,) + tuple((a.dtype.str, a.shape, a.tobytes()) for a in hosted)
    sent = _SENT.get(key)
    if sent is not None and not isinstance(jax.device_put(np.int8(0)), jax.core.Tracer):  # (not within a jit)
        return list(sent)
    sent = jax.device_put(hosted)
    if not any(isinstance(a, jax.core.Tracer) for a in sent):  # (made within a jit: that trace's own)
        with _SENT_LOCK:
            if len(_SENT) >= _SENT_ENTRIES:
                _SENT.pop(next(iter(_SENT)), None)
            _SENT[key] = sent
    return list(sent)


def _traced_as(value, dtype):
    """``jnp.asarray(value, dtype=dtype)`` of a traced value; the value itself where it is of that type
    already and strongly typed (under an eager transformation, a conversion is an operation of its own,
    run for the primal and again for the tangents: six of them per bay in a design's linearisation)."""
    aval = jax.typeof(value)
    if (dtype is None or aval.dtype == np.dtype(dtype)) and not aval.weak_type:
        return value
    return jnp.asarray(value, dtype=dtype)
