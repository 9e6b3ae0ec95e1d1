"""Inverse design: choose pressure, prestrain and rib geometry so the inflated skin matches a target.

Public names::

    optimise_pressure, refine_design, DesignResult, Constraints, section_errors,
    objective_residuals, design_errors, OBJECTIVES, VARIABLES, RibLimits,
    optimise_wing, WingDesignResult (a whole wing: one pressure for every bay)

``optimise_pressure`` wraps scipy's SLSQP (default), ``least_squares`` and
``brentq`` and optax around the differentiable
``forward_solver.solve_equilibrium`` (DESIGN sections 5-7).
"""

from .constraints import Constraints as Constraints
from .objectives import OBJECTIVES as OBJECTIVES
from .objectives import design_errors as design_errors
from .objectives import objective_residuals as objective_residuals
from .objectives import section_errors as section_errors
from .optimise import DesignResult as DesignResult
from .optimise import optimise_pressure as optimise_pressure
from .optimise import refine_design as refine_design
from .rib_design import RibLimits as RibLimits
from .variables import VARIABLES as VARIABLES
from .wing_design import WingDesignResult as WingDesignResult
from .wing_design import optimise_wing as optimise_wing

__all__ = [
    "Constraints",
    "DesignResult",
    "OBJECTIVES",
    "RibLimits",
    "VARIABLES",
    "design_errors",
    "objective_residuals",
    "optimise_pressure",
    "refine_design",
    "section_errors",
    "WingDesignResult",
    "optimise_wing",
]
