"""What held a design where it is: the shadow price of every active bound and limit, and each variable's window.

At the end of a design (`optimise.optimise_wing`, `optimise_pressure`,
`refine_design`), from the linearisation at the design
(`problem.DesignProblem.linearisation`: the shape residuals ``r``, whose
``f = r . r`` is the mean square distance, rms ``= sqrt(f)``, their Jacobian
``J`` in the scaled variables ``u``, the limit rows ``g >= 0`` and their
Jacobian ``G``; Gauss-Newton's last one, else one more wing solve and its
Jacobian, not a design).

**Multipliers.** The design solves ``min f(u)`` subject to
``lower <= u <= upper`` and ``g(u) >= 0``. At its optimum the KKT conditions
hold: ``grad f = 2 J^T r = sum_lower mu_i e_i - sum_upper nu_i e_i +
sum_rows lambda_j grad g_j`` with every multiplier ``>= 0`` and zero off the
active set. So the multipliers are the non-negative coefficients that
express ``grad f`` in the active constraints' gradients: the non-negative
least squares (`scipy.optimize.nnls`) of ``grad f`` on the columns ``e_i``
(active lower bounds), ``-e_i`` (upper) and ``grad g_j`` (active rows). Where
the active gradients are independent (a vertex of bounds, a few cells at a
limit) the solution is the unique multiplier vector; its residual, relative
to ``2 |r| |J|_F``, is the design's distance from stationarity (``stationarity``:
a converged design leaves about 1e-3 or less; a large one says the prices
are rough).

**Shadow prices.** By the envelope theorem the optimum's ``f*`` moves with a
constraint's right-hand side at the rate of its multiplier: raising a lower
bound of ``u_i`` raises ``f*`` by ``mu_i`` per scaled unit, raising an upper
bound lowers it by ``nu_i``; a tension floor's rows are ``(T - floor) / s``
(``s`` the rows' tension scale, `problem.DesignProblem.tension_scale`, ``p c / 2`` at the start), so
raising the floor by 1 N/m raises ``f*`` by ``sum_j lambda_j / s`` over its
active cells, and a ceiling the opposite; a rib thickness row is
``(t - m t0) / unit``, so raising ``min_thickness`` by one raises ``f*`` by
``sum_j lambda_j t0_j / unit_j``; a curvature row ``1 -+ kappa r_min`` at its
limit (``kappa r_min = +-1``) gives ``sum_j lambda_j / r_min``. A bound
shared by a vector variable's components (``rib_shape``, ``cut_pattern``)
moves all of them: its price is their sum. Then ``d rms = d f / (2 rms)``.
Each price is given per `UNITS` of the bound (per kPa of a pressure bound,
1% of a prestrain, 0.01 of a rib scale, 1 N/m of a tension limit, ...) as
``d_rms``, the rms change when the bound is raised by one unit: positive
for a lower bound, a floor and a rib limit (raising them costs accuracy),
negative for an upper bound and a ceiling; ``relaxed_gain = |d_rms|`` is
what relaxing it by one unit (lowering a lower bound or floor, raising an
upper bound or ceiling) gains at first: a rate at the design, which flattens
as the design moves (relaxing a bound alone never gains more than the
window's ``free_gain``, below).

**Windows.** For each design variable (each component of a vector one), the
range over which the rms stays within `WINDOW` (1%) of the optimum's, with
every other variable held as designed (how far the shop may miss this one
setting), from the same Gauss-Newton model ``f(u + t e_i) ~ |r + t J e_i|^2``,
clipped to the bounds and to the linearised limit rows ``g + t G e_i >= 0``;
each end says what ended it (``"rms"``, ``"lower bound"``, ``"upper bound"``
or a limit's name). A variable at a bound is *decided by the bound* when
freeing it alone from that bound (the model's minimum beyond it) would lower
the rms by less than 1%: the objective is flat there and the bound, not the
physics, picked the value; otherwise the bound *holds it back*.

For the objective "worst", ``r`` is each bay's worst row (SLSQP minimises a
smooth maximum of the rows: where two rows tie, ``stationarity`` says how
rough the prices are). Not for the objective "robust" (its ``r . r`` majorises a quantile, not the
mean square) nor the method "root" (a root of a condition, not a minimum of
the rms), nor a single equilibrium: `sensitivity` returns None.
"""

