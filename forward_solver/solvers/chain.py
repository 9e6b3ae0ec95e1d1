"""`Auto`, the ``"auto"`` method of `solve_equilibrium`: try the methods in turn before reporting a failure.

No method solves every scene: dynamic relaxation can cycle where the force
is not the gradient of an energy or the skin is slack (the measured cases
are in `relax`'s module docstring), and Newton's load continuation can stall
where relaxation converges. The chain is

1. `methods.RelaxNewton`: relaxation (which ends early with ``stalled`` when
   its residual stops falling) handing over to Newton, whose LU factor the
   adjoint reuses; warm-started from ``initial`` if given, and then retried
   from a cold start if that fails;
2. `methods.Newton` from where the relaxation stopped, when that shape did
   not diverge (a stalled relaxation is often near the equilibrium);
3. `methods.Newton` from the mounted shape, with its load continuation.

The first converged `Solution` is returned, its ``extra["attempts"]`` the
list of ``(how, result, steps, residual)`` tried. When every method fails
the returned solution is the one with the least residual, and its
``detail`` names every method tried with its result, then what to change.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..model.parameters import Parameters
from ..model.scene import Scene
from ..solution import Result, Solution
from .methods import RelaxNewton

__all__ = ["Auto", "EQUILIBRIUM_METHODS"]

#: The methods a user may name for an equilibrium (command line, case file, ``solver_options``).
EQUILIBRIUM_METHODS = ("auto", "relax", "newton", "relax+newton")

_WHAT_TO_CHANGE = (
    "check the input (a pressure far beyond the fabric's strength inflates without bound; a "
    "strongly anisotropic fabric with a large Poisson coupling, or slack fabric, is hard for every "
    "method); else raise max_steps or loosen rtol")


@dataclass(frozen=True)
class Auto(RelaxNewton):
    """The methods in turn until one converges (module docstring); its knobs are `methods.RelaxNewton`'s (the
    first try's; ``newton`` is every Newton try's)."""

    name: ClassVar[str] = "auto"

    def _tries(self, initial, failures: list):
        """``(method, start, how)`` of each try, lazily: the second looks at the first's failure."""
        first = RelaxNewton(self.switch_rtol, self.sequencing, self.symmetry, self.newton)
        if initial is not None:
            yield first, initial, f"{first.name} (warm start)"
            yield first, None, f"{first.name} (cold start)"
        else:
            yield first, None, first.name
        last = failures[-1]
        if last.result not in (Result.diverged, Result.nonfinite):
            yield self.newton, np.asarray(last.nodes), f"newton from where {last.method} stopped"
        yield self.newton, None, self.newton.name

    def solve(self, scene: Scene, parameters: Parameters, *, rtol: float, max_steps: int, initial) -> Solution:
        """The first converged `Solution`, else the least-residual failure (module docstring)."""
        attempts, failures = [], []
        for method, start, how in self._tries(initial, failures):
            sol = method.solve(scene, parameters, rtol=rtol, max_steps=max_steps, initial=start)
            result = Result(int(np.asarray(sol.result)))
            attempts.append((how, result.name, int(sol.steps), float(sol.residual)))
            if result == Result.converged:
                return sol.replace(extra={**sol.extra, "attempts": attempts})
            failures.append(sol)
        best = min(failures, key=lambda s: float(s.residual) if np.isfinite(s.residual) else np.inf)
        tried = "; ".join(f"{how}: {name} after {steps} steps (residual {res:.2e})"
                          for how, name, steps, res in attempts)
        detail = f"every method of the 'auto' chain failed ({tried}); {_WHAT_TO_CHANGE}"
        return best.replace(detail=detail, extra={**best.extra, "attempts": attempts})
