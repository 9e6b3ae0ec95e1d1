"""One report for N >= 1 bays: the same folder and summary keys for a bay given by options and by a
two-rib case file; the console's wording; the figures' legends, limits and titles.

The command runs in this process (`cli.main` with ``--no-compilation-cache``, as in
tests/command/test_wing_cli.py) on the small grid of tests/command/test_cli.py (5 x 32), so the two runs share
their compilations. The figure checks build figures from plain values (no solve) where they can.
"""

import json
import shutil
from types import SimpleNamespace

import numpy as np
import pytest

from inverse_design.app import cli
from inverse_design.app.console import describe, number_text
from support.cases import IN_PROCESS, SMALL, TWO_RIBS


def _keys(value, path=""):
    """Every key path of a JSON tree (list entries of dicts share one path)."""
    out = set()
    if isinstance(value, dict):
        for key, item in value.items():
            out.add(f"{path}/{key}")
            out |= _keys(item, f"{path}/{key}")
    elif isinstance(value, list):
        for item in value:
            if isinstance(item, dict):
                out |= _keys(item, f"{path}[]")
    return out


@pytest.fixture(scope="module")
def two_reports(tmp_path_factory):
    base = tmp_path_factory.mktemp("report")
    (base / "bay.toml").write_text(TWO_RIBS)
    runs = {"options": [*SMALL], "case file": ["--config", str(base / "bay.toml")]}
    summaries = {}
    for name, args in runs.items():
        out = base / name.replace(" ", "_")
        assert cli.main([*args, "--out", str(out), *IN_PROCESS]) == 0
        summaries[name] = json.loads((out / "summary.json").read_text())
        summaries[name]["folder"] = str(out)
    return summaries


def test_a_bay_by_options_and_by_a_two_rib_case_file_write_the_same_files_and_keys(two_reports):
    by_options, by_file = two_reports["options"], two_reports["case file"]
    assert sorted(by_options["files"]) == sorted(by_file["files"])
    assert {"wing.npz", "wing_overview.png", "bay_0_mid_bay_section.png", "equilibrium.npz", "deviation.png",
            "tensions.png", "bay_0_cut_pattern.csv"} <= set(by_options["files"])
    # The inputs are the options as given (where each came from, and the case file's rib tables, differ
    # by nature); every other key is the same, down to the bay axis.
    keys = [{k for k in _keys(s) if not k.startswith(("/inputs/sources/", "/inputs/wing[]/", "/folder"))}
            for s in (by_options, by_file)]
    assert keys[0] == keys[1]
    assert by_options["case"]["n_bays"] == by_file["case"]["n_bays"] == 1
    # The same bay: the same design (the same grid and start; the scenes are built the same way).
    assert by_options["results"]["values"]["pressure_pa"] == pytest.approx(
        by_file["results"]["values"]["pressure_pa"], rel=1e-6)


def test_each_bay_says_how_far_its_mid_bay_nose_lies_behind_the_target(two_reports):
    """The leading-edge recession of the summary against the equilibrium written beside it: the mid-bay
    row's foremost node (5 span rows: row 2 is mid-bay) behind NACA 2412's nose (x = 0), local chord 1 m."""
    from targets import naca

    summary = two_reports["options"]
    nodes = np.load(f"{summary['folder']}/wing.npz")["nodes"][0]
    expected = float(np.min(nodes[2, :, 0])) - float(np.min(naca("2412").x))
    recession = summary["bays"][0]["le_recession"]
    assert recession["chord_fraction"] == pytest.approx(expected, rel=1e-9, abs=1e-12)
    assert recession["mm"] == pytest.approx(1e3 * expected, rel=1e-9, abs=1e-9)
    assert 0.0 < recession["chord_fraction"] < 0.05  # (the prestressed skin pulls the nose back: README)


def test_the_console_says_one_bay_and_a_wing_of_n_bays(two_reports):
    summary = dict(two_reports["options"], out="out")
    first = describe(summary)[0]
    assert first.startswith("NACA 2412, one bay (1 m chord, 0.25 m span), 5x32 grid, average objective")
    assert "1 bays" not in "\n".join(describe(summary))
    wing = json.loads(json.dumps(summary))
    wing["case"]["n_bays"] = 3
    wing["case"]["ribs"] = [dict(r, station_m=0.25 * k, chord_m=1.0 - 0.1 * k)
                            for k, r in enumerate(wing["case"]["ribs"] * 2)][:4]
    wing["bays"] = [dict(summary["bays"][0], bay=k) for k in range(3)]
    lines = describe(wing)
    assert lines[0].startswith("NACA 2412, a wing of 3 bays (1 to 0.7 m chord, 0.75 m span), 5x32 grid per bay")
    assert sum(line.startswith("  bay ") for line in lines) == 3


