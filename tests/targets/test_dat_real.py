"""The ``.dat`` reader on real UIUC database files (tests/data/uiuc, see its README).

Each file exercised one reader or spline failure found by
benchmarks/dat_database.py: trailing comments, extra header lines, chords a
little off unit length, x(s) turning back near a sharp nose or trailing edge,
and two genuinely broken files that must stay refused with a message naming
the problem.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from targets import AirfoilWarning, load_airfoil, naca
from targets.dat import RENORMALISE_LIMIT
from targets.monotone_spline import REVERSAL_TOLERANCE, limit_x_reversals

DATA = Path(__file__).parents[1] / "data" / "uiuc"


def load_quietly(name: str):
    """Loads a file that must need no correction: any warning fails the test."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return load_airfoil(DATA / name)


def raw_points(name: str, skip: int = 1) -> np.ndarray:
    """The file's points by numpy alone (rows of exactly two numbers after ``skip`` lines)."""
    rows = []
    for line in (DATA / name).read_text().splitlines()[skip:]:
        try:
            values = [float(token) for token in line.split()]
        except ValueError:
            break  # the trailing comment
        if len(values) == 2:
            rows.append(values)
    return np.array(rows)


def assert_surfaces_monotonic(airfoil, n_points: int = 201) -> None:
    """Resampled nodes run monotonically in x on each surface, and thickness is >= 0."""
    nodes = airfoil.resample(n_points)
    half = n_points // 2
    assert np.all(np.diff(nodes.x[: half + 1]) < 0.0)  # upper: trailing edge -> nose
    assert np.all(np.diff(nodes.x[half:]) > 0.0)  # lower: nose -> trailing edge
    stations = np.linspace(airfoil.leading_edge[0], min(airfoil.x[0], airfoil.x[-1]), 401)
    assert np.all(airfoil.thickness(stations) >= -1e-12)
    assert np.all(np.isfinite(airfoil.camber(stations)))


# --------------------------------------------------------------------------- text around points


def test_trailing_comment_is_skipped():
    text = (DATA / "mg06.dat").read_text().splitlines()
    assert text[72].startswith("\t\t\t1.35 avec")  # the comment holds a line starting with a number
    airfoil = load_quietly("mg06.dat")
    expected = raw_points("mg06.dat")
    assert airfoil.n_points == len(expected) == 62  # lines 2-63; the comment starts at 65
    np.testing.assert_array_equal(airfoil.points, expected)
    assert_surfaces_monotonic(airfoil)


def test_text_between_points_is_refused_with_its_line(tmp_path):
    lines = (DATA / "mg06.dat").read_text().splitlines()
    path = tmp_path / "moved_comment.dat"
    path.write_text("\n".join(lines[:30] + lines[64:66] + lines[30:64]) + "\n")  # lines 31-32
    with pytest.raises(ValueError, match=r"moved_comment\.dat, line 31: expected two numbers"):
        load_airfoil(path)


def test_damaged_last_point_is_not_taken_for_a_comment(tmp_path):
    lines = (DATA / "mg06.dat").read_text().splitlines()
    path = tmp_path / "damaged.dat"
    path.write_text("\n".join(lines[:63] + ["1"] + lines[64:]) + "\n")  # line 64 lost its z
    message = r"damaged\.dat, line 64: expected two numbers 'x z', got '1'"
    with pytest.raises(ValueError, match=message):
        load_airfoil(path)


def test_second_header_line_and_mses_domain_line():
    airfoil = load_quietly("s1020.dat")
    assert airfoil.name == "Ornithopter airfoil."
    np.testing.assert_array_equal(airfoil.points, raw_points("s1020.dat", skip=2))
    mses = load_quietly("tasopt-b.dat")
    assert mses.name == "BOEING 737 INNER MIDSPAN AIRFOIL"
    np.testing.assert_array_equal(mses.points, raw_points("tasopt-b.dat", skip=2))
    assert mses.n_points == 160 and tuple(mses.points[0]) == (1.0, 0.0004)


# --------------------------------------------------------------------------- chord renormalisation


@pytest.mark.parametrize(
    ("name", "trailing_edge", "leading_edge"),
    [("ah88k136.dat", 1.00058, 0.0008), ("fx77w153.dat", 0.99893, 0.0)],
)
def test_small_chord_error_is_renormalised_with_a_warning(name, trailing_edge, leading_edge):
    with pytest.warns(AirfoilWarning) as caught:
        airfoil = load_airfoil(DATA / name)
    assert len(caught) == 1
    message = str(caught[0].message)
    chord = trailing_edge - leading_edge
    assert f"trailing edge was at x = {trailing_edge:.9g}" in message
    assert f"leading edge at x = {leading_edge:.9g}" in message
    scale = float(re.search(r"scaled by (\S+)$", message).group(1))
    assert scale == pytest.approx(1.0 / chord, rel=1e-8)  # printed to 9 significant digits
    # The same similarity map applied by hand to the raw points (rounding only).
    raw = raw_points(name)
    np.testing.assert_allclose(airfoil.x, (raw[:, 0] - leading_edge) / chord, rtol=0, atol=1e-12)
    np.testing.assert_allclose(airfoil.z, raw[:, 1] / chord, rtol=0, atol=1e-12)
    assert abs(0.5 * (airfoil.x[0] + airfoil.x[-1]) - 1.0) <= 1e-12
    assert abs(airfoil.x.min()) <= 1e-12
    assert_surfaces_monotonic(airfoil)


