"""Sections with open and closed trailing edges in one bay or wing.

Real `.dat` files (tests/data/uiuc, README there) mostly have an open
trailing edge (a gap of 0.08-0.18% of chord here) and NACA codes a closed
one; a skin runs one seam form, so `targets.common_trailing_edge` brings
them to one (closed by default) and says what it changed.
"""

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from forward_solver import Bay, Fabric
from forward_solver import Wing
from forward_solver.solvers.bays import solve_wing
from inverse_design.app import cli
from targets import AirfoilWarning, common_trailing_edge, load_airfoil, naca

UIUC = Path(__file__).parents[1] / "data" / "uiuc"
OPEN = ("fx77w153", "rc0864c", "tasopt-b")  # open trailing edges, gaps 1.81e-3, 1.6e-3, 8e-4
#: How far the section may move ahead of the blend: the resampling error of the
#: 401-node contour the blend is applied to (3.9e-6 measured, at rc0864c's sharp nose).
AHEAD_TOLERANCE = 1e-5


def _load(name):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AirfoilWarning)  # fx77w153's chord is renormalised
        return load_airfoil(UIUC / f"{name}.dat")


@pytest.mark.parametrize("name", OPEN)
def test_closing_moves_the_section_only_over_the_blend(name):
    airfoil = _load(name)
    gap = airfoil.trailing_edge_gap
    assert not airfoil.closed_te and gap > 5e-4
    closed = airfoil.with_closed_trailing_edge()
    assert closed.closed_te and closed.trailing_edge_gap == 0.0 and closed.name == airfoil.name
    ahead = airfoil.x < 1.0 - 0.05
    assert np.abs(closed.distance(airfoil.points[ahead])).max() < AHEAD_TOLERANCE
    # Over the blend the section moves by at most half the gap (each surface to the mid-point).
    assert np.abs(closed.distance(airfoil.points)).max() <= 0.5 * gap + AHEAD_TOLERANCE
    assert closed.thickness(np.linspace(0.95, 0.999, 50)).min() > 0.0


def test_opening_a_naca_section_gives_the_asked_gap_and_keeps_the_rest():
    section = naca("2412")
    opened = section.with_trailing_edge(1.5e-3)
    assert not opened.closed_te and opened.trailing_edge_gap == pytest.approx(1.5e-3, rel=1e-12)
    assert 0.5 * (opened.x[0] + opened.x[-1]) == pytest.approx(1.0, abs=1e-12)  # unit chord kept
    assert np.abs(section.distance(opened.points[opened.x < 0.95])).max() < AHEAD_TOLERANCE
    assert section.with_trailing_edge(0.0) is section  # already closed: unchanged
    with pytest.raises(ValueError, match="blend"):
        section.with_trailing_edge(1e-3, blend=0.0)


def test_as_given_refuses_a_mix_naming_both_sections_and_the_option():
    sections = [naca("2412"), _load("fx77w153")]
    with pytest.raises(ValueError) as info:
        common_trailing_edge(sections, "as-given", ["rib 0 (naca2412)", "rib 1 (fx77w153.dat)"])
    message = str(info.value)
    assert "rib 0 (naca2412)" in message and "rib 1 (fx77w153.dat)" in message
    assert "--trailing-edge" in message and "close" in message
    same, changes = common_trailing_edge([naca("2412"), naca("0012")], "as-given")
    assert changes == [] and same[0].closed_te


def test_a_bay_between_a_naca_and_an_open_dat_rib_is_built_closed():
    bay = Bay.from_airfoil(naca("2412"), tip_airfoil=_load("rc0864c"), n_span=5, n_contour=32)
    (change,) = bay.trailing_edge_changes
    assert change["label"].startswith("tip") and change["gap_before"] == pytest.approx(1.6e-3)
    assert change["gap_after"] == 0.0
    assert bay.fixed[:, 0].all() and not bay.fixed[1:-1, -1].any()  # one closed seam
    with pytest.raises(ValueError, match="root .* tip"):
        Bay.from_airfoil(naca("2412"), tip_airfoil=_load("rc0864c"), n_span=5, n_contour=32,
                         trailing_edge="as-given")


@pytest.mark.parametrize("mode", ["close", "open"])
def test_a_wing_mixing_naca_codes_and_real_files_solves(mode):
    sections = (naca("2412"), _load("fx77w153"), _load("tasopt-b"), naca("0012"))
    wing = Wing(sections, (1.0, 0.9, 0.8, 0.7), (0.0, 0.25, 0.5, 0.75), trailing_edge=mode)
    changed = [c["index"] for c in wing.trailing_edge_changes]
    assert changed == ([1, 2] if mode == "close" else [0, 3])
    assert len({s.closed_te for s in wing.sections}) == 1 and wing.airfoils == sections
    if mode == "open":  # opened to the largest gap among the sections
        assert all(s.trailing_edge_gap == pytest.approx(sections[1].trailing_edge_gap)
                   for s in (wing.sections[0], wing.sections[3]))
    solution = solve_wing(wing, Fabric(), 1e4, 0.02, n_span=5, n_contour=32)
    assert solution.converged, solution.result
    assert np.isfinite(np.asarray(solution.nodes)).all()


def test_the_command_closes_a_mixed_wing_and_says_so(tmp_path, monkeypatch, capsys):
    # The case file lives in its own folder with the .dat beside it, named relatively
    # (resolved against the case file's folder), and the command runs from elsewhere.
    folder = tmp_path / "case"
    folder.mkdir()
    shutil.copy(UIUC / "tasopt-b.dat", folder / "tasopt-b.dat")
    (folder / "wing.toml").write_text(
        'variables = ["pressure"]\npressure = 3e4\nn-span = 5\nn-contour = 32\nmax-iterations = 2\n'
        '[[rib]]\nsection = "naca2412"\nchord = 1.0\nstation = 0.0\n'
        '[[rib]]\nsection = "tasopt-b.dat"\nchord = 0.8\nstation = 0.25\n')
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    out = tmp_path / "out"
    code = cli.main(["--config", str(folder / "wing.toml"), "--out", str(out), "--no-figures", "--no-compilation-cache"])
    printed = capsys.readouterr()
    assert code in (0, 1), printed.err  # (two iterations need not converge)
    summary = json.loads((out / "summary.json").read_text())
    (change,) = summary["case"]["trailing_edge"]["changed"]
    assert summary["case"]["trailing_edge"]["option"] == "close"
    assert change["rib"] == 1 and change["gap_before"] == pytest.approx(8e-4) and change["gap_after"] == 0
    assert change["file"] == str(folder / "tasopt-b.dat")
    assert "rib 1 (" in printed.out and "trailing edge closed, gap 0.0008 -> 0 chord" in printed.out