def test_the_default_design_says_its_bounds_decided_it_with_their_prices(two_reports):
    # The default design sits on its pressure floor (1 kPa) and its rib thickness ceiling (1.0): the summary
    # prices both bounds, and the console says so in one line each, then that the floor, not the physics,
    # chose the pressure (freed from it the rms would fall by 0.015% on this grid).
    summary = dict(two_reports["options"], out="out")
    section = summary["sensitivity"]
    assert [(p["name"], p["per"]) for p in section["prices"]] == [("pressure>=lower", "1 kPa"),
                                                                   ("rib_thickness_scale<=upper", "0.01")]
    assert section["prices"][0]["d_rms"] > 0 > section["prices"][1]["d_rms"]
    assert [w["name"] for w in section["windows"]] == ["pressure", "rib_thickness_scale"]
    assert section["rms"] == pytest.approx(summary["errors"]["after"]["rms"], rel=1e-9)
    lines = describe(summary)
    priced = [line for line in lines if ": shadow price " in line]
    assert [line.split(":")[0] for line in priced] == ["  pressure >= 1 kPa", "  rib_thickness_scale <= 1"]
    assert f"{section['prices'][0]['relaxed_gain']:.3g} chord of rms per 1 kPa" in priced[0]
    (pressure,) = [line for line in lines if line.startswith("  pressure: ")]
    high = section["windows"][0]["high"]
    assert pressure.startswith(f"  pressure: any value from 1 kPa to {number_text(high / 1e3, 3)} kPa keeps the rms "
                               "within 1%; the lower bound decides it")
    assert lines.index(pressure) < len(lines) - 2  # before the timing and the files


def test_a_value_zero_to_rounding_prints_as_zero():
    # SLSQP returns a variable at an active bound of 0 as a few 1e-15 of its scaled value (e.g.
    # minimize((x + 1)^2, bounds [0, 5]) from 0.3 gives 2.8e-15): a prestrain of 3.9e-19.
    assert number_text(3.89664e-19) == "0" and number_text(-2e-16) == "0"
    assert number_text(0.0) == "0" and number_text(1e-9) == "1e-09" and number_text(1234.5678) == "1234.57"
    summary = {"case": {"n_bays": 1, "ribs": [{"target": "NACA 2412", "chord_m": 1.0, "station_m": 0.0}] * 2,
                        "grid": [5, 32]},
               "mode": "optimise", "results": {"values": {"prestrain_chord": 3.89664e-19, "pressure_pa": 1e3},
                                               "variables": ["prestrain_chord"], "method": "slsqp", "iterations": 1,
                                               "forward_solves": 1, "equilibrium": {"wrinkled_fraction": 0.0}},
               "errors": {"objective": "average", "before": {"rms": 1e-2, "max": 2e-2},
                          "after": {"rms": 1e-3, "max": 2e-3}},
               "constraints": {"active": [], "violated": {}, "violated_where": {}, "violated_at_start": {}},
               "bays": [], "timings_s": {"total": 1.0, "report": 0.5}, "out": "out", "files": []}
    lines = describe(summary)
    assert "  slsqp: prestrain_chord 0" in lines
    assert lines[3].endswith("violated: none; 1 iterate, 1 forward solve")  # (not "1 iterates")


def test_a_failed_design_says_that_no_panel_was_written_not_that_no_cut_pattern_was(tmp_path, capsys):
    code = cli.main([*SMALL, "--max-iterations", "1", "--no-figures", "--out", str(tmp_path / "out"), *IN_PROCESS])
    err = capsys.readouterr().err
    assert code == 1 and "no panel or rib template (DXF, SVG) was written" in err
    assert "no cut pattern" not in err
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert "bay_0_cut_pattern.csv" in summary["files"]  # (the cut lengths are written: they are data)
    assert not list((tmp_path / "out").glob("*.dxf"))