from __future__ import annotations

import math
import time

import numpy as np
import scipy.optimize
import scipy.sparse

from .constraints import ACTIVE_TOLERANCE

__all__ = ["UNITS", "WINDOW", "WIDE_WINDOW", "sensitivity"]

#: The rms may grow by this fraction of the optimum's inside a design window.
WINDOW = 0.01
#: A window is wide when it spans more than this fraction of its bound interval or of the design value,
#: whichever is smaller (a pressure's interval spans decades: 1 to 1.4 kPa is wide in 1 to 100 kPa).
WIDE_WINDOW = 0.2
#: Per what a price is given: ``{variable or limit: (words, size in its own unit)}``.
UNITS = {
    "pressure": ("1 kPa", 1e3), "prestrain_span": ("1% prestrain", 0.01), "prestrain_chord": ("1% prestrain", 0.01),
    "cut_pattern": ("1% prestrain", 0.01), "rib_thickness_scale": ("0.01", 0.01), "rib_chord_scale": ("0.01", 0.01),
    "rib_shape": ("0.01 chord", 0.01), "min_tension": ("1 N/m", 1.0), "max_tension": ("1 N/m", 1.0),
    "rib_min_thickness": ("0.01 of the starting thickness", 0.01), "rib_min_radius": ("0.001 chord", 1e-3),
}
#: The unit of each variable's value (and window) in the record.
_VALUE_UNITS = {"pressure": "Pa", "prestrain_span": "fraction", "prestrain_chord": "fraction",
                "cut_pattern": "fraction (local prestrain)", "rib_thickness_scale": "", "rib_chord_scale": "",
                "rib_shape": "chord"}


def sensitivity(problem, u, active: list, parameters, rib_shapes=None, cut_patterns=None) -> dict | None:
    """The shadow prices of the active bounds and limits and the design windows at the design ``u``
    (module docstring), as a JSON-friendly record; None for the objective "robust".

    Args:
        problem: the design's `problem.DesignProblem`.
        u: the design's scaled vector.
        active: the active bounds and limits (`result.LimitReport.active`'s names).
        parameters: the design's shared `forward_solver.Parameters`.
        rib_shapes, cut_patterns: its per-rib shapes and per-bay fields, if any.

    Returns:
        ``{"rms", "prices": [...], "windows": [...], "stationarity", "solves", "seconds", ...}``:
        ``prices`` one entry per active bound (a vector variable's components at one bound
        together) and limit: ``name``, ``kind`` ("bound" or "limit"), ``variable`` or ``limit``,
        ``side`` ("lower" or "upper"), ``value`` (the bound or limit, its own unit), ``unit``,
        ``per`` (the unit of the price), ``d_rms`` (the rms change, fraction of the chord, when the
        bound is raised by ``per``), ``relaxed_gain``, ``percent`` (``relaxed_gain`` against the rms)
        and ``components`` or ``rows``; ``windows`` one per scalar component: ``name``, ``variable``,
        ``value``, ``unit``, ``low``, ``high``, ``low_end``, ``high_end`` (what ends each side: "rms",
        "lower bound", "upper bound" or a limit), ``bounds``, ``fraction_of_bounds``, ``wide``
        (`WIDE_WINDOW`), ``at_bound`` (the side of a bound that holds it, with a positive multiplier;
        None), ``free_gain`` (the rms's relative fall if freed from that bound) and
        ``decided_by_bound`` (``free_gain`` under `WINDOW`). ``stationarity``: the KKT balance's
        residual; ``solves`` and ``seconds``: what the record cost (no solve after Gauss-Newton).

    Raises:
        BaysConvergenceError: if the linearisation's solve (methods other than Gauss-Newton) fails.
    """
    if problem.robust is not None:
        return None
    start = time.perf_counter()
    r, jr, g, jg, solves = problem.linearisation(u)
    r = np.asarray(r, np.float64)
    f = float(r @ r)
    rms = math.sqrt(f)
    jr = scipy.sparse.csc_matrix(jr)
    jg = scipy.sparse.csc_matrix(jg) if np.size(g) else scipy.sparse.csc_matrix((0, jr.shape[1]))
    g = np.asarray(g, np.float64)
    gradient = 2.0 * np.asarray(jr.T @ r).reshape(-1)
    squares = np.asarray(jr.multiply(jr).sum(axis=0)).reshape(-1)
    components = list(problem.variables.components(parameters, rib_shapes, cut_patterns))
    scales = np.concatenate([np.full(part.stop - part.start, problem.variables.scale(n))
                             for n, part in problem.variables.slices().items()])
    columns, prices = _constraints(problem, active, components, g, jg)
    multipliers, stationarity = _multipliers(columns, gradient, rms, squares)
    priced = [_price(entry, multipliers, scales, rms) for entry in prices]
    # A variable sits at its bound where the bound holds it (a positive multiplier), not merely within the
    # active tolerance of it (1e-3 of a pressure interval of 1 to 100 kPa is 99 Pa).
    sides = {k: entry["side"] for entry in prices if entry["kind"] == "bound"
             for k, column in zip(entry["indices"], entry["columns"]) if multipliers[column] > 0}
    names = _limit_names(problem, g.size)
    windows = [_window(component, scales[k], 0.5 * float(gradient[k]), float(squares[k]), f, g, jg[:, k], names,
                       sides.get(k)) for k, component in enumerate(components)]
    return {"rms": rms, "unit": "fraction of the local chord", "window": WINDOW,
            "model": "Gauss-Newton: f(u + d) ~ |r + J d|^2 at the design; windows with the other variables held",
            "convention": "d_rms: the rms change when the bound or limit is raised by one 'per'; relaxing it by "
                          "one (lowering a lower bound, floor or rib limit, raising an upper bound or ceiling) "
                          "lowers the rms by relaxed_gain",
            "prices": priced, "windows": windows, "stationarity": stationarity,
            "solves": int(solves), "seconds": time.perf_counter() - start}


