"""What every design method offers the design loop (`optimise.optimise_wing`).

A method is a small frozen dataclass with its own knobs (a tolerance, an
optax optimiser, a root condition) that subclasses `Method`: the loop calls
``method.run(problem, u0, max_iterations)`` on it, whatever it is.
"""

from __future__ import annotations

import math
from typing import ClassVar

__all__ = ["Method", "check_tolerance"]


class Method:
    """The interface of a design method (a frozen dataclass subclasses it with its knobs).

    Attributes:
        name: the method's shortcut (``"gauss_newton"``, ...), as `DesignResult.method` names it.
        robust: whether it designs for ``objective="robust"`` (a sum of squares whose derivatives are
            the tolerance Jacobian's).
        rib_limits: whether it enforces the rib limits (`rib_design.RibLimits`) as constraints.
    """

    name: ClassVar[str] = ""
    robust: ClassVar[bool] = False
    rib_limits: ClassVar[bool] = False

    def check(self, objective: str, names: tuple, n_bays: int) -> None:
        """Refuse a design this method cannot run (ValueError saying what to use instead)."""

    def start(self, problem, u0):
        """The starting iterate's concrete `BaysSolution`, with what the method computes there."""
        return problem.solve(u0)

    def evaluations(self, max_iterations: int) -> int:
        """The most wing solves the method may spend (the progress bar's cap)."""
        return max_iterations

    def shown(self, value: float) -> str:
        """An iterate's objective as the progress bar shows it."""
        return f"rms={math.sqrt(max(value, 0.0)):.3e}"

    def run(self, problem, u0, max_iterations: int) -> tuple:
        """``(u, success, message)``: the scaled design vector the method ends at, whether it reports
        convergence, and its message (`problem.DesignProblem` in; the common checks of the result are
        `optimise.optimise_wing`'s)."""
        raise NotImplementedError


def check_tolerance(tolerance) -> None:
    """Raise a ValueError for a tolerance outside (0, 1)."""
    if isinstance(tolerance, bool) or not (isinstance(tolerance, float | int) and 0 < tolerance < 1):
        raise ValueError(f"tolerance must lie in (0, 1) (or None for the method's default), got {tolerance!r}")