def test_without_figures_the_report_is_the_same_less_every_png_each_named_skipped(two_reports, tmp_path):
    # --no-figures into the folder of the same run with figures: every other file written again, each
    # figure named in skipped and the earlier report's figures removed (files this report does not write).
    with_figures = two_reports["options"]
    out = tmp_path / "out"
    shutil.copytree(with_figures["folder"], out)
    assert cli.main([*SMALL, "--no-figures", "--out", str(out), *IN_PROCESS]) == 0
    summary = json.loads((out / "summary.json").read_text())
    figures = {name for name in with_figures["files"] if name.endswith(".png")}
    assert len(figures) >= 5 and set(summary["files"]) == set(with_figures["files"]) - figures
    assert {name for name, why in summary["skipped"].items() if "--no-figures" in why} == figures
    assert sorted(path.name for path in out.iterdir()) == sorted(summary["files"])
    assert summary["results"]["values"] == pytest.approx(with_figures["results"]["values"], rel=1e-9)
    assert summary["inputs"]["no_figures"] is True

# ------------------------------------------------------------------ figures
def _points_in_display(ax):
    """Every plotted data point of ``ax``'s lines, in display coordinates."""
    points = [line.get_xydata() for line in ax.get_lines() if len(line.get_xydata())]
    data = np.concatenate(points)
    data = data[np.all(np.isfinite(data), axis=1)]
    return ax.transData.transform(data)


def test_the_history_legends_cover_no_curve_and_every_result_has_its_unit():
    from inverse_design.app.wing_figures import plot_history

    history = [{"objective": 1e-4 / (k + 1), "values": {"pressure": 3e4 / (k + 1), "rib_thickness_scale": 1.0}}
               for k in range(8)]
    result = SimpleNamespace(variables=("pressure", "rib_thickness_scale"), method="slsqp", objective="average",
                             rms_error=3e-3, success=True, history=history,
                             values={"pressure": 3750.0, "rib_thickness_scale": 1.0})
    fig = plot_history(result, {"pressure": (1e3, 1e5), "rib_thickness_scale": (0.5, 1.0)})
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    for ax in fig.axes:
        legend = ax.get_legend()
        box = legend.get_window_extent(renderer)
        inside = box.contains_points(_points_in_display(ax)) if hasattr(box, "contains_points") else [
            box.contains(x, y) for x, y in _points_in_display(ax)]
        assert not np.any(inside), ax.get_ylabel()
    labels = [t.get_text() for ax in fig.axes for t in ax.get_legend().get_texts()]
    assert "result: 1 x starting thickness" in labels and "result: 3.75 kPa" in labels


def test_the_wing_overview_holds_every_tension_inside_its_axes():
    from inverse_design.app.wing_figures import plot_wing_overview

    n = 4
    result = SimpleNamespace(
        wing=SimpleNamespace(stations=np.linspace(0.0, 1.0, n + 1)), initial_bay_rms_error=np.full(n, 1e-2),
        bay_rms_error=np.full(n, 1e-3), bay_max_error=np.full(n, 3e-3),
        bay_min_tension=np.array([5.0, 20.0, 40.0, 60.0]), bay_max_tension=np.array([900.0, 1500.0, 2400.0, 3125.0]),
        constraint_values={"min_tension_floor": 0.0}, parameters=SimpleNamespace(pressure=2e4), success=True,
        variables=("pressure",), initial_rms_error=1e-2, rms_error=1e-3, method="gauss_newton", solves=5)
    fig = plot_wing_overview(result, np.zeros((n, 5, 8)))
    fig.canvas.draw()
    ax = fig.axes[2]
    points = _points_in_display(ax)
    box = ax.get_window_extent()
    # Every point, its marker included (3 pt, about 6 px at 100 dpi), well inside the axes.
    assert np.all(points[:, 1] < box.y1 - 5) and np.all(points[:, 1] > box.y0 + 5)
    assert fig.get_suptitle().startswith("4 bays at 20 kPa")


