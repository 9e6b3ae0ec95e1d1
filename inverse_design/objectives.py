"""Distances between the inflated skin and the target profile."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["SectionErrors", "section_errors"]


class SectionErrors(NamedTuple):
    """Normal distance of one section from the target, in fractions of chord."""

    distance: np.ndarray  # (n_contour,) signed, positive outside the target
    rms: float
    max: float  # largest absolute distance


def section_errors(solution, target, chord: float, eta: float = 0.5) -> SectionErrors:
    """Signed normal distance of the section at ``y = eta * rib_spacing`` from the target.

    Args:
        solution: a `forward_solver.Solution`.
        target: a `targets.Airfoil` (chord-normalised).
        chord: the chord the target is scaled to, m.
        eta: span station as a fraction of the rib spacing (0.5 is mid-bay).

    Returns:
        `SectionErrors` in fractions of chord.
    """
    points = solution.section(eta) / chord
    distance = np.asarray(target.distance(points), dtype=np.float64)
    return SectionErrors(distance, float(np.sqrt(np.mean(distance**2))), float(np.max(np.abs(distance))))
