"""Inverse design: choose pressure, prestrain and rib geometry so the inflated skin matches a target.

Public names::

    optimise_pressure, refine_design, DesignResult, Constraints, section_errors,
    objective_residuals, design_errors, OBJECTIVES, VARIABLES, RibLimits,
    optimise_wing, WingDesignResult (an alias of DesignResult), PerBayResults (DesignResult.per_bay),
    Limits, SolverSettings, Layout, DesignRequest (the options of a design: `settings`)

One design over a wing of N >= 1 bays: ``optimise_wing`` runs a
Gauss-Newton trust-region SQP (the default, ``method="auto"``; SLSQP for the
objective "worst"), scipy's SLSQP and ``least_squares``, or optax around the
differentiable N-bay forward solve ``forward_solver.solve_bays``;
``optimise_pressure`` is its one-bay case (and adds ``brentq`` on one bay's
mid-bay condition). The packages and the data flow: ``docs/architecture.md``.
"""

from .constraints import Constraints as Constraints
from .objectives import OBJECTIVES as OBJECTIVES
from .objectives import design_errors as design_errors
from .objectives import objective_residuals as objective_residuals
from .objectives import section_errors as section_errors
from .optimise import DesignResult as DesignResult
from .optimise import PerBayResults as PerBayResults
from .optimise import WingDesignResult as WingDesignResult
from .optimise import optimise_wing as optimise_wing
from .optimise import evaluate_design as evaluate_design
from .optimise import optimise_pressure as optimise_pressure
from .optimise import refine_design as refine_design
from .rib_design import RibLimits as RibLimits
from .settings import DesignRequest as DesignRequest
from .settings import Layout as Layout
from .settings import Limits as Limits
from .settings import SolverSettings as SolverSettings
from .variables import VARIABLES as VARIABLES

__all__ = [
    "Constraints",
    "DesignRequest",
    "DesignResult",
    "Layout",
    "Limits",
    "OBJECTIVES",
    "PerBayResults",
    "RibLimits",
    "VARIABLES",
    "design_errors",
    "objective_residuals",
    "evaluate_design",
    "optimise_pressure",
    "refine_design",
    "section_errors",
    "SolverSettings",
    "WingDesignResult",
    "optimise_wing",
]
