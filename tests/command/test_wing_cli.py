"""A wing case file (``[[rib]]`` tables) for ``optimise-pressure --config``: bad input and a full run.

The command runs in this process (`cli.main` with ``--no-compilation-cache``,
which leaves JAX's configuration alone), so the end-to-end run reuses the
3-bay 9x32 compilation of tests/wing/test_wing_design.py when both run together.
Bad input never reaches JAX: it is refused while the case file is read.
"""

import json
import re

import numpy as np
import pytest

from inverse_design.app import cli, design
from inverse_design.app.case import Case
from inverse_design.app.case_file import EXAMPLE_CASE
from support.cases import IN_PROCESS, case_text, rib_tables

WING = (("naca2412", 1.0, 0.0), ("naca2412", 0.8, 0.25), ("naca2412", 0.7, 0.5), ("naca4415", 0.6, 0.75))
RIBS = rib_tables(*WING)
CASE = case_text(*WING, variables=["pressure"], pressure=3e4, pressure_bounds=[1e3, 1e5], n_span=9, n_contour=32,
                 max_iterations=30)


def _run(tmp_path, text, *extra):
    case = tmp_path / "wing.toml"
    case.write_text(text)
    return cli.main(["--config", str(case), "--out", str(tmp_path / "out"), *IN_PROCESS, *extra]), case


def test_the_wing_case_file_runs_end_to_end_and_writes_its_summary(tmp_path, capsys):
    # Into the folder of an earlier wing report with rib shapes (rib_K.dat) and more bays, beside
    # the user's files: the earlier report's files go, the user's stay byte for byte.
    out = tmp_path / "out"
    out.mkdir()
    earlier = ["rib_0.dat", "rib_1.dat", "rib_2.dat", "rib_3.dat", "bay_3_mid_bay_section.png", "wing.npz"]
    for name in earlier:
        (out / name).write_text("earlier")
    (out / "summary.json").write_text(json.dumps({"package": {"name": "inflatable-wing"},
                                                  "files": earlier + ["summary.json"]}))
    (out / "rib_0.dat.orig").write_bytes(b"the user's rib")
    (out / "wing.toml").write_bytes(b"# the user's case")
    code, _ = _run(tmp_path, CASE)
    assert code == 0, capsys.readouterr().err
    assert (out / "rib_0.dat.orig").read_bytes() == b"the user's rib"
    assert (out / "wing.toml").read_bytes() == b"# the user's case"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["mode"] == "optimise" and summary["results"]["success"]
    assert summary["schema"] == 3 and summary["case"]["n_bays"] == 3 and len(summary["bays"]) == 3
    assert [r["chord_m"] for r in summary["case"]["ribs"]] == [1.0, 0.8, 0.7, 0.6]
    assert summary["case"]["ribs"][3]["target"] == "NACA 4415"
    bays = summary["bays"]
    assert [b["result"] for b in bays] == ["converged"] * 3
    assert summary["errors"]["after"]["rms"] < summary["errors"]["before"]["rms"]
    assert [w for w in summary["warnings"] if "span nodes, fewer than" not in w] == []  # (the test grid's)
    assert summary["constraints"]["violated_at_start"] == {}
    patterns = {f"pattern_bay_{k}_{panel}.{kind}" for k in range(3) for panel in ("upper", "lower")
                for kind in ("dxf", "svg")}
    assert set(summary["files"]) == {"summary.json", "wing.npz", "skin.obj", "skin.stl", "history.png",
                                     "wing_overview.png", "bay_0_mid_bay_section.png", "bay_1_mid_bay_section.png",
                                     "bay_2_mid_bay_section.png", "bay_0_cut_pattern.csv", "bay_1_cut_pattern.csv",
                                     "bay_2_cut_pattern.csv", "rib_0.dxf", "rib_1.dxf", "rib_2.dxf",
                                     "rib_3.dxf"} | patterns
    assert {p.name for p in out.iterdir()} == set(summary["files"]) | {"rib_0.dat.orig", "wing.toml"}
    # The patterns of every bay and rib read back clean (tests/patterns/test_patterns.py checks one bay's in depth).
    import ezdxf

    for name in sorted(n for n in summary["files"] if n.endswith(".dxf")):
        doc = ezdxf.readfile(out / name)
        assert not doc.audit().has_errors and doc.header["$INSUNITS"] == 4, name
    assert summary["patterns"]["largest_length_error_m"] < 1e-9 and len(summary["patterns"]["panels"]) == 6
    with np.load(out / "wing.npz") as npz:
        assert npz["nodes"].shape == (3, 9, 32, 3) and npz["deviation"].shape == (3, 9, 32)
        assert float(npz["pressure"]) == pytest.approx(summary["results"]["values"]["pressure_pa"])
        # The bays meet at their ribs: bay k's tip row is bay k + 1's root row (in wing coordinates).
        np.testing.assert_allclose(npz["nodes"][0, -1, :, [0, 2]], npz["nodes"][1, 0, :, [0, 2]], atol=1e-12)
    # One mesh for the whole wing: 3 bays of 8 cell rows, 32 cells round.
    faces = [line for line in (out / "skin.obj").read_text().splitlines() if line.startswith("f ")]
    assert len(faces) == 3 * 8 * 32


