"""A wing with a cut field per bay: one overview figure of every bay's field (`plots.plot_cut_fields`)."""

import json

import numpy as np

from inverse_design.app import cli, plots

CASE = """
variables = ["pressure", "rib_thickness_scale", "cut_pattern"]
cut-pattern-layout = "per_bay"
cut-pattern-terms = 4
pressure = 3e4
n-span = 5
n-contour = 32
max-iterations = 2
[[rib]]
section = "naca2412"
chord = 1.0
station = 0.0
[[rib]]
section = "naca2412"
chord = 0.9
station = 0.25
[[rib]]
section = "naca2412"
chord = 0.8
station = 0.5
"""


def test_the_overview_shows_each_bay_and_fibre_on_one_scale():
    # 40 bays of 32 nodes, the span field rising with the bay and the contour field with the arc:
    # each image holds its own field, bays on the vertical axis, both on one colour scale.
    arc = np.tile(np.linspace(0.0, 1.0, 32, endpoint=False), (40, 1))
    span = np.repeat(np.linspace(0.01, 0.03, 40)[:, None], 32, axis=1)
    contour = 0.02 + 0.01 * np.sin(2 * np.pi * arc)
    fig = plots.plot_cut_fields(arc, span, contour, leading_edge=0.5)
    images = [ax.collections[0] for ax in fig.axes[:2]]
    assert [ax.get_title() for ax in fig.axes[:2]] == ["span fibres", "contour fibres"]
    np.testing.assert_array_equal(images[0].get_array().reshape(40, 32), span)
    np.testing.assert_array_equal(images[1].get_array().reshape(40, 32), contour)
    assert images[0].get_clim() == images[1].get_clim() == (contour.min(), max(span.max(), contour.max()))
    assert fig.axes[0].get_ylim()[1] > 39 > 0 > fig.axes[0].get_ylim()[0]


def test_a_per_bay_design_writes_the_overview_of_its_fields(tmp_path, capsys):
    # Two iterations: the design does not converge (exit 1), and its folder is written all the same.
    case = tmp_path / "wing.toml"
    case.write_text(CASE)
    out = tmp_path / "out"
    code = cli.main(["--config", str(case), "--out", str(out), "--no-compilation-cache", "--no-patterns"])
    summary = json.loads((out / "summary.json").read_text())
    assert code in (0, 1), capsys.readouterr().err
    assert "cut_pattern_overview.png" in summary["files"] and (out / "cut_pattern_overview.png").stat().st_size
    assert {"bay_0_cut_pattern.csv", "bay_1_cut_pattern.csv"} <= set(summary["files"])
    peak = summary["timings_s"]["peak_memory_mb"]
    assert 50 < peak < 1e5 and f"peak memory {peak:.0f} MB" in capsys.readouterr().out