def _constraints(problem, active: list, components: list, g, jg) -> tuple[list, list]:
    """The active constraints' gradient columns (scaled variables) and one entry per priced constraint
    (the columns it owns), from the names of ``active``."""
    n = len(components)
    index = {label: k for k, (label, *_rest) in enumerate(components)}
    columns, entries, grouped = [], [], {}
    for name in active:
        label, side = _bound_of(name)
        if label in index:
            k = index[label]
            variable = label.split("[")[0]
            entry = grouped.get((variable, side))
            if entry is None:
                bound = components[k][2] if side == "lower" else components[k][3]
                entry = grouped[(variable, side)] = {
                    "kind": "bound", "name": f"{variable}{'>=lower' if side == 'lower' else '<=upper'}",
                    "variable": variable, "side": side, "value": bound, "columns": [], "indices": []}
                entries.append(entry)
            column = np.zeros(n)
            column[k] = 1.0 if side == "lower" else -1.0
            entry["columns"].append(len(columns))
            entry["indices"].append(k)
            columns.append(column)
    for limit, rows, weights, value in _limit_rows(problem, active, g):
        entry = {"kind": "limit", "name": limit, "limit": limit, "value": value,
                 "side": "upper" if limit == "max_tension" else "lower", "columns": [], "weights": weights,
                 "rows": int(rows.size)}
        for j in rows:
            entry["columns"].append(len(columns))
            columns.append(np.asarray(jg[j, :].toarray(), np.float64).reshape(-1))
        entries.append(entry)
    return columns, entries


def _bound_of(name: str) -> tuple[str, str]:
    """``("pressure", "lower")`` of an active name ``"pressure>=lower"`` (``("", "")`` for a limit)."""
    for suffix, side in ((">=lower", "lower"), ("<=upper", "upper")):
        if name.endswith(suffix):
            return name[:-len(suffix)], side
    return "", ""


