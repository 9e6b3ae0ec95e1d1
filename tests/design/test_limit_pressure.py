"""Tension limits are judged at the design's own pressure (inverse_design/constraints.py, docs/architecture.md,
"Limits at the design's own pressure").

The wrinkle floor's tolerance is a fraction of the tension scale ``p c / 2``; taken at the starting pressure
(10 kPa: 5 N/m) it let a 1 kPa design with a least tension of -2.3 N/m and 0.8% of its cells wrinkled pass
as "violated: none". A design reported wrinkle-free has no wrinkled cell in its own tension map.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from forward_solver import Parameters
from inverse_design.constraints import VIOLATION_TOLERANCE, Constraints, constraint_report, floor_threshold
from inverse_design.variables import DesignVariables


def test_a_wrinkle_free_floor_is_broken_by_any_negative_tension():
    design = DesignVariables.build(("pressure",), {"pressure": 1e3}, {"pressure": (5e2, 1e5)})
    at_design = Parameters(pressure=1e3, prestrain_span=0.02, prestrain_chord=0.02)
    scale = 0.5 * 1e3 * 1.0  # the design's own p c / 2: 500 N/m
    tensions = [np.array([120.0, 0.3 * -VIOLATION_TOLERANCE * scale, 800.0])]  # within the old tolerance
    _, violated, values, messages = constraint_report(Constraints(max_tension=float("inf")), design, at_design, tensions,
                                                      None, scale)
    assert values["min_tension"] < 0.0
    assert violated["min_tension"] == {0: pytest.approx(-values["min_tension"])}
    assert "the skin wrinkles" in messages[0]
    # a floor above zero keeps its tolerance, at the design's scale; a floor below zero too
    assert floor_threshold(100.0, scale) == pytest.approx(100.0 - VIOLATION_TOLERANCE * scale)
    assert floor_threshold(-5.0, scale) == pytest.approx(-5.0 - VIOLATION_TOLERANCE * scale)
    assert floor_threshold(0.0, scale) == 0.0


def test_the_reported_cut_pattern_design_is_wrinkle_free_or_a_failure_naming_the_amount(tmp_path, capsys):
    from inverse_design.app import cli

    out = tmp_path / "design"
    code = cli.main(["--n-span", "9", "--n-contour", "32", "--variables", "pressure,rib_thickness_scale,cut_pattern",
                     "--no-patterns", "--no-figures", "--out", str(out)])
    printed = "".join(capsys.readouterr())
    summary = json.loads((out / "summary.json").read_text())
    wrinkled = np.load(out / "equilibrium.npz")["wrinkled"]
    least = summary["constraints"]["values"]["min_tension"]
    if "min_tension" in summary["constraints"]["violated"]:
        assert code != 0
        assert summary["constraints"]["violated"]["min_tension"] == pytest.approx(-least)
        assert f"smallest fibre tension is {least:.4g} N/m" in printed
    else:
        assert not wrinkled.any() and least >= 0.0
