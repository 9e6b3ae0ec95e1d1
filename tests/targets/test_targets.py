"""Tests of targets/: NACA geometry, airfoil files, the smooth contour and distance.

References are closed forms (Report 824 formulas and constants, a circle) or
brute-force dense projections onto the analytic NACA surface, each with a
stated tolerance.
"""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.path import Path as PolygonPath
from scipy.integrate import quad
from scipy.optimize import brentq, minimize_scalar
from scipy.spatial import cKDTree

from targets import Airfoil, load_airfoil, naca, parse_naca
from targets.naca import FIVE_DIGIT_MEAN_LINES, LEADING_EDGE_RADIUS_FACTOR

CODES = ["0012", "2412", "4415", "23012", "23112"]


# --------------------------------------------------------------------------- helpers


def circle(n_points: int) -> Airfoil:
    """Circle of diameter 1 centred at (0.5, 0), Selig order, uniform angles."""
    angle = np.linspace(0.0, 2.0 * np.pi, n_points)
    x, z = 0.5 + 0.5 * np.cos(angle), 0.5 * np.sin(angle)
    x[-1], z[-1] = x[0], z[0]
    return Airfoil(x, z, name="circle")


def reference_distance(section, points: np.ndarray) -> np.ndarray:
    """Signed distance by brute force: 200k analytic samples, then 401 around the nearest.

    The local window is ±2 sample spacings, so the foot parameter is resolved
    to 3e-7 rad: the distance error is far below 1e-9 chord.
    """
    phi = np.linspace(0.0, 2.0 * np.pi, 200_001)
    samples = np.column_stack(section.surface(phi))
    _, nearest = cKDTree(samples).query(points)
    spacing = phi[1] - phi[0]
    window = np.mod(phi[nearest][:, None] + np.linspace(-2, 2, 401) * spacing, 2.0 * np.pi)
    x, z = section.surface(window)
    distance = np.hypot(x - points[:, :1], z - points[:, 1:]).min(axis=1)
    first, last = samples[0], samples[-1]
    if not np.array_equal(first, last):  # open trailing edge: the straight base closes it
        base = first - last
        fraction = np.clip((points - last) @ base / (base @ base), 0.0, 1.0)
        to_base = np.linalg.norm(points - last - fraction[:, None] * base, axis=1)
        distance = np.minimum(distance, to_base)
    inside = PolygonPath(samples).contains_points(points)
    return np.where(inside, -distance, distance)


def minimum_x_parameter(section) -> float:
    """Angle parameter of the analytic surface's minimum-x point (upper side for camber >= 0)."""
    x_of = lambda phi: float(section.surface(np.array(phi))[0])
    bounds = (np.pi - 0.5, np.pi)
    return minimize_scalar(x_of, bounds=bounds, method="bounded", options={"xatol": 1e-12}).x