def _row_blocks(problem, n_rows: int) -> list:
    """``(limit, rib, rows, geometry)`` of each block of the constraint vector (`problem.DesignProblem`:
    each tension limit's rows over every cell, then each rib's thickness and curvature rows; ``rib`` and
    its `rib_design.RibGeometry` None for a tension limit)."""
    blocks, offset = [], 0
    if problem.tension is not None:
        names = problem.tension.names(problem.fabric)
        per = (n_rows - sum(_rib_size(geometry) for _, geometry in problem.ribs)) // max(len(names), 1)
        for name in names:
            blocks.append((name, None, np.arange(offset, offset + per), None))
            offset += per
    for rib, geometry in problem.ribs:
        thickness, curvature = geometry.upper.size, _rib_size(geometry) - geometry.upper.size
        blocks.append(("rib_min_thickness", rib, np.arange(offset, offset + thickness), geometry))
        blocks.append(("rib_min_radius", rib, np.arange(offset + thickness, offset + thickness + curvature), geometry))
        offset += thickness + curvature
    return blocks


def _rib_size(geometry) -> int:
    """Rows of one rib's limits (`rib_design.RibGeometry.functions`): thickness, then two per inner point."""
    return geometry.upper.size + 2 * (geometry.x.size - 2)


def _limit_names(problem, n_rows: int) -> np.ndarray:
    """The limit each constraint row belongs to (``"min_tension"``, ``"rib_min_radius"``, ...)."""
    names = np.empty(n_rows, dtype=object)
    for limit, _, rows, _ in _row_blocks(problem, n_rows):
        names[rows] = limit
    return names


def _limit_rows(problem, active: list, g) -> list:
    """``(limit, rows, weights, value)`` of every active tension or rib limit (each rib's own rows
    joined under one name): its rows within `constraints.ACTIVE_TOLERANCE` of its least row, per row
    ``-d g_j / d limit`` (how far ``f*`` moves per unit multiplier when the limit is raised by one of
    its own units: module docstring), and the limit's value."""
    out = {}
    one = len(problem.ribs) == 1
    for limit, rib, rows, geometry in _row_blocks(problem, g.size):
        if not rows.size or (limit if rib is None or one else f"{limit}@rib {rib}") not in active:
            continue
        near = g[rows] <= np.min(g[rows]) + ACTIVE_TOLERANCE
        if limit == "min_tension":  # rows (T - floor) / s
            weights, value = np.full(rows.size, 1.0 / problem.tension_scale), problem.tension.min_tension
        elif limit == "max_tension":  # rows (ceiling - T) / s
            weights, value = np.full(rows.size, -1.0 / problem.tension_scale), problem.tension.ceiling(problem.fabric)
        elif limit == "rib_min_thickness":  # rows (t - m t0) / unit
            weights, value = geometry.thickness0 / geometry.thickness_unit, geometry.limits.min_thickness
        else:  # rows 1 -+ kappa r_min, at their limit where kappa r_min = +-1
            weights, value = np.full(rows.size, 1.0 / geometry.min_radius), geometry.min_radius
        joined = out.setdefault(limit, [np.zeros(0, int), np.zeros(0), value])
        joined[0] = np.concatenate([joined[0], rows[near]])
        joined[1] = np.concatenate([joined[1], weights[near]])
    return [(limit, rows, weights, value) for limit, (rows, weights, value) in out.items()]


def _multipliers(columns: list, gradient, rms: float, squares) -> tuple[np.ndarray, float]:
    """The non-negative multipliers of the active constraints' ``columns`` that balance ``gradient``
    (``grad f``; module docstring), and the balance's residual against ``2 |r| |J|_F``."""
    scale = 2.0 * rms * math.sqrt(float(np.sum(squares))) or 1.0
    if not columns:
        return np.zeros(0), float(np.linalg.norm(gradient)) / scale
    a = np.stack(columns, axis=1)
    multipliers, residual = scipy.optimize.nnls(a, gradient, maxiter=50 * max(a.shape))
    return multipliers, float(residual) / scale