def test_a_bay_s_section_plot_names_its_own_ribs_and_stations():
    from forward_solver import Bay, Fabric, Scene, solve_equilibrium
    from inverse_design.app.bay_figures import plot_section
    from targets import naca

    scene = Scene(Bay.from_airfoil(naca("2412"), chord=0.8, rib_spacing=0.25, n_span=5, n_contour=32), Fabric())
    solution = solve_equilibrium(scene, pressure=2e4, prestrain=(0.02, 0.02))
    fig = plot_section(solution, naca("2412"), scene, bay=2, rib_stations=(0.5, 0.75))
    title = fig.get_suptitle()
    assert title.startswith("bay 2 (ribs 2 and 3 at y = 0.5 and 0.75 m)")
    labels = [t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()]
    assert any(label.startswith("rib 2 at y = 0.5 m") for label in labels)
    assert not any("y = 0 " in label or label.endswith("y = 0") for label in labels + [title])
    fig.canvas.draw()  # the title fits the figure's width (it ran off both sides on one line)
    from matplotlib.text import Text

    (shown,) = [t for t in fig.findobj(Text) if t.get_text() == title]
    box = shown.get_window_extent(fig.canvas.get_renderer())
    assert box.x0 >= 0 and box.x1 <= fig.bbox.width


def test_a_bay_s_figures_unpickle_without_jax_or_the_solver(tmp_path):
    """The report's workers save figures built here and pickled (`inverse_design.app.workers`): every
    function a figure keeps (a secondary axis's scale) unpickles with matplotlib alone."""
    import os
    import pickle
    import subprocess
    import sys
    from pathlib import Path

    from forward_solver import Bay, Fabric, Scene, solve_equilibrium
    from inverse_design.app.bay_figures import plot_deviation, plot_section, plot_tensions
    from targets import naca

    scene = Scene(Bay.from_airfoil(naca("2412"), chord=0.8, rib_spacing=0.25, n_span=5, n_contour=32), Fabric())
    solution = solve_equilibrium(scene, pressure=2e4, prestrain=(0.02, 0.02))
    deviation = np.asarray(naca("2412").distance(np.asarray(solution.nodes)[..., [0, 2]] / 0.8))
    figures = [plot_section(solution, naca("2412"), scene), plot_deviation(solution, naca("2412"), scene, deviation),
               plot_tensions(solution, scene)]
    (tmp_path / "figures.pkl").write_bytes(pickle.dumps(figures))
    code = ("import pickle, sys\nimport matplotlib.figure\n"
            f"figures = pickle.loads(open({str(tmp_path / 'figures.pkl')!r}, 'rb').read())\n"
            "print(len(figures), sorted(m for m in ('jax', 'scipy', 'forward_solver', 'targets') if m in sys.modules))")
    root = Path(__file__).resolve().parents[2]
    ran = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=120,
                         env=dict(os.environ, PYTHONPATH=str(root)))
    assert ran.returncode == 0, ran.stderr
    assert ran.stdout.strip() == "3 []"


def test_the_panel_label_runs_clear_of_the_warp_arrow(tmp_path):
    ezdxf = pytest.importorskip("ezdxf")
    from ezdxf import bbox

    from forward_solver import Bay, Fabric, Parameters, Scene
    from inverse_design.app.cut_files import write_panel_dxf
    from inverse_design.flat_panels import bay_panels
    from targets import naca

    scene = Scene(Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=9, n_contour=32), Fabric())
    for panel in bay_panels(scene, Parameters(pressure=1e3, prestrain_span=0.02, prestrain_chord=0.0)):
        msp = ezdxf.readfile(write_panel_dxf(tmp_path / f"{panel.name}.dxf", panel, 10.0)).modelspace()
        (label,) = [t for t in msp.query("TEXT") if t.dxf.text == f"bay 0 {panel.name} panel"]
        box = bbox.extents([label])
        # the arrow's shaft: the longest two-point mark (the notches are 13 mm); every point along it clear
        shaft = max((np.asarray(e.get_points("xy")) for e in msp.query('LWPOLYLINE[layer=="MARK"]')
                     if len(e) == 2), key=lambda p: np.linalg.norm(p[1] - p[0]))
        along = shaft[0] + np.linspace(0.0, 1.0, 200)[:, None] * (shaft[1] - shaft[0])
        inside = ((along[:, 0] >= box.extmin.x) & (along[:, 0] <= box.extmax.x) & (along[:, 1] >= box.extmin.y)
                  & (along[:, 1] <= box.extmax.y))
        assert not inside.any() and np.linalg.norm(shaft[1] - shaft[0]) > 50.0, panel.name