def vertical_cut(section, stations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Upper and lower z of the analytic surface at chordwise stations (brentq on phi)."""
    x_of = lambda phi: float(section.surface(np.array(phi))[0])
    phi_le = minimum_x_parameter(section)
    cut = []
    for low, high in ((0.0, phi_le), (phi_le, 2 * np.pi)):
        phi = [brentq(lambda v: x_of(v) - x, low, high, xtol=1e-14) for x in stations]
        cut.append(section.surface(np.array(phi))[1])
    return cut[0], cut[1]


def analytic_normal(section, phi: np.ndarray) -> np.ndarray:
    """Outward unit normal of the analytic surface (central differences, h = 1e-6 rad)."""
    h = 1e-6
    xp, zp = section.surface(phi + h)
    xm, zm = section.surface(phi - h)
    tangent = np.column_stack([xp - xm, zp - zm])
    normal = np.column_stack([tangent[:, 1], -tangent[:, 0]])
    return normal / np.linalg.norm(normal, axis=1, keepdims=True)


def thin_airfoil_coefficients(slope, r: float) -> tuple[float, float]:
    """Design lift c_l = pi A1 and moment c_m,c/4 = pi/4 (A2 - A1) (thin-airfoil theory).

    Args:
        slope: dy_c/dx of the mean line as a function of x.
        r: Station where the mean line's formula changes (the integral is split there).
    """

    def fourier(n: int) -> float:
        theta_r = np.arccos(1.0 - 2.0 * r)  # split at the mean line's joint x = r
        f = lambda theta: slope((1.0 - np.cos(theta)) / 2.0) * np.cos(n * theta)
        pieces = ((0.0, theta_r), (theta_r, np.pi))
        return 2.0 / np.pi * sum(quad(f, a, b, epsabs=1e-13, epsrel=1e-12)[0] for a, b in pieces)

    a1, a2 = fourier(1), fourier(2)
    return np.pi * a1, np.pi / 4.0 * (a2 - a1)


def write_selig(path, airfoil: Airfoil, name: str = "TEST SECTION") -> None:
    lines = [name] + [f"{x:.12f} {z:.12f}" for x, z in zip(airfoil.x, airfoil.z)]
    path.write_text("\n".join(lines) + "\n")


def write_lednicer(path, airfoil: Airfoil, name: str = "TEST SECTION") -> None:
    le = (airfoil.n_points - 1) // 2
    upper = list(zip(airfoil.x[: le + 1], airfoil.z[: le + 1]))[::-1]
    lower = list(zip(airfoil.x[le:], airfoil.z[le:]))
    lines = [name, f"{len(upper)}. {len(lower)}.", ""]
    lines += [f"  {x:.12f}  {z:.12f}" for x, z in upper] + [""]
    lines += [f"  {x:.12f}  {z:.12f}" for x, z in lower]
    path.write_text("\n".join(lines) + "\n")


# --------------------------------------------------------------------------- NACA 4-digit


@pytest.mark.parametrize("code", ["0006", "0012", "0015", "0024"])
@pytest.mark.parametrize("closed_te", [True, False])
def test_symmetric_max_thickness_and_location(code, closed_te):
    t = int(code[2:]) / 100
    section = parse_naca(code, closed_te)
    airfoil = section.airfoil()
    # Analytic maximiser of y_t (the report quotes 30 % chord).
    dydx = lambda x: (section.half_thickness(x + 1e-7) - section.half_thickness(x - 1e-7)) / 2e-7
    x_max = brentq(dydx, 0.2, 0.4, xtol=1e-12)
    # The spline follows the surface to ~1e-9; the flat maximum is located to ~1e-5.
    assert airfoil.max_thickness == pytest.approx(2 * section.half_thickness(x_max), abs=1e-9)
    assert airfoil.max_thickness_location == pytest.approx(x_max, abs=2e-5)
    # Report 824: maximum thickness t at 0.30 chord (the polynomial: t to 3e-4 t, 0.2995-0.2998).
    assert airfoil.max_thickness == pytest.approx(t, rel=3e-4)
    assert airfoil.max_thickness_location == pytest.approx(0.30, abs=1e-3)


@pytest.mark.parametrize("code", ["2412", "4415", "6409"])
def test_four_digit_max_camber_m_at_p(code):
    m, p = int(code[0]) / 100, int(code[1]) / 10
    line = parse_naca(code).mean_line
    # Exact mean line: maximum m at p, zero slope there, zero at both ends.
    x = np.linspace(0, 1, 100_001)
    ordinate, slope = line(x)
    assert ordinate.max() == pytest.approx(m, abs=1e-15)
    assert x[np.argmax(ordinate)] == pytest.approx(p, abs=1e-12)
    assert line(np.array([p]))[1][0] == pytest.approx(0.0, abs=1e-15)
    assert line(np.array([0.0, 1.0]))[0] == pytest.approx([0.0, 0.0], abs=1e-15)
    # Camber read off the contour (vertical mid-point of the surfaces): thickness laid
    # perpendicular to the mean line shifts it by O(t^2 * camber curvature): 2e-6 chord in value,
    # up to 4e-3 chord in location for these sections.
    airfoil = naca(code)
    assert airfoil.max_camber == pytest.approx(m, abs=2e-6)
    assert airfoil.max_camber_location == pytest.approx(p, abs=5e-3)


@pytest.mark.parametrize(
    ("code", "nodes_tolerance"), [("0006", None), ("0012", 0.01), ("0021", 0.01)]
)
def test_symmetric_leading_edge_radius(code, nodes_tolerance):
    t = int(code[2:]) / 100
    # Report 824: r = 1.1019 t^2; the polynomial gives exactly 25 * 0.2969^2 / 2 = 1.10187 t^2.
    assert LEADING_EDGE_RADIUS_FACTOR == pytest.approx(25 * 0.2969**2 / 2, rel=3e-5)
    # Curvature of naca()'s smooth representation (4097 analytic samples) at the leading edge:
    # 1e-4 relative for t = 0.06, 2e-5 for t = 0.12 (it converges as h^2 / r^2).
    radius = naca(code).leading_edge_radius
    assert radius == pytest.approx(LEADING_EDGE_RADIUS_FACTOR * t**2, rel=2e-4)
    if nodes_tolerance is not None:
        # From the 257 nodes alone (as for a .dat file): 0.6 % for t = 0.12, 0.2 % for 0.21.
        nodes = naca(code)
        plain = Airfoil(nodes.x, nodes.z)
        expected = LEADING_EDGE_RADIUS_FACTOR * t**2
        assert plain.leading_edge_radius == pytest.approx(expected, rel=nodes_tolerance)


@pytest.mark.parametrize("code", ["2412", "4415", "23012", "23112"])
def test_cambered_leading_edge_radius_matches_analytic_curvature(code):
    section = parse_naca(code)
    # Independent reference: the minimum-x point of the analytic surface, curvature by
    # central differences (h = 1e-4 rad, error ~1e-7 relative).
    phi_le = minimum_x_parameter(section)
    h = 1e-4
    x, z = section.surface(phi_le + h * np.array([-1.0, 0.0, 1.0]))
    dx, dz = (x[2] - x[0]) / (2 * h), (z[2] - z[0]) / (2 * h)
    ddx, ddz = (x[2] - 2 * x[1] + x[0]) / h**2, (z[2] - 2 * z[1] + z[0]) / h**2
    radius = (dx**2 + dz**2) ** 1.5 / (dx * ddz - dz * ddx)
    airfoil = section.airfoil()
    assert airfoil.leading_edge[0] == pytest.approx(section.surface(phi_le)[0], abs=1e-9)
    assert airfoil.leading_edge_radius == pytest.approx(radius, rel=1e-4)
    # Near 1.1019 t^2, but not equal: the minimum-x point is not the end of the camber line.
    t = int(code[-2:]) / 100
    assert airfoil.leading_edge_radius == pytest.approx(LEADING_EDGE_RADIUS_FACTOR * t**2, rel=0.05)


@pytest.mark.parametrize("code", CODES)
def test_trailing_edge_closed_or_open_by_parameter(code):
    t = int(code[-2:]) / 100
    closed = naca(code, closed_te=True)
    assert closed.closed_te
    assert closed.x[0] == closed.x[-1] and closed.z[0] == closed.z[-1]
    assert closed.x[0] == 1.0
    opened = naca(code, closed_te=False)
    assert not opened.closed_te
    # Open edge: 2 y_t(1) = 10 t (0.2969 - 0.1260 - 0.3516 + 0.2843 - 0.1015) = 0.021 t, laid
    # perpendicular to the mean line, so the two end points are that far apart.
    gap = np.hypot(opened.x[0] - opened.x[-1], opened.z[0] - opened.z[-1])
    assert gap == pytest.approx(0.021 * t, rel=1e-9)
    assert 0.5 * (opened.x[0] + opened.x[-1]) == pytest.approx(1.0, abs=1e-15)


@pytest.mark.parametrize("n_points", [16, 17, 257])
@pytest.mark.parametrize("code", ["2412", "23112"])
def test_selig_order_cosine_stations_and_perpendicular_thickness(code, n_points):
    section = parse_naca(code)
    airfoil = naca(code, n_points=n_points)
    assert airfoil.n_points == n_points
    k = np.arange(n_points)
    station = (1 + np.cos(2 * np.pi * k / (n_points - 1))) / 2
    upper, lower = airfoil.points[: n_points // 2], airfoil.points[::-1][: n_points // 2]
    # Node k and node n-1-k share the camber-line station: their mid-point is on the mean line
    # and their difference is perpendicular to it (thickness normal to the camber line).
    middle = 0.5 * (upper + lower)
    ordinate, slope = section.mean_line(station[: n_points // 2])
    np.testing.assert_allclose(middle[:, 0], station[: n_points // 2], atol=1e-15)
    np.testing.assert_allclose(middle[:, 1], ordinate, atol=1e-15)
    along = (upper - lower) @ np.array([1.0, 0.0]) + (upper - lower)[:, 1] * slope
    np.testing.assert_allclose(along, 0.0, atol=1e-15)
    thickness = 2 * section.half_thickness(station[: n_points // 2])
    np.testing.assert_allclose(np.hypot(*(upper - lower).T), thickness, atol=1e-15)
    # Upper surface first (above the lower one), leading edge not duplicated.
    assert np.all(upper[1:, 1] > lower[1:, 1])
    if n_points % 2:
        assert airfoil.x[n_points // 2] == 0.0 and airfoil.z[n_points // 2] == 0.0
        assert np.sum((airfoil.x == 0.0) & (airfoil.z == 0.0)) == 1


@pytest.mark.parametrize("spelling", ["2412", "NACA2412", "naca 2412", "NACA-2412", " naca 2412 "])
def test_code_spellings(spelling):
    reference = naca("2412", n_points=33)
    airfoil = naca(spelling, n_points=33)
    np.testing.assert_array_equal(airfoil.x, reference.x)
    np.testing.assert_array_equal(airfoil.z, reference.z)
    assert airfoil.name == "NACA 2412"


@pytest.mark.parametrize(
    ("code", "hint"),
    [
        ("abcd", "expected 4 or 5 digits"),
        ("0000", "must not be 00"),
        ("2012", "camber-position digit 1-9"),
        ("0412", "use '0012'"),
        ("241200", "6 digits"),
        ("03012", "for a symmetric section use"),
        ("23212", "third digit must be 0"),
        ("26012", "not tabulated"),
        ("21112", "not tabulated"),
        ("23000", "must not be 00"),
        ("24 12", "expected 4 or 5 digits"),
    ],
)
def test_invalid_codes_say_what_to_change(code, hint):
    with pytest.raises(ValueError, match="is not a valid 4- or 5-digit code") as info:
        naca(code)
    assert repr(code) in str(info.value)
    assert hint in str(info.value)


@pytest.mark.parametrize("n_points", [3, 6, 0, -5, 10.0, True])
def test_invalid_point_counts(n_points):
    with pytest.raises(ValueError, match="n_points"):
        naca("0012", n_points=n_points)


def test_closed_te_must_be_bool_and_code_a_string():
    with pytest.raises(ValueError, match="closed_te"):
        naca("0012", closed_te="yes")
    with pytest.raises(TypeError, match="string"):
        naca(12)


# --------------------------------------------------------------------------- NACA 5-digit


@pytest.mark.parametrize("line", sorted(FIVE_DIGIT_MEAN_LINES))
def test_five_digit_mean_line_against_report_constants(line):
    constants = FIVE_DIGIT_MEAN_LINES[line]
    r, p = constants.r, constants.position
    mean_line = parse_naca(line + "12").mean_line
    # Continuous ordinate and slope where the front cubic meets the rear part (x = r), zero at
    # both ends.
    ordinate, slope = mean_line(np.array([r * (1 - 1e-13), r]))
    assert ordinate[0] == pytest.approx(ordinate[1], abs=1e-12)
    assert slope[0] == pytest.approx(slope[1], abs=1e-9)
    np.testing.assert_allclose(mean_line(np.array([0.0, 1.0]))[0], 0.0, atol=1e-15)
    # Maximum camber at p = 0.05 P: r was tabulated to 4 decimals (standard: p = r(1 - sqrt(r/3))).
    x = np.linspace(0, 1, 400_001)
    assert x[np.argmax(mean_line(x)[0])] == pytest.approx(p, abs=3e-4)
    if not constants.k2_over_k1:
        assert r * (1 - np.sqrt(r / 3)) == pytest.approx(p, abs=3e-4)
    # k1 gives the design lift coefficient 0.3 (thin-airfoil theory, c_l = pi A1); the rounded
    # constants reproduce it within 3 % (the 210 line: 0.308; the others within 0.5 %).
    lift, moment = thin_airfoil_coefficients(lambda v: mean_line(np.asarray(v))[1], r)
    assert lift == pytest.approx(0.3, rel=0.03)
    if constants.k2_over_k1:
        # Reflexed lines: k2/k1 is chosen for zero quarter-chord pitching moment. The standard
        # lines give -0.004 to -0.024; the rounded k2/k1 leaves at most 1.5e-3.
        standard = parse_naca(line[:2] + "012").mean_line
        standard_r = FIVE_DIGIT_MEAN_LINES[line[:2] + "0"].r
        _, standard_moment = thin_airfoil_coefficients(
            lambda v: standard(np.asarray(v))[1], standard_r
        )
        assert abs(moment) < 1.5e-3
        assert abs(moment) < 0.2 * abs(standard_moment)
    else:
        assert moment < -3e-3


def test_five_digit_camber_scales_with_design_lift():
    x = np.linspace(0, 1, 1001)
    base = parse_naca("23012").mean_line(x)[0]
    for lift_digit in (1, 4, 6):
        scaled = parse_naca(f"{lift_digit}3012").mean_line(x)[0]
        np.testing.assert_allclose(scaled, base * lift_digit / 2, rtol=1e-14, atol=1e-17)
        mean_line = parse_naca(f"{lift_digit}3012").mean_line
        lift, _ = thin_airfoil_coefficients(lambda v: mean_line(np.asarray(v))[1], 0.2025)
        assert lift == pytest.approx(0.15 * lift_digit, rel=5e-3)


def test_five_digit_sections_share_four_digit_thickness():
    # 23012 and 0012 have the same y_t: the perpendicular distance of paired nodes is 2 y_t.
    cambered, symmetric = naca("23012", n_points=65), naca("0012", n_points=65)
    gap = np.hypot(cambered.x - cambered.x[::-1], cambered.z - cambered.z[::-1])
    np.testing.assert_allclose(gap, np.abs(symmetric.z - symmetric.z[::-1]), atol=1e-15)


# --------------------------------------------------------------------------- Airfoil, circle


def test_circle_geometry():
    airfoil = circle(257)
    assert airfoil.closed_te
    np.testing.assert_allclose(airfoil.leading_edge, [0.0, 0.0], atol=1e-12)
    # Curvature of a cubic spline through 257 points of a circle: 5e-5 relative.
    assert airfoil.leading_edge_radius == pytest.approx(0.5, rel=1e-4)
    assert airfoil.max_thickness == pytest.approx(1.0, abs=1e-9)
    assert airfoil.max_thickness_location == pytest.approx(0.5, abs=1e-4)
    x = np.linspace(0.0, 1.0, 101)
    np.testing.assert_allclose(airfoil.thickness(x), 2 * np.sqrt(x * (1 - x)), atol=1e-6)
    np.testing.assert_allclose(airfoil.camber(x), 0.0, atol=1e-9)


@pytest.mark.parametrize("n_points", [16, 17, 256, 257, 1000])
def test_resampled_circle_has_uniform_angles(n_points):
    resampled = circle(257).resample(n_points)
    angle = np.mod(np.arctan2(resampled.z, resampled.x - 0.5), 2 * np.pi)
    angle[-1] = 2 * np.pi
    # The spline through 257 points follows the circle to 5e-10, which sets the angle error.
    np.testing.assert_allclose(angle, 2 * np.pi * np.arange(n_points) / (n_points - 1), atol=1e-7)
    assert resampled.closed_te and resampled.x[0] == 1.0


def test_circle_signed_distance():
    airfoil = circle(257)
    rng = np.random.default_rng(1)
    radius, angle = rng.uniform(0.02, 1.5, 2000), rng.uniform(0, 2 * np.pi, 2000)
    points = np.column_stack([0.5 + radius * np.cos(angle), radius * np.sin(angle)])
    # Spline vs circle: 5e-10 for 257 points.
    np.testing.assert_allclose(airfoil.distance(points), radius - 0.5, atol=1e-8)
    projection = airfoil.project(points)
    # The spline's tangent follows the circle to 3e-7 rad; near the centre the closest point is
    # ill-conditioned (errors grow as 1 / (1 - curvature * depth)), so those points are left out.
    away = np.abs(radius - 0.5) < 0.3
    expected = np.column_stack([np.cos(angle), np.sin(angle)])
    np.testing.assert_allclose(projection.normal[away], expected[away], atol=1e-6)
    foot_radius = np.hypot(projection.foot[:, 0] - 0.5, projection.foot[:, 1])
    np.testing.assert_allclose(foot_radius, 0.5, atol=1e-8)


def test_distance_keeps_the_batch_shape():
    airfoil = naca("0012", n_points=65)
    points = np.random.default_rng(2).uniform(-0.1, 1.1, size=(3, 4, 2))
    assert airfoil.distance(points).shape == (3, 4)
    assert airfoil.distance(np.array([0.3, 0.5])).shape == ()
    assert airfoil.project(points).foot.shape == (3, 4, 2)
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 2\)"):
        airfoil.distance(np.zeros((4, 3)))
    with pytest.raises(ValueError, match="finite"):
        airfoil.distance(np.array([[np.nan, 0.0]]))


def test_scaled_and_read_only_nodes():
    airfoil = naca("2412", n_points=33)
    x, z = airfoil.scaled(0.35)
    np.testing.assert_allclose(x, 0.35 * airfoil.x)
    np.testing.assert_allclose(z, 0.35 * airfoil.z)
    with pytest.raises(ValueError, match="positive"):
        airfoil.scaled(-1.0)
    with pytest.raises(ValueError):
        airfoil.x[0] = 2.0


# --------------------------------------------------------------------------- distance vs analytic


@pytest.mark.parametrize("closed_te", [True, False])
@pytest.mark.parametrize("code", CODES)
def test_distance_zero_on_curve_and_offset_along_normal(code, closed_te):
    section = parse_naca(code, closed_te)
    airfoil = section.airfoil(65)  # coarse nodes: accuracy comes from the smooth representation
    rng = np.random.default_rng(3)
    phi = np.concatenate([rng.uniform(0, 2 * np.pi, 600), [0.0, np.pi, 2 * np.pi]])
    on_curve = np.column_stack(section.surface(phi))
    np.testing.assert_allclose(airfoil.distance(on_curve), 0.0, atol=1e-7)
    # Offsets along the analytic normal, away from the trailing-edge wedge and the leading edge
    # singular parameter; inward offsets stay well inside the local half thickness.
    phi = rng.uniform(0.15, 2 * np.pi - 0.15, 600)
    phi = phi[np.abs(phi - np.pi) > 1e-3]
    base = np.column_stack(section.surface(phi))
    normal = analytic_normal(section, phi)
    half = section.half_thickness(np.cos(phi / 2) ** 2)
    outward = rng.uniform(1e-6, 0.02, phi.size)
    inward = -rng.uniform(1e-6, 0.4, phi.size) * half
    offset = np.where(rng.random(phi.size) < 0.5, outward, inward)
    distance = airfoil.distance(base + offset[:, None] * normal)
    # 1e-6 chord is the target; the spline of 4097 samples measures 5e-8 at worst (the tangent
    # kink of 4-digit surfaces at x = p).
    np.testing.assert_allclose(distance, offset, atol=1e-6)
    assert np.all(np.sign(distance) == np.sign(offset))


@pytest.mark.parametrize("closed_te", [True, False])
@pytest.mark.parametrize("code", CODES)
def test_distance_matches_brute_force_projection(code, closed_te):
    section = parse_naca(code, closed_te)
    airfoil = section.airfoil(129)
    rng = np.random.default_rng(4)
    boxes = [  # (x range, z range, count): anywhere, near the section, trailing and leading edge
        ((-0.3, 1.3), (-0.4, 0.4), 600),
        ((0.0, 1.0), (-0.08, 0.1), 300),
        ((0.97, 1.03), (-0.02, 0.02), 200),
        ((-0.03, 0.03), (-0.03, 0.03), 200),
    ]
    points = np.vstack(
        [np.column_stack([rng.uniform(*xs, n), rng.uniform(*zs, n)]) for xs, zs, n in boxes]
    )
    expected = reference_distance(section, points)
    # Measured: 5e-8 at worst (4-digit kink at x = p), 1e-10 elsewhere; the target is 1e-6.
    np.testing.assert_allclose(airfoil.distance(points), expected, atol=1e-6, rtol=0)


def test_projection_normal_is_the_gradient_of_distance():
    airfoil = naca("2412", closed_te=False)
    rng = np.random.default_rng(6)
    points = np.column_stack([rng.uniform(-0.1, 1.1, 300), rng.uniform(-0.15, 0.15, 300)])
    h = 1e-6
    gradient = np.stack(
        [
            (airfoil.distance(points + h * e) - airfoil.distance(points - h * e)) / (2 * h)
            for e in np.eye(2)
        ],
        axis=-1,
    )
    # Central differences of a distance accurate to ~1e-15 relative: error ~1e-8.
    np.testing.assert_allclose(airfoil.project(points).normal, gradient, atol=1e-6)


def test_resampled_naca_nodes_lie_on_the_analytic_surface():
    for code in ("2412", "23112"):
        section = parse_naca(code)
        for n_points in (64, 65):
            resampled = section.airfoil().resample(n_points)
            # 7e-8 at worst, at the tangent kink of the 4-digit surface at x = p.
            off = reference_distance(section, resampled.points)
            np.testing.assert_allclose(off, 0.0, atol=1e-7)
            k = np.arange(n_points)
            station = (1 + np.cos(2 * np.pi * k / (n_points - 1))) / 2
            x_le = resampled.leading_edge[0]
            np.testing.assert_allclose(resampled.x, x_le + (1 - x_le) * station, atol=1e-14)
            # Away from the nose (where the minimum-x point lies on the upper surface), upper
            # nodes lie above the mean line and lower nodes below it.
            upper, lower = 2 * k < n_points - 1, 2 * k > n_points - 1
            camber = section.mean_line(np.clip(resampled.x, 0, 1))[0]
            away = (resampled.x > 0.01) & (resampled.x < 1.0)
            assert np.all(resampled.z[upper & away] > camber[upper & away])
            assert np.all(resampled.z[lower & away] < camber[lower & away])
            if n_points % 2:
                le = resampled.points[n_points // 2]
                np.testing.assert_array_equal(le, resampled.leading_edge)


def test_symmetric_resample_reproduces_naca_nodes():
    # For a symmetric section the camber-line stations are the chordwise stations.
    for n_points in (64, 65, 257):
        resampled = naca("0012").resample(n_points)
        direct = naca("0012", n_points=n_points)
        np.testing.assert_allclose(resampled.x, direct.x, atol=1e-14)
        np.testing.assert_allclose(resampled.z, direct.z, atol=1e-10)


def test_thickness_and_camber_distributions():
    section = parse_naca("0012")
    x = np.linspace(0.0, 1.0, 201)
    np.testing.assert_allclose(naca("0012").thickness(x), 2 * section.half_thickness(x), atol=1e-9)
    np.testing.assert_allclose(naca("0012").camber(x), 0.0, atol=1e-12)
    # Cambered: against vertical cuts through the analytic surface (the mid-point differs from
    # the mean line by ~ y_t y_t' theta, 1e-3 chord near the nose, since the thickness is
    # perpendicular to the mean line).
    for code in ("2412", "23112"):
        section, airfoil = parse_naca(code), naca(code)
        nose = [airfoil.leading_edge[0] + 1e-6, 0.0, 1e-4]
        stations = np.concatenate([nose, np.linspace(0.01, 1.0, 23)])
        upper, lower = vertical_cut(section, stations)
        np.testing.assert_allclose(airfoil.thickness(stations), upper - lower, atol=1e-7)
        np.testing.assert_allclose(airfoil.camber(stations), 0.5 * (upper + lower), atol=1e-7)
    with pytest.raises(ValueError, match="outside the section"):
        naca("0012").thickness(1.2)


# --------------------------------------------------------------------------- Airfoil validation


def test_airfoil_rejects_bad_contours():
    good = naca("0012", n_points=33)
    x, z = good.x.copy(), good.z.copy()
    with pytest.raises(ValueError, match="at least 7"):
        Airfoil(x[:5], z[:5])
    bad = x.copy()
    bad[4] = np.nan
    with pytest.raises(ValueError, match="point 4 is not finite"):
        Airfoil(bad, z)
    with pytest.raises(ValueError, match="runs clockwise"):
        Airfoil(x[::-1], z[::-1])
    with pytest.raises(ValueError, match="not chord-normalised"):
        Airfoil(100 * x, 100 * z)
    with pytest.raises(ValueError, match="not chord-normalised"):
        Airfoil(0.5 + 0.5 * x, z)
    with pytest.raises(ValueError, match="coincide"):
        Airfoil(np.insert(x, 3, x[3]), np.insert(z, 3, z[3]))
    with pytest.raises(ValueError, match="1-D arrays of equal length"):
        Airfoil(x, z[:-1])
    with pytest.raises(ValueError, match="the first point is the leading edge"):
        Airfoil(x[16:], z[16:])  # lower surface only


def test_airfoil_surface_must_carry_the_nodes():
    nodes = naca("0012", n_points=33)
    other = naca("0015", n_points=129)
    with pytest.raises(ValueError, match="off the given surface"):
        Airfoil(nodes.x, nodes.z, surface=(other.x, other.z))


# --------------------------------------------------------------------------- .dat files


@pytest.mark.parametrize("writer", [write_selig, write_lednicer])
@pytest.mark.parametrize("closed_te", [True, False])
def test_dat_round_trip(tmp_path, writer, closed_te):
    airfoil = naca("2412", n_points=65, closed_te=closed_te)
    path = tmp_path / "section.dat"
    writer(path, airfoil)
    loaded = load_airfoil(path)
    assert loaded.name == "TEST SECTION"
    assert loaded.closed_te == closed_te
    np.testing.assert_allclose(loaded.x, airfoil.x, atol=1e-12)
    np.testing.assert_allclose(loaded.z, airfoil.z, atol=1e-12)
    # Geometry from the file's 65 nodes agrees with the analytic section to the spline's accuracy.
    points = np.random.default_rng(5).uniform([-0.1, -0.2], [1.1, 0.2], size=(200, 2))
    np.testing.assert_allclose(loaded.distance(points), airfoil.distance(points), atol=3e-5)


def test_dat_in_percent_of_chord_is_rejected(tmp_path):
    airfoil = naca("0012", n_points=33)
    path = tmp_path / "percent.dat"
    rows = [f"{100 * x:.6f} {100 * z:.6f}" for x, z in zip(airfoil.x, airfoil.z)]
    path.write_text("NACA 0012 in percent\n" + "\n".join(rows))
    message = r"percent\.dat: airfoil .* is not chord-normalised.*divide the coordinates"
    with pytest.raises(ValueError, match=message):
        load_airfoil(path)


def test_dat_without_name_line_and_with_repeated_point(tmp_path):
    airfoil = naca("0012", n_points=33)
    rows = [f"{x:.10f} {z:.10f}" for x, z in zip(airfoil.x, airfoil.z)]
    rows.insert(16, rows[16])
    path = tmp_path / "n0012.dat"
    path.write_text("\n".join(rows) + "\n\n")
    loaded = load_airfoil(path)
    assert loaded.name == "n0012"
    assert loaded.n_points == 33


def reversed_rows(text: str) -> str:
    return "\n".join(text.strip().split("\n")[::-1]) + "\n"


UPPER_ONLY = "1.0 0.0\n0.7 0.05\n0.5 0.06\n0.3 0.06\n0.1 0.04\n0.03 0.02\n0.0 0.0\n"
LEDNICER_UPPER = "0.0 0.0\n0.3 0.06\n0.7 0.04\n1.0 0.0\n"  # lines 4-7 after a count line
LEDNICER_LOWER = "0.0 0.0\n0.5 -0.05\n0.8 -0.02\n1.0 0.0\n"  # lines 9-12


@pytest.mark.parametrize(
    ("content", "match"),
    [
        ("NAME\n1.0 0.0\n0.5 abc\n0.0 0.0\n", r"line 3: expected two numbers"),
        ("NAME\n1.0 0.0\n0.5 0.1\n0.5 nan\n0.0 0.0\n", r"line 4: coordinate is not finite"),
        ("NAME\n1.0 0.0 2.0\n", r"line 2: expected two numbers"),
        ("", "empty"),
        ("NAME\n" + UPPER_ONLY, r"line 8\), so the lower surface is missing"),
        ("NAME\n" + reversed_rows(UPPER_ONLY), r"start at the leading edge \(line 2\)"),
        (
            "NAME\n4. 4.\n\n" + LEDNICER_UPPER,
            r"line 2 declares 4 upper and 4 lower.*surface is missing",
        ),
        (
            "NAME\n4. 3.\n\n" + LEDNICER_UPPER + "\n" + LEDNICER_LOWER,
            r"declares 3 lower surface points, but the lower surface \(lines 9-12\) has 4",
        ),
        (
            "NAME\n4. 4.\n\n" + LEDNICER_UPPER + "\n" + LEDNICER_LOWER.replace("1.0 0.0", "1 nan"),
            r"line 12: coordinate is not finite",
        ),
        (
            "NAME\n4. 4.\n\n" + reversed_rows(LEDNICER_UPPER) + "\n" + LEDNICER_LOWER,
            r"must run from the leading edge",
        ),
    ],
)
def test_malformed_dat_files_name_the_line(tmp_path, content, match):
    path = tmp_path / "section.dat"
    path.write_text(content)
    with pytest.raises(ValueError, match=match):
        load_airfoil(path)