def _price(entry: dict, multipliers, scales, rms: float) -> dict:
    """The record of one priced bound or limit (module docstring)."""
    ours = multipliers[entry["columns"]]
    if entry["kind"] == "bound":
        # d f*/d bound: +mu (lower) or -nu (upper) per scaled unit; the bound's unit is the variable's scale.
        sign = 1.0 if entry["side"] == "lower" else -1.0
        d_f = sign * float(np.sum(ours / scales[entry["indices"]]))
        words, size = UNITS[entry["variable"]]
        extra = {"variable": entry["variable"], "components": len(entry["indices"]),
                 "unit": _VALUE_UNITS[entry["variable"]]}
    else:
        d_f = float(np.sum(ours * entry["weights"]))
        words, size = UNITS[entry["limit"]]
        extra = {"limit": entry["limit"], "rows": entry["rows"],
                 "unit": "N/m" if entry["limit"].endswith("tension") else
                 ("fraction of the starting thickness" if entry["limit"] == "rib_min_thickness" else "chord")}
    d_rms = d_f * size / (2.0 * rms) if rms > 0 else 0.0
    return {"name": entry["name"], "kind": entry["kind"], "side": entry["side"], "value": entry["value"], **extra,
            "per": words, "d_rms": d_rms, "relaxed_gain": abs(d_rms),
            "percent": 100.0 * abs(d_rms) / rms if rms > 0 else 0.0}


def _window(component: tuple, scale: float, slope: float, curvature: float, f: float, g, column, limit_names,
            at_bound: str | None) -> dict:
    """One component's design window (module docstring): ``f(t) = f + 2 slope t + curvature t^2`` along
    its scaled variable (``slope = r . J e_i``, ``curvature = |J e_i|^2``), at most ``(1 + WINDOW)^2 f``,
    clipped to its bounds and to the linearised rows ``g + t column >= 0`` (``limit_names``: each row's
    limit); ``at_bound``: the side of the bound that holds it, or None."""
    label, value, lower, upper = component
    variable = label.split("[")[0]
    delta = ((1.0 + WINDOW) ** 2 - 1.0) * f
    root = math.sqrt(slope * slope + curvature * delta)
    # The two roots of f(t) = (1 + WINDOW)^2 f, in the forms that do not cancel (inf where f stays below).
    with np.errstate(divide="ignore"):
        t_high = delta / (slope + root) if slope + root > 0 else math.inf
        t_low = -delta / (root - slope) if root - slope > 0 else -math.inf
    ends = {"low": (value + t_low * scale, "rms"), "high": (value + t_high * scale, "rms")}
    if ends["low"][0] <= lower:
        ends["low"] = (lower, "lower bound")
    if ends["high"][0] >= upper:
        ends["high"] = (upper, "upper bound")
    rows = column.nonzero()[0]
    if rows.size:
        b = np.asarray(column[rows].toarray(), np.float64).reshape(-1)
        room = np.maximum(g[rows], 0.0)
        for side, sign in (("high", 1.0), ("low", -1.0)):
            falling = sign * b < 0  # rows that this direction brings towards their limit
            if np.any(falling):
                reach = room[falling] / np.abs(b[falling])
                j = int(np.argmin(reach))
                edge = value + sign * float(reach[j]) * scale
                inside = 1e-9 * (upper - lower)  # (a row at its limit where a bound already ends it: the bound)
                if (edge < ends["high"][0] - inside) if side == "high" else (edge > ends["low"][0] + inside):
                    ends[side] = (edge, str(limit_names[rows[falling][j]]))
    free_gain = 0.0
    if at_bound is not None and curvature > 0:
        free_gain = 1.0 - math.sqrt(max(f - slope * slope / curvature, 0.0) / f) if f > 0 else 0.0
    width = upper - lower
    span = ends["high"][0] - ends["low"][0]
    # Wide against the bound interval, or against the value where the interval spans decades (pressure).
    wide = bool(span > WIDE_WINDOW * (min(width, abs(value)) if value else width))
    return {"name": label, "variable": variable, "value": value, "unit": _VALUE_UNITS[variable],
            "low": ends["low"][0], "high": ends["high"][0], "low_end": ends["low"][1], "high_end": ends["high"][1],
            "bounds": [lower, upper], "fraction_of_bounds": span / width, "wide": wide,
            "at_bound": at_bound, "free_gain": free_gain,
            "decided_by_bound": at_bound is not None and free_gain < WINDOW}
