"""What the report measures of a design beyond the result's own numbers: the wing against its row targets.

Every bay's rows are measured against their targets blended between the
bay's two ribs at the local chord (`inverse_design.objectives.row_targets`,
`local_chords`), as the design's objective measures them: the deviation of
every node (`wing_deviation`, the one deviation of the report: ``wing.npz``,
``equilibrium.npz``, the deviation figures), the mid-bay sections' errors
(`mid_bay_errors`) and their noses' recession (`le_recessions`). Measured in
float64 whatever the caller's JAX configuration (a thread-local scope).
"""

from __future__ import annotations

import jax
import numpy as np

from ..objectives import bay_distances, distance_errors, local_chords, row_targets, same_section

__all__ = ["chords_and_stations", "le_recessions", "mid_bay_errors", "mid_bay_targets", "wing_deviation",
           "wing_nodes"]


def chords_and_stations(result) -> tuple:
    """The ribs' chords and span stations, m."""
    return tuple(result.wing.chords), tuple(result.wing.stations)


def mid_bay_targets(result) -> list:
    """Each bay's target at mid-bay: its two ribs' targets blended at the local chord
    (`objectives.row_targets`; the rib's own when both ribs have the same target)."""
    out = []
    for k, bay in enumerate(result.wing_solution.bays):
        root, tip = result.per_bay.targets[k], result.per_bay.targets[k + 1]
        out.append(root if same_section(root, tip) else
                   row_targets(root, tip, bay.chord_root, bay.chord_tip, [0.5])[0])
    return out


def _bay_deviation(result, k: int, etas) -> np.ndarray:
    """``(len(etas), n_contour)`` signed distances of bay ``k``'s rows at ``etas`` from their targets."""
    sol, targets = result.wing_solution, result.per_bay.targets
    bay = sol.bays[k]
    with jax.enable_x64(True):
        rows = row_targets(targets[k], targets[k + 1], bay.chord_root, bay.chord_tip, etas)
        return np.asarray(bay_distances(np.asarray(sol.nodes[k]), rows, etas, local_chords(bay, etas)))


def wing_deviation(result) -> np.ndarray:
    """``(n_bays, n_span, n_contour)`` signed normal distance of every node from its row's target,
    fractions of the local chord (positive outside; `objectives` module docstring)."""
    return np.stack([_bay_deviation(result, k, np.linspace(0.0, 1.0, bay.n_span))
                     for k, bay in enumerate(result.wing_solution.bays)])


def mid_bay_errors(result) -> dict:
    """RMS (weighted by bay area) and largest distance of the bays' mid-bay sections from their targets."""
    rms, largest = zip(*(distance_errors(_bay_deviation(result, k, np.array([0.5])), "mid_bay")
                         for k in range(result.n_bays)))
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
