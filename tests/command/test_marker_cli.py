"""``--roll-width``: the command nests a one-bay design's panels into ``marker.dxf``/``.svg``/``.png`` and
summary.json's ``marker``; nonsense values and a missing nester are refused as the case is read (one line,
exit 2), a roll narrower than a panel right after the design, before anything is written.

The nested outlines are read back from ``marker.dxf`` and matched against the CUT lines of the pattern files
(``pattern_bay_0_*.dxf``), not against the marker's own record.
"""

import json
import sys

import numpy as np
import pytest

ezdxf = pytest.importorskip("ezdxf")

from inverse_design.app import cli  # noqa: E402
from inverse_design.app.case import Case  # noqa: E402
from inverse_design.app.options import InputError  # noqa: E402
from support.cases import IN_PROCESS, SMALL  # noqa: E402
from support.geometry import area, overlap  # noqa: E402

WIDTH = 1400.0


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("marker") / "out"
    code = cli.main([*SMALL, *IN_PROCESS, "--evaluate", "--roll-width", f"{WIDTH:g}", "--marker-seconds", "3",
                     "--out", str(out)])
    assert code == 0
    return out, json.loads((out / "summary.json").read_text())


def _cuts(path) -> list:
    doc = ezdxf.readfile(path)
    return [np.asarray(e.get_points("xy"), np.float64) for e in doc.modelspace().query('LWPOLYLINE[layer=="CUT"]')]


def test_the_folder_has_the_marker_and_its_summary(report):
    out, summary = report
    assert {"marker.dxf", "marker.svg", "marker.png"} <= set(summary["files"])
    assert (out / "marker.svg").read_text().startswith("<svg")
    marker = summary["marker"]
    assert marker["panels"] == 2 and marker["roll_width_mm"] == WIDTH and marker["nester"] == "sparrow"
    assert set(marker) >= {"roll_width_mm", "length_mm", "utilisation", "panels", "seconds", "nester", "ended"}
    layers = {layer.dxf.name for layer in ezdxf.readfile(out / "marker.dxf").layers}
    assert {"CUT", "SEW", "MARK"} <= layers
    texts = [t.dxf.text for t in ezdxf.readfile(out / "marker.dxf").modelspace().query("TEXT")]
    assert {"bay 0 upper", "bay 0 lower", "WARP"} <= set(texts)


def test_each_nested_outline_is_its_pattern_files_cut_line_moved_or_turned(report):
    out, summary = report
    nested = _cuts(out / "marker.dxf")
    patterns = [_cuts(out / f"pattern_bay_0_{name}.dxf")[0] for name in ("upper", "lower")]
    assert len(nested) == 2
    for pattern in patterns:
        matches = 0
        for outline in nested:
            for turned in (pattern, -pattern):  # moved, or turned by 180 degrees (never mirrored)
                if outline.shape == turned.shape and np.allclose(outline, turned + (outline[0] - turned[0]), atol=0.01):
                    matches += 1
        assert matches == 1
    assert not overlap(*nested)
    assert all(o[:, 0].min() >= 0 and o[:, 0].max() <= WIDTH for o in nested)
    marker = summary["marker"]
    used = sum(area(o) for o in nested) / (WIDTH * marker["length_mm"])
    assert marker["utilisation"] == pytest.approx(used, rel=1e-3)


def test_a_roll_narrower_than_a_panel_is_refused_after_the_design(tmp_path, capsys):
    out = tmp_path / "out"
    code = cli.main([*SMALL, "--no-compilation-cache", "--evaluate", "--roll-width", "600", "--out", str(out)])
    assert code == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--roll-width 600 mm is narrower than the bay 0 upper panel, which needs" in line, line
    assert not (out / "summary.json").exists()


@pytest.mark.parametrize("argv, message", [
    (["--roll-width", "0"], "argument --roll-width: must be a positive number (mm), got '0'"),
    (["--roll-width", "-1400"], "argument --roll-width: must be a positive number (mm), got '-1400'"),
    (["--roll-width", "1.4e6"], "--roll-width 1.4e+06 mm is wider than any roll (10 m at most"),
    (["--roll-width", "1400", "--marker-gap", "-5"], "--marker-gap must be 0 mm or more and less than --roll-width "
                                                     "1400 mm"),
    (["--roll-width", "1400", "--marker-gap", "1400"], "--marker-gap must be 0 mm or more and less than"),
    (["--roll-width", "1400", "--marker-seconds", "0.5"], "--marker-seconds is the nesting's time limit, from 1"),
], ids=["zero", "negative", "absurd", "negative-gap", "gap-as-wide", "seconds"])
def test_nonsense_is_refused_as_the_case_is_read(argv, message):
    with pytest.raises(InputError) as info:
        Case.from_arguments([*argv, "--out", "unused"])
    assert str(info.value).startswith(message), str(info.value)


def test_a_case_file_gives_the_same_marker_and_the_same_refusals(tmp_path):
    (tmp_path / "case.toml").write_text("roll-width = 1400\nmarker-gap = 8\nmarker-seconds = 20\nwarp = \"chord\"\n")
    case = Case.from_arguments(["--config", str(tmp_path / "case.toml"), "--out", "unused"])
    request = case.marker
    assert (request.roll_width_mm, request.gap_mm, request.seconds, request.warp) == (1400.0, 8.0, 20.0, "chord")
    assert Case.from_arguments(["--roll-width", "1400", "--marker-gap", "8", "--marker-seconds", "20", "--warp",
                                "chord", "--out", "unused"]).marker == request
    (tmp_path / "case.toml").write_text("roll-width = 20000\n")
    with pytest.raises(InputError, match=r"^roll-width \(case file\) 20000 mm is wider than any roll"):
        Case.from_arguments(["--config", str(tmp_path / "case.toml"), "--out", "unused"])


def test_without_the_nester_the_roll_is_refused_with_the_pip_command(monkeypatch):
    monkeypatch.setitem(sys.modules, "spyrrow", None)  # (as if it were not installed)
    with pytest.raises(InputError, match=r'^--roll-width: the marker\'s nester spyrrow \(sparrow\) is not installed: '
                                         r'pip install "inflatable-wing\[marker\]"'):
        Case.from_arguments(["--roll-width", "1400", "--out", "unused"])
    assert Case.from_arguments(["--out", "unused"]).marker is None  # (no roll: no nester needed)
