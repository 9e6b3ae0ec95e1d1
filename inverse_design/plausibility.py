"""Plausibility of a design's inputs: the ranges the model and its validation cover.

The solver runs far outside these ranges (an 80% prestrain, a 100 m bay) and
may converge, but nothing has checked that its answer means anything there:
the membrane law of eq. 10 assumes small strains, and the validation cases
and the random-scene stress test (docs/validation.md;
``tests/reliability/test_stress.py``) cover:

=====================  =================  ====================================
quantity               range              from
=====================  =================  ====================================
pressure               1e2 to 2e5 Pa      stress test (1e2-2e5 Pa)
fibre stiffnesses      1e4 to 1e6 N/m     stress test
stiffness ratio        0.1 to 10          stress test (span over chord)
prestrains             -2% to 5%          stress test; the command's bounds
rib spacing            0.05 to 0.5 m      stress test (chord 1 m)
rib spacing / chord    0.05 to 0.5        stress test (chord 1 m)
=====================  =================  ====================================

Beside the physical ranges, `check_plausibility` flags the numerical and
drawing choices that make a result doubtful (`LIMITS`): a design on fewer
span nodes than the grid study of docs/design_studies.md found enough (17: on 9 span nodes
the default design lands at 6.4 kPa and rib scale 0.945 against 1 kPa and
1.0 on 17 or more, a spurious compression beside the ribs that the wrinkle
constraint obeys; docs/design_studies.md, "The default case on several grids"); a seam allowance over
50 mm (a typo for metres or centimetres more likely than a seam); more
cut-pattern or rib-shape terms than a quarter of the contour nodes (each
term then spans fewer than about four nodes: the grid cannot resolve it);
a Reynolds number outside NeuralFoil's training data (its XFoil runs drew
Re = 10^(5.5 + 1.5 N(0, 1)), NeuralFoil's
``training/gen2_architecture/training_data/generate_xfoil_data.py``, and
its input scaling ``(ln Re - 12.5) / 3.5``: two standard deviations are
3e2 to 3e8).

`check_plausibility` compares the starting values (and the bounds the
optimiser may move them to) with `RANGES` and returns one line per value
outside; by default it also issues each as a `PlausibilityWarning`
(``warnings.warn``), so library callers can filter or escalate them. It never
prints and never refuses: the command shows the lines and records them in
``summary.json`` under ``warnings``.
"""

from __future__ import annotations

import math
import warnings
from typing import Mapping, Sequence

__all__ = ["LIMITS", "PlausibilityWarning", "RANGES", "check_plausibility"]


class PlausibilityWarning(UserWarning):
    """An input lies outside the ranges the model and its validation cover (`RANGES`)."""


#: ``{quantity: (low, high, unit)}``: what the validation and the stress test cover (module docstring).
RANGES = {
    "pressure": (1e2, 2e5, "Pa"),
    "stiffness": (1e4, 1e6, "N/m"),
    "stiffness_ratio": (0.1, 10.0, ""),
    "prestrain": (-0.02, 0.05, ""),
    "rib_spacing": (0.05, 0.5, "m"),
    "rib_spacing_over_chord": (0.05, 0.5, ""),
}

#: The numerical and drawing limits of the module docstring: least span nodes of a design, largest seam
#: allowance (mm), most terms of a cut pattern or rib shape per contour node, and the Reynolds numbers of
#: NeuralFoil's training data.
LIMITS = {
    "n_span": 17,
    "seam_allowance_mm": 50.0,
    "terms_per_contour_node": 0.25,
    "reynolds": (10**2.5, 10**8.5),
}

_COVERED = "outside the range the model is validated for"


def _fmt(value: float, unit: str) -> str:
    text = f"{value:.4g}"
    return f"{text} {unit}" if unit else text


def _outside(quantity: str, value: float) -> bool:
    low, high, _ = RANGES[quantity]
    return not (math.isfinite(value) and low <= value <= high)


def _range(quantity: str) -> str:
    low, high, unit = RANGES[quantity]
    if quantity == "prestrain":
        return f"{low:.0%} to {high:.0%}"
    return f"{_fmt(low, '')} to {_fmt(high, unit)}"


def _value(quantity: str, value: float) -> str:
    return f"{value:.4g} ({value:.0%})" if quantity == "prestrain" else _fmt(value, RANGES[quantity][2])


