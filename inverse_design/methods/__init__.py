"""The design methods: each a small frozen value with its own knobs, run by the design loop as
``method.run(problem, u0, max_iterations)`` (`base.Method`).

* `GaussNewton` (``"gauss_newton"``): the trust-region Gauss-Newton SQP, with its block Jacobian
  (`blocks`) and step QP (`step_qp`).
* `SLSQP` (``"slsqp"``), `LeastSquares` (``"least_squares"``) and `Root` (``"root"``: brentq on one
  bay's pressure): scipy's (`scipy_methods`).
* `Optax` (``"optax"``): an optax optimiser (`optax_descent`).

``method=`` of `optimise.optimise_wing` and `optimise.optimise_pressure` takes one of these values or a
shortcut string (`METHODS`); `named` builds a method from its shortcut and the user's knobs.
``"auto"`` is `GaussNewton`, or `SLSQP` for the objective "worst" (no sum of squares for
Gauss-Newton): on the design matrix (every documented variable set on the default bay, the built-in
wing, a NACA 0012 bay and a bay of a ``.dat`` section, 17x64: ``benchmarks/design_matrix.py``)
Gauss-Newton converges on every cell, in as many forward solves as SLSQP or fewer (3 against 7 on
the default case, at the same optimum), and where SLSQP stops at its iteration cap (a cut pattern, a
rib shape on the wing and on a ``.dat`` section, the prestrains with a rib shape); where both
converge its rms error is SLSQP's within 0.01% or lower (its largest error at most 0.21% above
SLSQP's).
"""

from __future__ import annotations

import dataclasses

from ..objectives import DEFAULT_OBJECTIVE
from .base import Method
from .gauss_newton import GaussNewton
from .optax_descent import Optax
from .scipy_methods import ROOT_CONDITIONS, SLSQP, LeastSquares, Root

__all__ = ["AUTO", "AUTO_FOR_WORST", "METHODS", "ROOT_CONDITIONS", "SHORTCUTS", "GaussNewton", "LeastSquares",
           "Method", "Optax", "Root", "SLSQP", "named", "resolve"]

#: Each shortcut string and the method it names (with its default knobs).
SHORTCUTS = {"slsqp": SLSQP, "gauss_newton": GaussNewton, "least_squares": LeastSquares, "optax": Optax,
             "root": Root}
#: The shortcuts ``method=`` accepts.
METHODS = ("auto", *SHORTCUTS)
#: What ``method="auto"`` runs ...
AUTO = "gauss_newton"
#: ... and what it runs for the objective "worst" (no sum of squares for Gauss-Newton).
AUTO_FOR_WORST = "slsqp"
#: Every method's knobs.
_KNOBS = {f.name for method in SHORTCUTS.values() for f in dataclasses.fields(method)}


def named(name: str, *, objective: str = DEFAULT_OBJECTIVE, **knobs) -> Method:
    """The method of a shortcut with the user's knobs: the command's one way to build it.

    Args:
        name: one of `METHODS` ("auto": `AUTO`, or `AUTO_FOR_WORST` for ``objective`` "worst").
        objective: the design's objective (what "auto" resolves by).
        **knobs: ``tolerance``, ``optimiser``, ``condition``: a knob that is None keeps the method's
            default, and one of another method (a command passes all of its options) is not used.

    Raises:
        ValueError: for an unknown shortcut or a knob value out of its range.
        TypeError: for a knob no method has.
    """
    if name not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {name!r}")
    unknown = sorted(set(knobs) - _KNOBS)
    if unknown:
        raise TypeError(f"no design method has the knob(s) {unknown}; the knobs are {sorted(_KNOBS)}")
    if name == "auto":
        name = AUTO_FOR_WORST if objective == "worst" else AUTO
    method = SHORTCUTS[name]
    own = {f.name for f in dataclasses.fields(method)}
    return method(**{k: v for k, v in knobs.items() if v is not None and k in own})


def resolve(method, objective: str) -> Method:
    """``method`` as a value: a `Method` as it is, a shortcut string by `named` with its defaults.

    Raises:
        ValueError: for an unknown shortcut, or anything else.
    """
    if isinstance(method, Method):
        return method
    if isinstance(method, str):
        return named(method, objective=objective)
    raise ValueError(f"method must be one of {METHODS} or a method value (inverse_design.methods), got "
                     f"{method!r}")
