"""What the report measures of a design beyond the result's own numbers: the wing against its row targets.

Every bay's rows are measured against their targets blended between the
bay's two ribs at the local chord (`inverse_design.objectives.WingTargets`),
as the design's objective measures them: the deviation of
every node (`wing_deviation`, the one deviation of the report: ``wing.npz``,
``equilibrium.npz``, the deviation figures), the mid-bay sections' errors
(`mid_bay_errors`) and their noses' recession (`le_recessions`).
"""

from __future__ import annotations

import numpy as np

from ..objectives import WingTargets, distance_errors

__all__ = ["chords_and_stations", "le_recessions", "mid_bay_errors", "mid_bay_targets", "wing_deviation",
           "wing_nodes"]


def chords_and_stations(result) -> tuple:
    """The ribs' chords and span stations, m."""
    return tuple(result.wing.chords), tuple(result.wing.stations)


def mid_bay_targets(result) -> list:
    """Each bay's target at mid-bay (`inverse_design.objectives.WingTargets.mid_bay_targets`)."""
    return WingTargets(result.wing_solution.bays, result.per_bay.targets, "mid_bay").mid_bay_targets()


def wing_deviation(result) -> np.ndarray:
    """``(n_bays, n_span, n_contour)`` signed normal distance of every node from its row's target,
    fractions of the local chord (positive outside; `WingTargets.deviation` of every row)."""
    sol = result.wing_solution
    return np.stack(WingTargets(sol.bays, result.per_bay.targets, "average").deviation(sol.nodes))


def mid_bay_errors(result) -> dict:
    """RMS (weighted by bay area) and largest distance of the bays' mid-bay sections from their targets."""
    sol = result.wing_solution
    distances = WingTargets(sol.bays, result.per_bay.targets, "mid_bay").deviation(sol.nodes)
    rms, largest = zip(*(distance_errors(d, "mid_bay") for d in distances))
    weights = np.asarray(result.per_bay.weights, np.float64)
    return {"rms": float(np.sqrt(np.sum(weights * np.square(rms)))), "max": float(np.max(largest))}


def le_recessions(result) -> np.ndarray:
    """``(n_bays,)`` how far each bay's mid-bay section's nose lies behind its target's (positive: pulled
    back by the prestressed skin), in fractions of the bay's chord at mid-bay."""
    sol = result.wing_solution
    out = []
    for k, (bay, target) in enumerate(zip(sol.bays, mid_bay_targets(result))):
        nodes = np.asarray(sol.nodes[k])
        s = 0.5 * (nodes.shape[0] - 1)  # (the mid-bay row, interpolated on an even n_span: Solution.section)
        i0 = min(int(np.floor(s)), nodes.shape[0] - 2)
        row = (1.0 - (s - i0)) * nodes[i0] + (s - i0) * nodes[i0 + 1]
        out.append(float(np.min(row[:, 0])) / (0.5 * (bay.chord_root + bay.chord_tip)) - float(np.min(target.x)))
    return np.array(out)


def wing_nodes(result) -> np.ndarray:
    """``(n_bays (n_span - 1) + 1, n_contour, 3)`` m: the bays joined at their shared ribs, y the
    span station (`forward_solver.Wing.stations`)."""
    sol = result.wing_solution
    stations = np.asarray(chords_and_stations(result)[1], np.float64)
    parts = []
    for k in range(len(sol.bays)):
        nodes = np.array(sol.nodes[k], dtype=np.float64)
        nodes[..., 1] += stations[k]
        parts.append(nodes if k == 0 else nodes[1:])  # the first row is the previous bay's tip rib
    return np.concatenate(parts)
