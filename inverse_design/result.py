"""What a design found: `DesignResult`, its per-bay arrays (`PerBayResults`) and its limits (`LimitReport`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from forward_solver import Parameters, Solution, Wing
from forward_solver.model.parameters import ParameterViews
from forward_solver.solution import BaysSolution, Result

from .settings import DesignRequest
from .variables import VARIABLES

__all__ = ["FORMER_LIMIT_FIELDS", "DesignResult", "LimitReport", "PerBayResults", "WingDesignResult"]


@dataclass(frozen=True, eq=False)
class PerBayResults:
    """The per-bay (and per-rib) arrays of a `DesignResult`, root to tip.

    Attributes:
        scenes: the `Scene` of each bay.
        targets: the target section of each rib.
        weights: ``(n_bays,)`` bay weights of the objective (planform area).
        rms_error, max_error: ``(n_bays,)`` RMS and largest normal distance
            of each bay's objective rows from their targets at the design,
            fractions of the local chord.
        initial_rms_error, initial_max_error: the same at the start (NaN
            for a single equilibrium).
        min_tension, max_tension: ``(n_bays,)`` smallest and largest
            unclamped fibre tension of each bay at the design, N/m.
        rib_shapes: ``(n_ribs, 2 K)`` rib-shape coefficients of a shape per
            rib, else None.
        cut_patterns: ``(n_bays, 2 K)`` cut-field coefficients of a field per
            bay, else None.
        rib_limits: per shaped rib, ``{"rib": k, ...}`` its measured
            manufacturability limits (`rib_design.RibGeometry.measure`).
        sections: the starting section of each rib (what the rib limits are
            measured against; empty for a single equilibrium).
    """

    scenes: tuple
    targets: tuple
    weights: np.ndarray
    rms_error: np.ndarray
    max_error: np.ndarray
    initial_rms_error: np.ndarray
    initial_max_error: np.ndarray
    min_tension: np.ndarray
    max_tension: np.ndarray
    rib_shapes: np.ndarray | None = None
    cut_patterns: np.ndarray | None = None
    rib_limits: list = field(default_factory=list)
    sections: tuple = ()


@dataclass(frozen=True, eq=False)
class LimitReport:
    """How a design stands against its limits (`DesignResult.limits`).

    Attributes:
        active: names of bounds (``"pressure<=upper"``, ``"rib_shape[1][3]<=upper"``
            for rib 1's), tension constraints (``"min_tension"``,
            ``"max_tension"``) and rib limits (``"rib_min_thickness"``;
            ``"rib_min_thickness@rib 2"`` with a shape per rib) at their limit
            (within `constraints.ACTIVE_TOLERANCE`).
        violated: ``{name: amount}``: the amount beyond the limit (N/m for a
            tension limit, broken by more than `constraints.VIOLATION_TOLERANCE`;
            for a shaped rib ``rib_min_thickness``, the thickness ratio's
            shortfall, and ``rib_min_radius``, the radius's, chord, broken by
            more than `rib_design.RIB_TOLERANCE` of the limit), the largest over
            the bays or ribs.
        violated_where: ``{name: {index: amount}}``: the same amounts at each
            bay (tension limits) or rib (rib limits) that breaks them.
        violated_at_start, violated_at_start_where: the same for the starting
            design (empty when the start met every limit). A start that broke a
            limit may have a smaller error than a design that meets it: the
            error then rises, and this says why.
        values: the measured minimum and maximum fibre tension (N/m) over
            every bay and the limits; for a shaped rib the least thickness ratio
            and radius of curvature with their limits (`rib_design.rib_report`).
    """

    active: list = field(default_factory=list)
    violated: dict = field(default_factory=dict)
    violated_where: dict = field(default_factory=dict)
    violated_at_start: dict = field(default_factory=dict)
    violated_at_start_where: dict = field(default_factory=dict)
    values: dict = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class DesignResult(ParameterViews):
    """Outcome of `optimise_wing` and `optimise_pressure`: what was found, what was asked
    (``request``) and the per-bay arrays (``per_bay``).

    Attributes:
        parameters: the shared `forward_solver.Parameters` of the design
            (with a shared rib shape its ``rib_shape``); ``pressure``,
            ``prestrain`` and the other parameters read through.
        rms_error, max_error: normal distance from the target over the
            objective's sections at the design, fractions of the local chord:
            the square root of the bays' area-weighted mean squares, and the
            largest over the bays (one bay: its own).
        initial_rms_error, initial_max_error: the same at the start.
        wing_solution: the `forward_solver.solvers.bays.BaysSolution` at the design
            (``solution``: one bay's `Solution`, or the wing's).
        history: one dict per iterate (forward solve): ``values`` (the
            optimised variables), ``objective`` (mean square distance, chord^2,
            as `objectives.mean_square` for slsqp; for "root" the
            condition's value), ``gradient_norm`` (of the
            objective in the scaled variables; NaN where not computed),
            ``constraints`` (the smooth constraint values, >= 0 feasible,
            with the least thickness and curvature row of the rib limits;
            slsqp; for gauss_newton each tension limit's least cell row)
            and ``steps`` (forward-solve steps of the slowest bay); gauss_newton adds
            ``jacobian`` (its bay blocks and tangents) and, at each accepted iterate,
            ``qp_rows`` (the limit rows its step QP kept, `step_qp.solve_working_set`) and
            ``qp_reachable_rows`` (those a step in the trust box could reach, `step_qp.reachable_rows`).
        success: the method converged, every bay's final solve converged and
            no tension or rib limit is violated.
        message: the method's message, and what was violated.
        limits: the active and violated limits, at the design and at the
            start, and the measured values (`LimitReport`); its fields read as
            the former ``active_constraints``, ``violated_constraints``,
            ``violated_where``, ``violated_at_start``,
            ``violated_at_start_where`` and ``constraint_values`` for one more
            release (read-only properties).
        solves: forward solves (each solves every bay once).
        wall_time: s, compilation included.
        grid_change: after `refine_design`, how the design moved from the
            coarser grid: ``{"grids": [[n_span, n_contour], ...], "values":
            {name: [coarse, fine]}, "change": {name: relative change for the
            pressure, absolute otherwise (the largest component's for a
            vector)}, "rms_error": [coarse, fine]}``;
            None for a design on one grid.
        wing: the `forward_solver.Wing` designed (None for a flat panel).
        request: what was asked (`settings.DesignRequest`: variables, start,
            bounds, objective, the method that ran, limits, tolerances, layout
            and solver settings).
        per_bay: the per-bay and per-rib arrays (`PerBayResults`).
        sensitivity: what held the design where it is (`sensitivity.sensitivity`, JSON-friendly): the
            shadow price of every active bound and limit (the rms change per unit of it) and each
            variable's window (the range within 1% of the optimum's rms, the others held), from the
            linearisation at the design; None for a single equilibrium, the objective "robust" and
            the method "root". Its ``solves`` are not among ``solves`` (the design's).
    """

    parameters: Parameters
    rms_error: float
    max_error: float
    initial_rms_error: float
    initial_max_error: float
    wing_solution: BaysSolution
    request: DesignRequest
    per_bay: PerBayResults
    history: list = field(default_factory=list)
    success: bool = False
    message: str = ""
    limits: LimitReport = field(default_factory=LimitReport)
    solves: int = 0
    wall_time: float = 0.0
    grid_change: dict | None = None
    wing: Wing | None = None
    sensitivity: dict | None = None

    @property
    def variables(self) -> tuple:
        """The optimised names (``request.variables``; empty for a single equilibrium)."""
        return self.request.variables

    @property
    def objective(self) -> str:
        """The objective asked (``request.objective``)."""
        return self.request.objective

    @property
    def method(self) -> str:
        """The method that ran (``request.method``'s shortcut); "" for a single equilibrium."""
        return "" if self.request.method is None else self.request.method.name

    @property
    def values(self) -> dict:
        """``{name: value}`` of every design parameter (`variables.VARIABLES`)."""
        return {name: getattr(self.parameters, name) for name in VARIABLES}

    @property
    def n_bays(self) -> int:
        return len(self.wing_solution.bays)

    @property
    def solution(self) -> Solution | BaysSolution:
        """One bay: its `Solution` at the design; a wing: the `BaysSolution` (``bay_solution(k)``)."""
        return self.wing_solution.bay_solution(0) if self.n_bays == 1 else self.wing_solution

    @property
    def bay_results(self) -> tuple:
        """``(n_bays,)`` `forward_solver.Result` names of the final solves."""
        return tuple(Result(int(r)).name for r in np.asarray(self.wing_solution.result))


#: The former limit fields of `DesignResult` and the `LimitReport` field each reads now: read-only
#: properties kept for one release (read ``result.limits`` instead).
FORMER_LIMIT_FIELDS = {"active_constraints": "active", "violated_constraints": "violated",
                       "violated_where": "violated_where", "violated_at_start": "violated_at_start",
                       "violated_at_start_where": "violated_at_start_where", "constraint_values": "values"}
for _former, _field in FORMER_LIMIT_FIELDS.items():
    setattr(DesignResult, _former, property(lambda self, name=_field: getattr(self.limits, name),
                                            doc=f"``limits.{_field}`` (the former field; kept for one release)."))


#: The wing's name of the result (one class for one bay and a wing).
WingDesignResult = DesignResult