def check_plausibility(fabric, parameters, bays: Sequence, bounds: Mapping | None = None, *,
                       grid: tuple[int, int] | None = None, design: bool = True,
                       seam_allowance_mm: float | None = None, terms: Mapping | None = None,
                       reynolds: float | None = None, warn: bool = True) -> list[str]:
    """Lines for every input outside the covered ranges (`RANGES`); none for the default case.

    Args:
        fabric: the `forward_solver.Fabric` (its stiffnesses, unless
            ``parameters`` sets them).
        parameters: the starting `forward_solver.Parameters`, or a mapping
            with ``pressure``, ``prestrain_span``, ``prestrain_chord`` (and
            optionally ``stiffness_span``, ``stiffness_chord``).
        bays: ``(rib_spacing_m, chord_m)`` of each bay: one pair for a single
            bay; for a wing, each bay's rib spacing and mean chord.
        bounds: ``{name: (low, high)}`` of the optimised variables: a bound of
            the pressure or a prestrain outside its range is reported too (the
            design may land there).
        grid: ``(n_span, n_contour)`` of the design's grid (None: not checked).
        design: whether the grid is that of a design (its optimum depends on
            the span nodes, `LIMITS`) rather than of one equilibrium.
        seam_allowance_mm: the patterns' seam allowance, mm (None: not checked).
        terms: ``{"cut_pattern" or "rib_shape": terms per direction or surface}``
            of the fields designed (needs ``grid``).
        reynolds: the chord Reynolds number of the aerodynamic comparison (None: none).
        warn: also issue each line as a `PlausibilityWarning`.

    Returns:
        One line per finding (empty when every input is covered).
    """
    get = parameters.get if isinstance(parameters, Mapping) else (lambda name: getattr(parameters, name, None))
    lines = []

    def check(quantity: str, label: str, value) -> None:
        if value is not None and _outside(quantity, float(value)):
            lines.append(f"{label} {_value(quantity, float(value))} lies {_COVERED} "
                         f"({_range(quantity)}); check the value, or treat the result as unvalidated")

    check("pressure", "pressure", get("pressure"))
    for name in ("prestrain_span", "prestrain_chord"):
        check("prestrain", name.replace("_", " "), get(name))
    stiffness = {}
    for name in ("stiffness_span", "stiffness_chord"):
        value = get(name)
        stiffness[name] = float(getattr(fabric, name) if value is None else value)
        check("stiffness", name.replace("_", " "), stiffness[name])
    if stiffness["stiffness_chord"] > 0:
        check("stiffness_ratio", "stiffness ratio span/chord",
              stiffness["stiffness_span"] / stiffness["stiffness_chord"])
    for name, (low, high) in dict(bounds or {}).items():
        quantity = "pressure" if name == "pressure" else "prestrain" if name.startswith("prestrain") else None
        if quantity is None:
            continue
        outside = [b for b in (float(low), float(high)) if _outside(quantity, b)]
        if outside:
            lines.append(f"{name.replace('_', ' ')} bounds {_value(quantity, float(low))} to "
                         f"{_value(quantity, float(high))} reach {_COVERED} ({_range(quantity)}): the design "
                         "may land there; narrow the bounds, or treat the result as unvalidated")
    several = len(bays) > 1
    for k, (spacing, chord) in enumerate(bays):
        where = f"bay {k}: " if several else ""
        check("rib_spacing", f"{where}rib spacing", spacing)
        if chord > 0:
            check("rib_spacing_over_chord", f"{where}rib spacing / chord", float(spacing) / float(chord))
    if grid is not None and design and grid[0] < LIMITS["n_span"]:
        lines.append(f"the design grid has {grid[0]} span nodes, fewer than the {LIMITS['n_span']} that the "
                     "grid study found enough (on 9 the default design lands at 6.4 kPa and rib scale 0.945 "
                     f"against 1 kPa and 1.0 on 17 or more; docs/design_studies.md): design on n_span "
                     f"{LIMITS['n_span']} or more, or refine the design on a finer grid (refine_design)")
    if seam_allowance_mm is not None and seam_allowance_mm > LIMITS["seam_allowance_mm"]:
        lines.append(f"seam allowance {seam_allowance_mm:g} mm is more than {LIMITS['seam_allowance_mm']:g} mm: "
                     "the value is in millimetres; check it")
    for name, count in dict(terms or {}).items():
        if grid is not None and count > LIMITS["terms_per_contour_node"] * grid[1]:
            lines.append(f"{name.replace('_', ' ')} of {count} terms on {grid[1]} contour nodes: more than a "
                         f"quarter of the nodes ({LIMITS['terms_per_contour_node'] * grid[1]:g}), so each term "
                         f"spans fewer than 4 nodes and the grid cannot resolve it; give {name} terms "
                         f"{int(LIMITS['terms_per_contour_node'] * grid[1])} or fewer, or more contour nodes "
                         "(n_contour)")
    low, high = LIMITS["reynolds"]
    if reynolds is not None and not low <= reynolds <= high:
        lines.append(f"Reynolds number {reynolds:.3g} lies outside NeuralFoil's training data ({low:.1g} to "
                     f"{high:.1g}): its lift, drag and moment there are extrapolated; treat them as unvalidated")
    if warn:
        for line in lines:
            warnings.warn(line, PlausibilityWarning, stacklevel=2)
    return lines
