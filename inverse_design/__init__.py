"""Inverse design: choose pressure, prestrain and rib geometry so the inflated skin matches a target.

Public names::

    optimise_pressure, refine_design, DesignResult, Constraints, section_errors,
    objective_residuals, design_errors, OBJECTIVES, VARIABLES, RibLimits,
    optimise_wing, WingDesignResult (an alias of DesignResult), PerBayResults (DesignResult.per_bay),
    LimitReport (DesignResult.limits), Limits, SolverSettings, Layout, DesignRequest (the options of a
    design: `settings`)

One design over a wing of N >= 1 bays: ``optimise_wing`` runs a method of
`methods` (each a small value with its own knobs: the Gauss-Newton
trust-region SQP, the default ``method="auto"``; SLSQP for the objective
"worst"; scipy's ``least_squares``; optax) around the differentiable N-bay
forward solve ``forward_solver.solve_bays``; ``optimise_pressure`` is its
one-bay case (and adds ``brentq`` on one bay's mid-bay condition). The
tolerance analysis and the robust design: `tolerance`. The packages and the
data flow: ``docs/architecture.md``.
"""

import importlib

#: Each public name and the submodule that defines it: imported on first use (PEP 562), so that a
#: process that needs only a JAX-free submodule (the report's workers: `app.workers`, `app.cut_files`)
#: does not import JAX and the solver.
_PUBLIC = {"Constraints": "constraints", "OBJECTIVES": "objectives", "design_errors": "objectives",
           "objective_residuals": "objectives", "section_errors": "objectives", "DesignResult": "result",
           "WingDesignResult": "result", "optimise_wing": "optimise", "evaluate_design": "optimise",
           "optimise_pressure": "optimise", "refine_design": "optimise", "PerBayResults": "result",
           "LimitReport": "result",
           "RibLimits": "rib_design", "DesignRequest": "settings", "Layout": "settings", "Limits": "settings",
           "SolverSettings": "settings", "VARIABLES": "variables"}


def __getattr__(name: str):
    if name in _PUBLIC:
        value = getattr(importlib.import_module(f".{_PUBLIC[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "Constraints",
    "DesignRequest",
    "DesignResult",
    "Layout",
    "LimitReport",
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
