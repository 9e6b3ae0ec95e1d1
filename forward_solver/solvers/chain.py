"""The ``"auto"`` method of `solve_equilibrium`: try the methods in turn before reporting a failure.

No method solves every scene: dynamic relaxation (kinetic damping) can cycle
where the force is not the gradient of an energy or the skin is slack, and
Newton's load continuation can stall where relaxation converges. The
``"auto"`` chain (`AUTO_CHAIN`) is

1. "relax+newton": relaxation (which ends early with ``stalled`` when its
   residual stops falling, see `relax`) handing over to Newton, whose LU
   factor the adjoint reuses; warm-started from ``initial`` if given, and
   then retried from a cold start if that fails;
2. "newton" from where the relaxation stopped, when that shape did not
   diverge (a stalled relaxation is often near the equilibrium: Newton's
   quadratic convergence finishes it);
3. "newton" from the mounted shape, with its load continuation.

The first converged `Solution` is returned, its ``extra["attempts"]`` the
list of ``(how, result, steps, residual)`` tried. When every method fails
the returned solution is the one with the least residual, and its
``detail`` names every method tried with its result, then what to change.
Measured (17x64, 2-core x86_64): NACA 0006 bay, 323 Pa, prestrain 4%/3%,
fabric 2e4/3e5 N/m, ribs 0.5 m: relax stalls after 11,000 steps, Newton
converges in 30 iterations (before the early stop, relax ran its
200,000-step cap first); slack fabric (NACA 2412, 1e4 Pa, -5%): relax stalls
after 10,500 steps, Newton from there converges in 8.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from ..solution import Result, Solution

__all__ = ["AUTO_CHAIN", "EQUILIBRIUM_METHODS", "run_chain"]

#: The ``"auto"`` chain; "newton@stop" is Newton from where the previous attempt stopped.
AUTO_CHAIN = ("relax+newton", "newton@stop", "newton")
#: The methods a user may name for an equilibrium (command line, case file, ``solver_options``).
EQUILIBRIUM_METHODS = ("auto", "relax", "newton", "relax+newton")

_WHAT_TO_CHANGE = (
    "check the input (a pressure far beyond the fabric's strength inflates without bound; a "
    "strongly anisotropic fabric with a large Poisson coupling, or slack fabric, is hard for every "
    "method); else raise max_steps or loosen rtol")


def run_chain(solve: Callable, initial=None) -> Solution:
    """Run `AUTO_CHAIN`: ``solve(method, initial) -> Solution`` (concrete, no raising) per try.

    Returns the first converged `Solution`, or the least-residual failure
    with a ``detail`` that names every try; ``extra["attempts"]`` either way.
    """
    attempts, failures = [], []
    for k, step in enumerate(AUTO_CHAIN):
        if step == "newton@stop":
            last = failures[-1]
            if last.result in (Result.diverged, Result.nonfinite):
                continue
            tries = [("newton", np.asarray(last.nodes), f"newton from where {last.method} stopped")]
        elif k == 0 and initial is not None:
            tries = [(step, initial, f"{step} (warm start)"), (step, None, f"{step} (cold start)")]
        else:
            tries = [(step, None, step)]
        for method, start, how in tries:
            sol = solve(method, start)
            result = Result(int(np.asarray(sol.result)))
            attempts.append((how, result.name, int(sol.steps), float(sol.residual)))
            if result == Result.converged:
                return dataclasses.replace(sol, extra={**sol.extra, "attempts": attempts})
            failures.append(sol)
    best = min(failures, key=lambda s: float(s.residual) if np.isfinite(s.residual) else np.inf)
    tried = "; ".join(f"{how}: {name} after {steps} steps (residual {res:.2e})"
                      for how, name, steps, res in attempts)
    detail = f"every method of the 'auto' chain failed ({tried}); {_WHAT_TO_CHANGE}"
    return dataclasses.replace(best, detail=detail, extra={**best.extra, "attempts": attempts})