def test_a_wing_outside_the_validated_ranges_warns_before_the_design(tmp_path, capsys, monkeypatch):
    # Bay 1 spans 2.25 m (3 chords: outside the validated range, inside what is refused). The lines come
    # before the optimisation, which is stopped there (as Ctrl-C would) so that no such bay is solved.
    def stop(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(design, "optimise_wing", stop)
    case = tmp_path / "wing.toml"
    case.write_text(CASE.replace("station = 0.5", "station = 2.5").replace("station = 0.75", "station = 2.75"))
    code = cli.main(["--config", str(case), "--out", str(tmp_path / "out"), "--no-compilation-cache"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == cli.EXIT_INTERRUPTED
    assert err[:2] == ["optimise-pressure: warning: bay 1: rib spacing 2.25 m lies outside the range the model is "
                       "validated for (0.05 to 0.5 m); check the value, or treat the result as unvalidated",
                       "optimise-pressure: warning: bay 1: rib spacing / chord 3 lies outside the range the "
                       "model is validated for (0.05 to 0.5); check the value, or treat the result as unvalidated"]
    assert len(err) == 4 and "span nodes, fewer than" in err[2]  # the test grid's, then the interruption


def test_the_built_in_example_is_a_valid_wing_case():
    case = Case.from_arguments(["--config", str(EXAMPLE_CASE)])
    assert case.n_bays == 3 and case.from_ribs and case.options.n_span == 17


def test_the_40_cell_case_is_a_tapered_wing_of_40_bays():
    case = Case.from_arguments(["--config", str(EXAMPLE_CASE.parent / "wing_40_cells.toml")])
    chords = [rib.chord for rib in case.ribs]
    assert len(chords) == 41 and (case.options.n_span, case.options.n_contour) == (17, 64)
    assert case.options.method == "gauss_newton"
    assert case.variables == ("pressure", "prestrain_span", "prestrain_chord")
    assert chords[0] == 2.4 and chords[-1] == pytest.approx(1.0, abs=1e-3) and all(np.diff(chords) < 0)


@pytest.mark.parametrize("text, message", [
    ('[[rib]]\nsection = "naca2412"\nchord = 1.0\nstation = 0.0\n',
     r"wing.toml: a wing needs at least two \[\[rib\]\] tables \(root and tip\), got 1; add ribs"),
    (RIBS.replace("station = 0.5", "station = 0.2"),
     r"wing.toml: rib 2: station 0.2 m does not lie beyond rib 1's \(0.25 m\); list the ribs root to tip"),
    (RIBS.replace('"naca4415"', '"naca99x"'),
     r"wing.toml: rib 3: section 'naca99x' is neither a NACA code nor a .dat file"),
    (RIBS.replace("chord = 0.8\n", ""), r"wing.toml: rib 1: missing chord; every \[\[rib\]\] needs section"),
    (RIBS.replace("chord = 0.7", "chord = -0.7"), r"wing.toml: rib 2: chord must be a positive length in m"),
    (RIBS.replace("station = 0.25", "station = 0.25\nspan = 3"), r"wing.toml: rib 1: unknown key\(s\) \['span'\]"),
    (RIBS.replace('section = "naca4415"', 'section = "missing.dat"'), r"wing.toml: rib 3: section: no such file"),
    ("chord = 0.5\n" + RIBS, r"chord does not apply to a wing .*: give each rib's chord in its \[\[rib\]\] table"),
    ('method = "root"\n' + RIBS, r"method root does not apply to a wing of 3 bays .*: root finding solves one scalar "
                                  r"condition at one bay's mid-bay section: use slsqp, gauss_newton, least_squares or optax"),
], ids=["one rib", "stations", "unknown section", "missing chord", "negative chord", "unknown key",
        "missing file", "chord option", "method"])
def test_bad_wing_input_exits_2_with_one_line_naming_file_and_rib(tmp_path, capsys, text, message):
    code, case = _run(tmp_path, text)
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and err.startswith("optimise-pressure: error: ")
    assert str(case) in err or "wing.toml" in err
    assert re.search(message, err), err
    assert not (tmp_path / "out").exists()


def test_a_wing_is_evaluated_and_compared_aerodynamically_bay_by_bay(tmp_path, capsys):
    # --evaluate and --aero on a wing (both were refused): one equilibrium of the three bays, each
    # bay's sections against its own mid-bay target, written as a single bay's would be, per bay.
    pytest.importorskip("neuralfoil")
    code, _ = _run(tmp_path, CASE, "--evaluate", "--aero", "--alpha-range", "0", "4", "2")
    assert code == 0, capsys.readouterr().err
    out = tmp_path / "out"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["mode"] == "evaluate" and summary["case"]["n_bays"] == 3
    assert summary["errors"]["before"] is None and summary["history"] == []
    assert "history.png" in summary["skipped"] and not (out / "history.png").exists()
    for k, bay in enumerate(summary["bays"]):
        assert bay["result"] == "converged" and bay["errors_before"] is None
        assert bay["aero"]["alphas_deg"] == [0.0, 2.0, 4.0] and f"bay_{k}_aero.png" in summary["files"]
        assert (out / f"bay_{k}_aero.png").stat().st_size > 10_000
    # The wing's own files, as a design's, but no optimiser history.
    assert {"wing.npz", "wing_overview.png", "bay_2_mid_bay_section.png", "bay_2_cut_pattern.csv"} <= set(
        summary["files"])
    assert summary["errors"]["after"]["rms"] > 0 and summary["constraints"]["note"].startswith("a single equilibrium")


@pytest.mark.parametrize("key", ["section", "target"])
def test_a_bad_dat_file_of_a_rib_is_refused_with_the_one_line_of_the_option(tmp_path, capsys, key):
    """A ``.dat`` file that is not an airfoil, named by a ``[[rib]]`` table, is refused as ``--target`` refuses
    it: one line, exit 2, before any work (it was a traceback from the airfoil reader, exit 1)."""
    bad = tmp_path / "bad.dat"
    bad.write_text("not an airfoil\n1 2 3\n")
    code = cli.main(["--target", str(bad), "--out", str(tmp_path / "by-option"), *IN_PROCESS])
    by_option = capsys.readouterr().err
    assert code == 2 and by_option.count("\n") == 1 and by_option.startswith("optimise-pressure: error: "), by_option
    code, _ = _run(tmp_path, RIBS.replace('section = "naca2412"\nchord = 0.8',
                                          f'{key} = "bad.dat"\n' + ('section = "naca2412"\n' if key == "target" else "")
                                          + "chord = 0.8"))
    assert code == 2 and capsys.readouterr().err == by_option
    assert not (tmp_path / "out").exists()