def test_chord_error_above_the_limit_is_refused(tmp_path):
    section = naca("0012", n_points=33)
    path = tmp_path / "long.dat"
    scale = 1.0 + 2.0 * RENORMALISE_LIMIT  # e.g. measured to the end of a tab
    rows = [f"{scale * x:.8f} {scale * z:.8f}" for x, z in zip(section.x, section.z)]
    path.write_text("LONG\n" + "\n".join(rows) + "\n")
    with pytest.raises(ValueError, match=r"long\.dat: .* is at x = 1\.01 .*renormalised, this one"):
        load_airfoil(path)


# --------------------------------------------------------------------------- spline turning back


def test_sharp_nose_spline_stays_monotonic():
    raw = raw_points("rc0864c.dat")
    nose = int(np.argmin(raw[:, 0]))
    # The premise: the points themselves run monotonically to and from the nose.
    assert np.all(np.diff(raw[: nose + 1, 0]) < 0) and np.all(np.diff(raw[nose:, 0]) > 0)
    airfoil = load_quietly("rc0864c.dat")
    assert_surfaces_monotonic(airfoil)
    # The repaired spline has its minimum x at the nose point (it overshot it by 1.5e-4).
    np.testing.assert_allclose(airfoil.leading_edge, raw[nose], atol=1e-12)
    # Thickness grows from the nose, and the contour still runs through every point.
    near_nose = np.linspace(0.0, 0.02, 81)
    assert np.all(np.diff(airfoil.thickness(near_nose)) > 0.0)
    assert np.abs(airfoil.distance(airfoil.points)).max() < 1e-12


@pytest.mark.parametrize("name", ["fx73170a.dat", "dbln526.dat"])
def test_trailing_edge_spline_stays_monotonic(name):
    airfoil = load_quietly(name)
    assert_surfaces_monotonic(airfoil)
    assert airfoil.thickness(1.0) == pytest.approx(0.0, abs=1e-12)  # closed trailing edge
    assert np.abs(airfoil.distance(airfoil.points)).max() < 1e-12


def test_kinked_sharp_trailing_edge_is_a_corner():
    # fx73170a turns 2.12 rad at its trailing edge and 0.59 rad at the next node; a smooth
    # join would round the corner off (private attribute: the choice has no public switch).
    assert not load_quietly("fx73170a.dat")._contour.periodic
    assert load_quietly("dbln526.dat")._contour.periodic  # the rounded one stays smooth


def test_reversal_repair_touches_only_reversing_splines():
    smooth = naca("2412", n_points=65)._contour
    assert limit_x_reversals(smooth.spline, smooth.spline(smooth.spline.x)[:, 0], False) is (
        smooth.spline
    )
    raw = raw_points("rc0864c.dat")
    knots = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(raw, axis=0).T))])
    spline = CubicSpline(knots, raw, axis=0)
    repaired = limit_x_reversals(spline, raw[:, 0], False)
    assert repaired is not spline
    s = np.linspace(0.0, knots[-1], 200_001)
    np.testing.assert_allclose(repaired(knots), raw, atol=1e-14)  # still interpolates
    np.testing.assert_array_equal(repaired(s)[:, 1], spline(s)[:, 1])  # z untouched
    slope = repaired(s, 1)[:, 0]
    nose = knots[int(np.argmin(raw[:, 0]))]
    assert np.all(slope[s < nose] <= REVERSAL_TOLERANCE)
    assert np.all(slope[s > nose] >= -REVERSAL_TOLERANCE)
    original = spline(s, 1)[:, 0]
    assert np.any(original[s < nose] > 1e-3) or np.any(original[s > nose] < -1e-3)


# --------------------------------------------------------------------------- broken files


def test_missing_values_are_refused_naming_the_line():
    with pytest.raises(ValueError, match=r"naca23021\.dat, line 2: expected two numbers"):
        load_airfoil(DATA / "naca23021.dat")


def test_incomplete_surface_is_refused():
    message = r"mh112\.dat: .*not chord-normalised.*surfaces end 0\.138 apart in x: is one"
    with pytest.raises(ValueError, match=message):
        load_airfoil(DATA / "mh112.dat")
