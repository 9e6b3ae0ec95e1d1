"""Sections that cross or pinch themselves are refused where they enter (docs/architecture.md,
"Impossible sections"): an airfoil file, an `Airfoil`, the command's target, and a rib shape of a design.

A figure-of-eight section encloses a positive area (its front loop is the larger), so the area and
orientation checks alone let it through; it must be refused with where it crosses (x/c) and what to
fix. Zero thickness at the trailing edge (a closed trailing edge) is normal and stays accepted, on
every real file of tests/data/uiuc.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from targets import Airfoil, AirfoilWarning, load_airfoil, naca
from targets.checks import self_crossings

DATA = Path(__file__).parents[1] / "data" / "uiuc"
#: The real files that are refused for a reason of their own (tests/data/uiuc/README.md), and why.
BROKEN = {"naca23021.dat": "expected two numbers", "mh112.dat": "not chord-normalised"}


def figure_of_eight(cross_at: float = 0.6, n_points: int = 81, touching: bool = False):
    """A NACA 0012 thickness whose surfaces swap sides at ``cross_at``: ``z = +-y_t(x) (cross_at - x)``.

    ``touching``: ``|cross_at - x|`` instead, with a node at ``cross_at`` on each surface, so the
    surfaces meet there (zero thickness) without crossing. Nodes at the NACA cosine stations.
    """
    base = naca("0012", n_points=n_points)
    half = n_points // 2
    upper_x = np.sort(np.append(base.x[:half], [cross_at] if touching else []))[::-1]  # trailing edge -> nose
    x = np.concatenate([upper_x, [0.0], upper_x[::-1]])
    thickness = 0.6 * (0.2969 * np.sqrt(x) - 0.1260 * x - 0.3516 * x**2 + 0.2843 * x**3 - 0.1036 * x**4)
    factor = np.abs(cross_at - x) if touching else (cross_at - x)
    z = thickness * factor
    z[upper_x.size + 1:] *= -1.0  # the lower surface
    z[0] = z[-1] = 0.0
    return x, z


def crossing_station(message: str) -> float:
    """The x/c a refusal names."""
    return float(re.search(r"at x/c = ([0-9.e-]+),", message).group(1))


def write_dat(path: Path, x, z, name: str = "EIGHT") -> Path:
    path.write_text(name + "\n" + "\n".join(f"{a:.8f} {b:.8f}" for a, b in zip(x, z)) + "\n")
    return path


def test_the_figure_of_eight_encloses_a_positive_area():
    # the premise: the older checks (area, orientation) do not see it
    x, z = figure_of_eight()
    area = 0.5 * np.sum(x * np.roll(z, -1) - np.roll(x, -1) * z)
    assert area > 1e-3


def test_a_figure_of_eight_file_is_refused_naming_where_it_crosses(tmp_path):
    path = write_dat(tmp_path / "eight.dat", *figure_of_eight(0.6))
    with pytest.raises(ValueError) as caught:
        load_airfoil(path)
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: airfoil 'EIGHT': its upper and lower surfaces cross at x/c = ")
    assert crossing_station(message) == pytest.approx(0.6, abs=0.005)  # the polygon's crossing, between nodes
    assert "between lines" in message and "negative thickness inside the chord" in message
    assert "correct the coordinates there" in message


def test_an_airfoil_that_crosses_itself_is_refused():
    with pytest.raises(ValueError, match=r"airfoil 'eight': its upper and lower surfaces cross at x/c = ") as caught:
        Airfoil(*figure_of_eight(0.45), name="eight")
    assert crossing_station(str(caught.value)) == pytest.approx(0.45, abs=0.005)


def test_a_section_pinched_to_zero_thickness_inside_the_chord_is_refused(tmp_path):
    x, z = figure_of_eight(0.5, touching=True)
    assert np.all(z[: x.size // 2] >= 0.0)  # the premise: nothing crosses, the surfaces only meet
    with pytest.raises(ValueError, match=r"surfaces meet at x/c = 0\.5, .*zero thickness inside the chord"):
        load_airfoil(write_dat(tmp_path / "pinch.dat", x, z))


def test_a_pinch_a_rounding_error_apart_is_zero_thickness():
    section = naca("0012", n_points=65)
    x, z = section.x.copy(), section.z.copy()
    k = 10  # upper node k and lower node n-1-k share their station (up to 1 ulp)
    z[k] = z[-1 - k] = 0.0
    crossings = self_crossings(x, z)
    assert len(crossings) == 1 and crossings[0].touching
    assert crossings[0].x == pytest.approx(x[k], abs=1e-12)


@pytest.mark.parametrize("name", sorted(p.name for p in DATA.glob("*.dat")))
def test_every_real_file_is_still_read(name):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AirfoilWarning)
        if name in BROKEN:
            with pytest.raises(ValueError, match=BROKEN[name]):
                load_airfoil(DATA / name)
            return
        airfoil = load_airfoil(DATA / name)
    assert self_crossings(airfoil.x, airfoil.z) == []
    # its closed-trailing-edge form (zero thickness at the trailing edge) and a resampling are accepted
    closed = airfoil.with_closed_trailing_edge()
    assert closed.closed_te and closed.resample(129).n_points == 129 and closed.resample(33).n_points == 33


@pytest.mark.parametrize("code", ["0001", "0006", "2412", "23012", "4440"])
@pytest.mark.parametrize("closed_te", [True, False])
def test_thin_thick_open_and_closed_naca_sections_are_accepted(code, closed_te):
    for n_points in (7, 33, 257):
        section = naca(code, n_points=n_points, closed_te=closed_te)
        assert self_crossings(section.x, section.z) == []


def test_the_command_refuses_a_crossing_target_with_one_line(tmp_path, capsys):
    from inverse_design.app import cli

    path = write_dat(tmp_path / "eight.dat", *figure_of_eight(0.6))
    code = cli.main(["--target", str(path), "--out", str(tmp_path / "out"), "--n-span", "5", "--n-contour", "32"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and crossing_station(err[0]) == pytest.approx(0.6, abs=0.005)
    assert not (tmp_path / "out").exists()


# --------------------------------------------------------------------------- a rib shape that crosses


#: Inward coefficients (upper, then lower surface, K = 2) that make NACA 2412's rib cross itself.
CROSSING_SHAPE = np.array([-0.2, -0.3, -0.2, -0.2])


def test_rib_crossings_names_where_and_how_deep():
    from forward_solver import Parameters
    from inverse_design.rib_design import rib_crossings

    section = naca("2412")
    start = Parameters(pressure=1e4, prestrain_span=0.02, prestrain_chord=0.02)
    assert rib_crossings([section, section], start.replace(rib_shape=np.zeros(4))) == ({}, [])
    violated, messages = rib_crossings([section, section], start.replace(rib_shape=CROSSING_SHAPE))
    assert len(messages) == 1 and "the designed rib crosses itself at x/c = " in messages[0]
    assert "keep the rib limits on" in messages[0]
    # the amount: the lower surface's height above the upper one, at the section's own stations
    depth = max(violated["rib_crossing"].values())
    assert 0.01 < depth < 0.2 and f"{depth:.3g} chord above the upper one" in messages[0]


def test_a_design_whose_rib_crosses_itself_is_a_failure_with_the_amount():
    from forward_solver import Bay, Fabric, Scene
    from inverse_design import Limits, SolverSettings, optimise_pressure

    section = naca("2412")
    bay = Bay.from_airfoil(section, chord=1.0, rib_spacing=0.25, n_span=5, n_contour=32)
    scene = Scene(bay=bay, fabric=Fabric(stiffness_span=2e5, stiffness_chord=2e5, poisson=0.25,
                                         areal_density=0.3, viscosity=0.0))
    # Bounds that leave no rib but a crossed one, and no rib limits to keep it out.
    result = optimise_pressure(scene, section, variables=("rib_shape",),
                               initial={"pressure": 1e4, "prestrain_span": 0.02, "prestrain_chord": 0.02,
                                        "rib_shape": CROSSING_SHAPE},
                               bounds={"rib_shape": (-0.3, -0.2)}, method="least_squares",
                               limits=Limits(ribs=None), solver=SolverSettings(max_iterations=1))
    assert not result.success
    amount = float(result.violated_constraints["rib_crossing"])
    assert amount > 0.01
    assert "the designed rib crosses itself at x/c = " in result.message and f"{amount:.3g} chord" in result.message
