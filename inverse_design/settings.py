"""What a design is asked for, and how it is run: the option objects of `optimise_wing` and `optimise_pressure`.

Four frozen dataclasses, each checked when it is built (a ValueError says
what to change):

* `DesignRequest`: what is asked, the variables, their start and bounds,
  the objective, the method (a value of `methods`, with its own knobs), the
  `Limits`, the layout and the solver settings; `DesignResult.request`
  records it (`optimise.refine_design` runs it again on a finer grid).
* `Limits`: the tension limits over every cell (`constraints.Constraints`)
  and the manufacturability limits of a shaped rib (`rib_design.RibLimits`).
* `SolverSettings`: what every method shares: the iteration cap, the
  forward solves' residual tolerance, equilibrium method and step cap, the
  progress bar and callback (a method's own tolerance is the method's).
* `Layout`: how vector variables are laid out over a wing (a rib shape per
  rib or shared, a cut pattern shared or per bay) and every bay's grid.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping

from forward_solver.derivatives.custom_jvp import GRADIENT_RTOL
from forward_solver.solvers.chain import EQUILIBRIUM_METHODS

from . import defaults
from .constraints import Constraints
from .methods import resolve
from .objectives import DEFAULT_OBJECTIVE, check_objective
from .rib_design import RibLimits
from .variables import CUT_PATTERN_LAYOUTS, RIB_SHAPE_LAYOUTS

__all__ = ["DesignRequest", "Layout", "Limits", "MOVED_KEYWORDS", "SolverSettings", "refuse_moved"]


#: The old keyword arguments of `optimise_wing` and `optimise_pressure`, and the object that holds each now.
MOVED_KEYWORDS = {
    "constraints": "limits=Limits(tension=...)",
    "rib_limits": "limits=Limits(ribs=...)",
    "max_iterations": "solver=SolverSettings(max_iterations=...)",
    "tolerance": "method=GaussNewton(tolerance=...), the tolerance of the method run (inverse_design.methods)",
    "optimiser": "method=Optax(optimiser=...)",
    "rtol": "solver=SolverSettings(rtol=...)",
    "max_steps": "solver=SolverSettings(max_steps=...)",
    "solver_options": "solver=SolverSettings(equilibrium_method=..., max_steps=...)",
    "progress": "solver=SolverSettings(progress=...)",
    "callback": "solver=SolverSettings(callback=...)",
    "root_condition": "method=Root(condition=...)",
    "rib_shape": "layout=Layout(rib_shape=...)",
    "cut_pattern": "layout=Layout(cut_pattern=...)",
    "n_span": "layout=Layout(n_span=...)",
    "n_contour": "layout=Layout(n_contour=...)",
    "rib": "the scene's bay, whose rib sections the rib limits are measured against (Bay.from_airfoil(rib, ...))",
}


#: The keywords of `SolverSettings` that moved onto the methods (`MOVED_KEYWORDS`).
_METHOD_KNOBS = ("tolerance", "optimiser", "root_condition")


def refuse_moved(function: str, keywords: Mapping, moved: Mapping | None = None) -> None:
    """Raise a TypeError naming, for each old keyword given, the object that now holds it (``moved``:
    the keyword and where it went, default `MOVED_KEYWORDS`)."""
    if not keywords:
        return
    moved = MOVED_KEYWORDS if moved is None else moved
    where = [f"{k} -> {moved[k]}" if k in moved else f"{k} (unknown)" for k in keywords]
    raise TypeError(f"{function}() got keyword argument(s) it no longer takes: {'; '.join(where)}")


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
    """What every design method shares: its iteration cap, how every forward solve runs, and what the
    caller sees. A method's own knobs (its tolerance, an optax optimiser, a root condition) are the
    method's (`methods`); those keywords given here are refused with a TypeError naming where they went.

    Args:
        max_iterations: cap on iterations (SLSQP iterations, and twice that
            in forward solves; Gauss-Newton forward solves; least-squares
            Jacobian evaluations; optax steps; brentq iterations).
        rtol: relative residual every bay is solved to (the implicit
            gradient is only as good as the equilibrium; default
            `forward_solver.derivatives.custom_jvp.GRADIENT_RTOL`).
        equilibrium_method: the method of every forward solve, one of
            `forward_solver.solvers.chain.EQUILIBRIUM_METHODS`: "auto" (default:
            relax+newton, then Newton from where it stopped, then Newton with
            load continuation), "relax", "newton" or "relax+newton".
        max_steps: step cap of each bay's relaxation (default 200000).
        progress: show a tqdm progress bar on stderr, one tick per wing
            solve (off by default: library code prints nothing unless asked).
        callback: called as ``callback(entry)`` after every iterate with the
            new `DesignResult.history` entry; an exception it raises stops the
            optimisation and propagates.

    Raises:
        ValueError: for a setting out of its range (the message names it and its range).
        TypeError: for a keyword that moved onto the methods (`MOVED_KEYWORDS`).
    """

    max_iterations: int = 50
    rtol: float = GRADIENT_RTOL
    equilibrium_method: str = "auto"
    max_steps: int = 200_000
    progress: bool = False
    callback: Callable | None = field(default=None, compare=False)

    def __new__(cls, *args, **kwargs):
        refuse_moved("SolverSettings", {k: v for k, v in kwargs.items() if k in _METHOD_KNOBS})
        return super().__new__(cls)

    def __post_init__(self):
        if isinstance(self.max_iterations, bool) or not (isinstance(self.max_iterations, int)
                                                         and self.max_iterations >= 1):
            raise ValueError(f"max_iterations must be a positive integer, got {self.max_iterations!r}")
        if not (isinstance(self.rtol, float | int) and 0 < self.rtol < 1):
            raise ValueError(f"rtol (the forward solves' relative residual) must lie in (0, 1), got {self.rtol!r}")
        if self.equilibrium_method not in EQUILIBRIUM_METHODS:
            raise ValueError(f"equilibrium_method must be one of {EQUILIBRIUM_METHODS}, got "
                             f"{self.equilibrium_method!r}")
        if isinstance(self.max_steps, bool) or not (isinstance(self.max_steps, int) and self.max_steps >= 1):
            raise ValueError(f"max_steps must be a positive integer, got {self.max_steps!r}")
        if self.callback is not None and not callable(self.callback):
            raise ValueError(f"callback must be callable (or None), got {self.callback!r}")


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
    n_span: int = defaults.N_SPAN
    n_contour: int = defaults.N_CONTOUR

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
        objective: per bay "mid_bay", "average" (`objectives.DEFAULT_OBJECTIVE`), "worst" or "robust"
            (`objectives`, `tolerance.robust`).
        method: a method value of `methods` (``GaussNewton(tolerance=...)``, ...) or its shortcut
            (`methods.METHODS`; "auto": `methods.AUTO`, or `methods.AUTO_FOR_WORST` for the
            objective "worst"), held as the value that runs; None for a single equilibrium
            (`optimise.evaluate_design`: nothing is optimised).
        limits: the `Limits` the design must meet.
        tolerances: the manufacturing tolerances of the objective "robust"
            (anything `tolerance.parse_tolerances` takes; None: every
            default); refused with another objective.
        layout: how the vector variables are laid out and every bay's grid (`Layout`).
        solver: what every method shares (`SolverSettings`).

    Raises:
        ValueError: for an unknown objective or method, limits that are not a
            `Limits`, tolerances without the objective "robust", "robust"
            with a method other than gauss_newton, or settings of the wrong type.
    """

    variables: tuple = ("pressure",)
    initial: object = None
    bounds: Mapping | None = None
    objective: str = DEFAULT_OBJECTIVE
    method: object = "auto"
    limits: Limits = Limits()
    tolerances: object = None
    layout: Layout = Layout()
    solver: SolverSettings = SolverSettings()

    def __post_init__(self):
        if isinstance(self.variables, str):
            object.__setattr__(self, "variables", (self.variables,))
        else:
            object.__setattr__(self, "variables", tuple(self.variables))
        check_objective(self.objective)
        if self.method is not None:
            object.__setattr__(self, "method", resolve(self.method, self.objective))
        if not isinstance(self.limits, Limits):
            raise ValueError(f"limits must be an inverse_design.Limits, got {self.limits!r}")
        if self.tolerances is not None and self.objective != "robust":
            raise ValueError(f"tolerances are what objective='robust' designs for; the objective is "
                             f"{self.objective!r}: give objective='robust', or analyse the design afterwards "
                             "with inverse_design.tolerance.tolerance_analysis")
        if self.objective == "robust" and self.method is not None and not self.method.robust:
            raise ValueError(f"objective='robust' is a sum of squares that method='gauss_newton' minimises "
                             f"(its derivatives are the tolerance Jacobian's); got method={self.method.name!r}: "
                             "give method='auto' or 'gauss_newton'")
        if not isinstance(self.solver, SolverSettings):
            raise ValueError(f"solver must be an inverse_design.SolverSettings, got {self.solver!r}")
        if not isinstance(self.layout, Layout):
            raise ValueError(f"layout must be an inverse_design.Layout, got {self.layout!r}")