def test_the_one_bay_overview_draws_each_bay_from_rib_to_rib_and_its_colour_bar_beside_its_map():
    from inverse_design.app.wing_figures import plot_wing_overview

    result = SimpleNamespace(
        wing=SimpleNamespace(stations=np.array([0.0, 0.25])), initial_bay_rms_error=np.array([6e-3]),
        bay_rms_error=np.array([2.5e-3]), bay_max_error=np.array([1.4e-2]), bay_min_tension=np.array([43.0]),
        bay_max_tension=np.array([6500.0]), constraint_values={"min_tension_floor": 0.0},
        parameters=SimpleNamespace(pressure=1e3), success=True, variables=("pressure",), initial_rms_error=6e-3,
        rms_error=2.5e-3, method="gauss_newton", solves=3)
    deviation = np.sin(np.arange(5 * 8)).reshape(1, 5, 8) * 1e-3
    fig = plot_wing_overview(result, deviation)
    fig.canvas.draw()
    per_bay = {"rms, start", "rms, design", "max, design", "min fibre tension", "max fibre tension"}
    drawn = {line.get_label(): line.get_xdata() for ax in fig.axes[1:3] for line in ax.get_lines()}
    assert per_bay <= set(drawn)
    for label in per_bay:  # a line across the bay, not a dot at its middle
        assert (min(drawn[label]), max(drawn[label])) == (0.0, 0.25), label
    ax_map = fig.axes[0]
    colour_bar = ax_map.collections[0].colorbar.ax
    gap = colour_bar.get_window_extent().x0 - ax_map.get_window_extent().x1
    assert 0.0 <= gap < 0.02 * fig.bbox.width  # (it stood a fifth of the figure's width away, past the legends)


def _budget(**change):
    sources = {"pressure": {"scale": 15.5, "value": 31.0, "text": "31%", "unit": "%", "given": "2%"},
               "cut_span": {"scale": 0.78, "value": 0.39, "text": "0.39", "unit": "mm", "given": "0.5"}}
    return {"budget": dict({"spec": 2.6, "nominal_rms": 2.56, "met_at_nominal": True, "sources": sources,
                            "common_scale": 0.66, "common": {}, "meets_given": False}, **change),
            "linear": {"rms": {"p95": 2.61}}, "samples": 0}


def test_the_tolerance_budget_says_what_scatter_it_allows_and_when_no_tolerance_can_meet_the_spec():
    from matplotlib.text import Text

    from inverse_design.app.wing_figures import plot_tolerance

    draws = np.random.default_rng(0).normal(2.56, 0.03, 500)
    left = plot_tolerance(_budget(), draws).axes[0]
    assert "times the given tolerance" in left.get_xlabel() and "largest multiple" not in left.get_xlabel()
    words = [t.get_text() for t in left.texts]
    assert any("31% allowed (given 2%)" in w for w in words)
    assert any("0.39 mm allowed (given 0.5 mm)" in w for w in words)
    # the nominal design misses a 0.1 mm spec: no bar says "none"; one statement says why and what to do
    nothing = {name: {"scale": 0.0, "value": 0.0, "text": "0", "unit": "mm", "given": "0.5"}
               for name in ("pressure", "cut_span")}
    fig = plot_tolerance(_budget(spec=0.1, met_at_nominal=False, sources=nothing, common_scale=0.0), draws)
    texts = [t.get_text() for t in fig.findobj(Text)]
    assert not any(t.strip() == "none" for t in texts)
    (statement,) = [t for t in texts if "cannot be met" in t]
    assert "2.56 mm" in statement and "0.1 mm" in statement and "--shape-spec" in statement


def test_root_finding_runs_on_a_one_bay_case_file(tmp_path):
    # Root finding solves one scalar condition at one bay's mid-bay section: a two-rib case file is
    # such a bay (a wing of several bays is refused, tests/command/test_wing_cli.py).
    (tmp_path / "bay.toml").write_text(TWO_RIBS)
    code = cli.main(["--config", str(tmp_path / "bay.toml"), "--method", "root", "--variables", "pressure",
                     "--no-figures", "--out", str(tmp_path / "out"), *IN_PROCESS])
    assert code == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["results"]["method"] == "root" and summary["results"]["success"]
