"""`solve_with_fallback`: try the equilibrium methods in turn before reporting a failure.

No method solves every scene: dynamic relaxation (kinetic damping) can cycle
where the force is not the gradient of an energy or the skin is slack, and
Newton's load continuation can stall where relaxation converges. The
``"auto"`` chain (`CHAINS`) is

1. the requested first method ("relax", or "relax+newton" in the design
   loop, warm-started there from the previous iterate), which ends early
   with ``stalled`` when its residual stops falling (`relax`);
2. "newton" from where the relaxation stopped, when that shape is finite
   and inside the divergence bound (a stalled relaxation is often near the
   equilibrium: Newton's quadratic convergence finishes it);
3. "newton" from the mounted shape, with its load continuation.

The first converged `Solution` is returned, its ``extra["attempts"]`` the
list of ``(method, result, steps, residual)`` tried. When every method fails
the returned (or raised) solution is the one with the least residual, and
its ``detail`` names every method tried with its result, then what to change.
Measured (17x64, 2-core x86_64): NACA 0006 bay, 323 Pa, prestrain 4%/3%,
fabric 2e4/3e5 N/m: relax stalls after 11,000 steps, Newton converges in 30
iterations; before the early stop relax ran its 200,000-step cap first.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .solution import ConvergenceError, Result, Solution
from .solve import METHODS, solve_equilibrium

__all__ = ["solve_with_fallback", "CHAINS", "EQUILIBRIUM_METHODS"]

#: What each ``method`` of `solve_with_fallback` tries, in order. "newton@start" is Newton from
#: where the previous attempt stopped (skipped when that shape diverged or is not finite).
CHAINS = {
    "auto": ("relax", "newton@start", "newton"),
    "auto-design": ("relax+newton", "newton@start", "newton"),
    "relax": ("relax",),
    "newton": ("newton",),
    "relax+newton": ("relax+newton",),
}
#: The methods a user may name (command line, case file, ``solver_options``).
EQUILIBRIUM_METHODS = ("auto", "relax", "newton", "relax+newton")

_WHAT_TO_CHANGE = (
    "check the input (a slack fabric, i.e. negative prestrain, has no taut equilibrium; a pressure "
    "far beyond the fabric's strength inflates without bound); else raise max_steps or loosen rtol")


def solve_with_fallback(scene, parameters, *, method: str = "auto", initial=None,
                        throw: bool = True, max_steps: int = 200_000, **options) -> Solution:
    """`solve_equilibrium` by each method of ``CHAINS[method]`` until one converges.

    Args:
        scene, parameters: as for `solve_equilibrium`.
        method: a key of `CHAINS`: "auto" (default), "auto-design" (the
            design loop's: relax+newton first, for its LU factor), or one
            method alone.
        initial: warm start of the first attempt (a `Solution` or nodes);
            a warm first attempt that fails is retried cold before the next
            method.
        throw: raise `ConvergenceError` when every method fails; else return
            the least-residual failure.
        max_steps: step cap of each relaxation.
        **options: passed to every `solve_equilibrium` call (rtol,
            sequencing, ...).

    Returns:
        The first converged `Solution` (``extra["attempts"]`` lists the
        tries), or the best failure, whose ``detail`` names them all.
    """
    if method not in CHAINS:
        raise ValueError(f"equilibrium method must be one of {EQUILIBRIUM_METHODS}, got {method!r}")
    attempts, failures = [], []
    last = None
    for k, step in enumerate(CHAINS[method]):
        if step == "newton@start":
            if last is None or last.result in (Result.diverged, Result.nonfinite) \
                    or not np.isfinite(np.asarray(last.nodes)).all():
                continue
            tries = [("newton", last.nodes, f"newton from where {last.method} stopped")]
        else:
            tries = [(step, initial if k == 0 else None, step)]
            if k == 0 and initial is not None:
                tries.append((step, None, f"{step} from a cold start"))
        for name, start, label in tries:
            assert name in METHODS
            sol = solve_equilibrium(scene, parameters, method=name, initial=start, throw=False,
                                    max_steps=max_steps, **options)
            result = Result(int(np.asarray(sol.result)))
            attempts.append((label, result.name, int(sol.steps), float(sol.residual)))
            if sol.converged:
                return dataclasses.replace(sol, extra={**sol.extra, "attempts": attempts})
            failures.append(sol)
            last = sol
    best = min(failures, key=lambda s: float(s.residual) if np.isfinite(s.residual) else np.inf)
    tried = "; ".join(f"{label}: {name} after {steps} steps (residual {res:.2e})"
                      for label, name, steps, res in attempts)
    detail = f"every method failed ({tried}); {best.detail or _WHAT_TO_CHANGE}"
    best = dataclasses.replace(best, detail=detail, extra={**best.extra, "attempts": attempts})
    if throw:
        raise ConvergenceError(best)
    return best
