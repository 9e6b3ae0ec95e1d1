"""What a design is asked for, and how it is run: the option objects of `optimise_wing` and `optimise_pressure`.

Four frozen dataclasses, each checked when it is built (a ValueError says
what to change):

* `DesignRequest`: what is asked, the variables, their start and bounds,
  the objective, the method and the `Limits`; `DesignResult.request`
  records it.
* `Limits`: the tension limits over every cell (`constraints.Constraints`)
  and the manufacturability limits of a shaped rib (`rib_design.RibLimits`).
* `SolverSettings`: how the optimiser and every forward solve run
  (iteration cap, tolerance, optax optimiser, residual tolerance, the
  equilibrium method and its step cap, the progress bar and callback, the
  condition of ``method="root"``).
* `Layout`: how vector variables are laid out over a wing (a rib shape per
  rib or shared, a cut pattern shared or per bay) and every bay's grid.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping

from forward_solver.derivatives.custom_jvp import GRADIENT_RTOL

from .constraints import Constraints
from .objectives import check_objective
from .rib_design import RibLimits
from .variables import CUT_PATTERN_LAYOUTS, RIB_SHAPE_LAYOUTS

__all__ = ["AUTO", "AUTO_FOR_WORST", "METHODS", "ROOT_CONDITIONS", "DesignRequest", "Layout", "Limits",
           "SolverSettings"]

METHODS = ("auto", "slsqp", "gauss_newton", "least_squares", "optax", "root")
ROOT_CONDITIONS = ("thickness", "mean_offset")
#: What ``method="auto"`` runs (`optimise` module docstring) ...
AUTO = "gauss_newton"
#: ... and what it runs for the objective "worst" (no sum of squares for Gauss-Newton).
AUTO_FOR_WORST = "slsqp"


@dataclass(frozen=True)
class Limits:
    """The limits a design must meet (inequality constraints of the methods that take them).

    Args:
        tension: limits of the fibre tensions over every cell of every bay
            (`constraints.Constraints`, N/m; default a wrinkle-free skin below
            the fabric's allowable tension), or None: no tension limit.
        ribs: manufacturability limits of every shaped rib against its own
            starting section (`rib_design.RibLimits`: least thickness ratio,
            least radius of curvature as a fraction of chord), enforced when
            ``rib_shape`` is a variable (slsqp, gauss_newton); None leaves
            the shapes free within their bounds.

    Raises:
        ValueError: for a limit of the wrong type or a rib limit that makes no sense.
    """

    tension: Constraints | None = Constraints()
    ribs: RibLimits | None = RibLimits()

    def __post_init__(self):
        if self.tension is not None and not isinstance(self.tension, Constraints):
            raise ValueError(f"Limits.tension must be an inverse_design.Constraints or None, got {self.tension!r}")
        if self.ribs is not None:
            if not isinstance(self.ribs, RibLimits):
                raise ValueError(f"Limits.ribs must be an inverse_design.RibLimits or None, got {self.ribs!r}")
            self.ribs.check()


@dataclass(frozen=True)
class SolverSettings:
    """How the optimiser and every forward solve run.

    Args:
        max_iterations: cap on iterations (SLSQP iterations, and twice that
            in forward solves; Gauss-Newton forward solves; least-squares
            Jacobian evaluations; optax steps; brentq iterations).
        tolerance: convergence tolerance in (0, 1), or None for the method's
            default: SLSQP's ``ftol`` on the objective relative to its
            starting value (1e-6: one part in a million of the mean square
            error, far below what the grid resolves), ``ftol``/``xtol`` of
            least_squares (1e-8), the relative pressure tolerance of brentq
            (1e-8), the model's predicted fall of the merit relative to it
            for gauss_newton (`optimise.GN_TOLERANCE`, 1e-3), the scaled
            gradient norm of optax relative to its starting loss (1e-8).
        optimiser: an ``optax.GradientTransformation`` (``method="optax"``;
            None: ``optax.adam(0.05)`` on the scaled variables, its step
            halved whenever the loss stops falling).
        rtol: relative residual every bay is solved to (the implicit
            gradient is only as good as the equilibrium; default
            `forward_solver.derivatives.custom_jvp.GRADIENT_RTOL`).
        equilibrium_method: the method of every forward solve, one of
            `forward_solver.solvers.chain.EQUILIBRIUM_METHODS`: "auto" (default:
            relax+newton, then Newton from where it stopped, then Newton with
            load continuation), "relax", "newton" or "relax+newton".
        max_steps: step cap of each bay's relaxation (default 200000).
        root_condition: the scalar condition of ``method="root"`` at the
            mid-bay section: "thickness" (default: the section's maximum
            thickness equal to the target's) or "mean_offset" (zero mean
            normal distance).
        progress: show a tqdm progress bar on stderr, one tick per wing
            solve (off by default: library code prints nothing unless asked).
        callback: called as ``callback(entry)`` after every iterate with the
            new `DesignResult.history` entry; an exception it raises stops the
            optimisation and propagates.

    Raises:
        ValueError: for a setting out of its range (the message names it and its range).
    """

    max_iterations: int = 50
    tolerance: float | None = None
    optimiser: object = None
    rtol: float = GRADIENT_RTOL
    equilibrium_method: str = "auto"
    max_steps: int = 200_000
    root_condition: str = "thickness"
    progress: bool = False
    callback: Callable | None = field(default=None, compare=False)

    def __post_init__(self):
        from forward_solver.solvers.chain import EQUILIBRIUM_METHODS

        if isinstance(self.max_iterations, bool) or not (isinstance(self.max_iterations, int)
                                                         and self.max_iterations >= 1):
            raise ValueError(f"max_iterations must be a positive integer, got {self.max_iterations!r}")
        if self.tolerance is not None and not (isinstance(self.tolerance, float | int) and 0 < self.tolerance < 1):
            raise ValueError(f"tolerance must lie in (0, 1) (or None for the method's default), got "
                             f"{self.tolerance!r}")
        if not (isinstance(self.rtol, float | int) and 0 < self.rtol < 1):
            raise ValueError(f"rtol (the forward solves' relative residual) must lie in (0, 1), got {self.rtol!r}")
        if self.equilibrium_method not in EQUILIBRIUM_METHODS:
            raise ValueError(f"equilibrium_method must be one of {EQUILIBRIUM_METHODS}, got "
                             f"{self.equilibrium_method!r}")
        if isinstance(self.max_steps, bool) or not (isinstance(self.max_steps, int) and self.max_steps >= 1):
            raise ValueError(f"max_steps must be a positive integer, got {self.max_steps!r}")
        if self.root_condition not in ROOT_CONDITIONS:
            raise ValueError(f"root_condition must be one of {ROOT_CONDITIONS}, got {self.root_condition!r}")
        if self.callback is not None and not callable(self.callback):
            raise ValueError(f"callback must be callable (or None), got {self.callback!r}")

    @property
    def solver_options(self) -> dict:
        """``{"method", "max_steps"}`` of every forward solve (`problem.check_solver_options`)."""
        return {"method": self.equilibrium_method, "max_steps": self.max_steps}


@dataclass(frozen=True)
class Layout:
    """How the vector variables are laid out over a wing, and the grid of every bay.

    Args:
        rib_shape: "per_rib" (default: one shape per rib, root to tip) or
            "shared" (one shape for every rib), when ``rib_shape`` is a
            variable (`variables.RIB_SHAPE_LAYOUTS`).
        cut_pattern: "shared" (default: one cut field for every bay) or
            "per_bay" (one field per bay, each cell's panel cut on its own),
            when ``cut_pattern`` is a variable (`variables.CUT_PATTERN_LAYOUTS`).
        n_span: nodes along the span of every bay (>= 2).
        n_contour: nodes around the contour of every bay (>= 3).

    Raises:
        ValueError: for an unknown layout or a grid too small.
    """

    rib_shape: str = "per_rib"
    cut_pattern: str = "shared"
    n_span: int = 17
    n_contour: int = 64

    def __post_init__(self):
        if self.rib_shape not in RIB_SHAPE_LAYOUTS:
            raise ValueError(f"rib_shape layout must be one of {RIB_SHAPE_LAYOUTS}, got {self.rib_shape!r}")
        if self.cut_pattern not in CUT_PATTERN_LAYOUTS:
            raise ValueError(f"cut_pattern layout must be one of {CUT_PATTERN_LAYOUTS}, got {self.cut_pattern!r}")
        for name, least in (("n_span", 2), ("n_contour", 3)):
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, int) and value >= least):
                raise ValueError(f"{name} must be an integer >= {least}, got {value!r}")


@dataclass(frozen=True, eq=False)
class DesignRequest:
    """What a design is asked for (recorded in `DesignResult.request`).

    Args:
        variables: names to optimise, from `variables.VARIABLES` (or one name).
        initial: the starting `forward_solver.Parameters`, or ``{name: value}``
            (Pa, fractions) over `variables.DEFAULT_START`; names not
            optimised stay at these values.
        bounds: ``{name: (lower, upper)}`` of optimised names (defaults
            `variables.DEFAULT_BOUNDS`).
        objective: per bay "mid_bay", "average", "worst" or "robust" (`objectives`, `robust`).
        method: one of `METHODS` ("auto": `AUTO`, or `AUTO_FOR_WORST` for
            the objective "worst"); None for a single equilibrium
            (`optimise.evaluate_design`: nothing is optimised).
        limits: the `Limits` the design must meet.
        tolerances: the manufacturing tolerances of the objective "robust"
            (anything `tolerance.parse_tolerances` takes; None: every
            default); refused with another objective.

    Raises:
        ValueError: for an unknown objective or method, limits that are not a
            `Limits`, tolerances without the objective "robust", or "robust"
            with a method other than gauss_newton.
    """

    variables: tuple = ("pressure",)
    initial: object = None
    bounds: Mapping | None = None
    objective: str = "mid_bay"
    method: str | None = "auto"
    limits: Limits = Limits()
    tolerances: object = None

    def __post_init__(self):
        if isinstance(self.variables, str):
            object.__setattr__(self, "variables", (self.variables,))
        else:
            object.__setattr__(self, "variables", tuple(self.variables))
        check_objective(self.objective)
        if self.method is not None and self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {self.method!r}")
        if not isinstance(self.limits, Limits):
            raise ValueError(f"limits must be an inverse_design.Limits, got {self.limits!r}")
        if self.tolerances is not None and self.objective != "robust":
            raise ValueError(f"tolerances are what objective='robust' designs for; the objective is "
                             f"{self.objective!r}: give objective='robust', or analyse the design afterwards "
                             "with inverse_design.tolerance.tolerance_analysis")
        if self.objective == "robust" and self.method not in (None, "auto", "gauss_newton"):
            raise ValueError(f"objective='robust' is a sum of squares that method='gauss_newton' minimises "
                             f"(its derivatives are the tolerance Jacobian's); got method={self.method!r}: "
                             "give method='auto' or 'gauss_newton'")

    @property
    def method_to_run(self) -> str:
        """The method that runs: ``method``, with "auto" resolved (`AUTO`, `AUTO_FOR_WORST`)."""
        if self.method != "auto":
            return self.method
        return AUTO_FOR_WORST if self.objective == "worst" else AUTO


#: The old keyword arguments of `optimise_wing` and `optimise_pressure`, and the object that holds each now.
MOVED_KEYWORDS = {
    "constraints": "limits=Limits(tension=...)",
    "rib_limits": "limits=Limits(ribs=...)",
    "max_iterations": "solver=SolverSettings(max_iterations=...)",
    "tolerance": "solver=SolverSettings(tolerance=...)",
    "optimiser": "solver=SolverSettings(optimiser=...)",
    "rtol": "solver=SolverSettings(rtol=...)",
    "max_steps": "solver=SolverSettings(max_steps=...)",
    "solver_options": "solver=SolverSettings(equilibrium_method=..., max_steps=...)",
    "progress": "solver=SolverSettings(progress=...)",
    "callback": "solver=SolverSettings(callback=...)",
    "root_condition": "solver=SolverSettings(root_condition=...)",
    "rib_shape": "layout=Layout(rib_shape=...)",
    "cut_pattern": "layout=Layout(cut_pattern=...)",
    "n_span": "layout=Layout(n_span=...)",
    "n_contour": "layout=Layout(n_contour=...)",
}


def refuse_moved(function: str, keywords: Mapping) -> None:
    """Raise a TypeError naming, for each old keyword given, the object that now holds it."""
    if not keywords:
        return
    where = [f"{k} -> {MOVED_KEYWORDS[k]}" if k in MOVED_KEYWORDS else f"{k} (unknown)" for k in keywords]
    raise TypeError(f"{function}() got keyword argument(s) it no longer takes: {'; '.join(where)}")
