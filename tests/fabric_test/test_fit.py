"""A shop's biaxial test read, checked and fitted (`forward_solver.model.biaxial`): NumPy only, no solve.

The fit is exact for readings of a reciprocal linear law (eq. 10 with equal
stiffnesses among them), recovers a known nonlinear law from noisy readings,
keeps a positive-definite tangent where the fabric was tested, and a file
that cannot be fitted is refused with one line that says what to change.
"""

from pathlib import Path

import numpy as np
import pytest

from forward_solver.model.biaxial import TestFileError, fit_law, read_test
from forward_solver.model.biaxial.fit import points_on_paths
from forward_solver.model.biaxial.readings import MIN_READINGS, readings_from_arrays
from forward_solver.model.biaxial.synthetic import (EXAMPLE_HEADER, STANDARD_PATHS, example_readings, example_surface, linear_law,
                               synthetic_test, write_test)
from inverse_design.app.case_file import EXAMPLE_FABRIC_TEST


def _csv(tmp_path, rows, header="strain_warp,strain_weft,tension_warp,tension_weft,load_ratio", name="test.csv"):
    path = tmp_path / name
    path.write_text("\n".join([header, *rows]) + "\n")
    return path


def _rows(test):
    return [",".join([*(repr(float(c[k])) for c in (test.strain_warp, test.strain_weft, test.tension_warp,
                                                     test.tension_weft)), test.paths[k]]) for k in range(test.size)]


@pytest.fixture(scope="module")
def linear():
    """Readings of eq. (10), 2e5 N/m both ways and Poisson 0.25, along the five standard paths to 8 kN/m."""
    return synthetic_test(linear_law(2e5, 2e5, 0.25), 8000.0)


def test_readings_of_eq_10_are_fitted_exactly(linear):
    # Reciprocal and linear: the quadratic terms hold it, the higher ones come out zero (rounding: the
    # readings' tensions are kN/m, the errors 1e-11 N/m).
    law = fit_law(linear)
    assert law.surface.degree == 4 and max(law.max_error) < 1e-9
    k = 2e5 / (1 - 0.25**2)
    np.testing.assert_allclose(law.surface.coefficients[:3], [k / 2, 0.25 * k, k / 2], rtol=1e-12)
    assert max(abs(c) for c in law.surface.coefficients[3:]) * 0.05**2 < 1e-9 * k  # (their tensions in range)
    assert (law.stiffness_warp, law.stiffness_weft, law.poisson) == pytest.approx((2e5, 2e5, 0.25), rel=1e-12)
    e = np.random.default_rng(0).uniform(-0.03, 0.06, (2, 200))  # inside and outside the tested range
    np.testing.assert_allclose(np.array(law.tensions(*e)), np.array(linear_law(2e5, 2e5, 0.25)(*e)), rtol=1e-11,
                               atol=1e-9)


def test_a_reciprocal_anisotropic_linear_law_is_fitted_exactly():
    # Orthotropic plane stress with nu12 E22 = nu21 E11 has an energy: the fit takes it whole.
    stiffness = np.array([[3e5, 6e4], [6e4, 1.2e5]])
    test = synthetic_test(lambda a, b: tuple(stiffness @ np.array([a, b])), 6000.0)
    law = fit_law(test)
    assert max(law.max_error) < 1e-9
    np.testing.assert_allclose(law.surface.tangent(0.01, -0.004), [3e5, 6e4, 1.2e5], rtol=1e-10)
    assert law.stiffness_warp == pytest.approx(3e5 - 6e4**2 / 1.2e5, rel=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_a_nonlinear_law_is_recovered_from_readings_with_one_percent_noise(seed):
    # The example's law (degree 4, stiffening), five paths of ten readings to 8 kN/m, each tension
    # recorded with 1% noise: the fitted tensions along every tested path within 2% of the test's
    # full-scale tension (8 kN/m), the scale a test's accuracy is stated against; the noise alone
    # puts single readings 1% off, the fit averages it (measured 0.4-1.4% over ten seeds).
    truth = example_surface()
    test = synthetic_test(truth.polynomial_tensions, 8000.0, noise=0.01, seed=seed)
    law = fit_law(test)
    points = points_on_paths(test)
    error = np.abs(np.array(law.tensions(*points)) - np.array(truth.polynomial_tensions(*points)))
    assert np.max(error) < 0.02 * 8000.0
    assert law.surface.degree == 4 and law.surface.not_positive_definite(*points) is None
    assert max(law.rms_error) < 0.01 * 8000.0  # (the reported error: the noise, about 1% of a reading)


def test_the_fit_keeps_a_positive_definite_tangent_where_tested():
    # Readings of a fabric that saturates (T = T0 tanh(K e / T0), its tangent near zero at the last
    # readings): cubic and quadratic tensions would bend the tangent negative on the 1:1 path, so the
    # fit takes the linear surface, says so, and reports its large error honestly.
    def saturating(a, b, top=3000.0):
        return top * np.tanh((2e5 * a + 4e4 * b) / top), top * np.tanh((2e5 * b + 4e4 * a) / top)

    test = synthetic_test(saturating, 2900.0)
    law = fit_law(test)
    assert law.surface.degree == 2 and "degree 4 was not taken: its tangent is not positive-definite" in law.notes[0]
    assert law.surface.not_positive_definite(*points_on_paths(test)) is None
    assert max(law.max_error) > 0.3 * 2900.0
    with pytest.raises(TestFileError, match="fits the readings, but its tangent is not positive-definite at warp"):
        fit_law(test, degree=4)
    assert fit_law(synthetic_test(saturating, 2500.0)).surface.degree == 4  # (further from saturation: cubic)


def test_the_tensions_continue_along_the_tangent_outside_the_tested_range():
    law = fit_law(example_readings())
    s = law.surface
    high = (s.warp_range[1], s.weft_range[1])
    t_edge = np.array(s.polynomial_tensions(*high))
    k = np.array(s.tangent(*high))
    outside = np.array(s.tensions(high[0] + 0.02, high[1] + 0.01))
    np.testing.assert_allclose(outside, t_edge + [k[0] * 0.02 + k[1] * 0.01, k[1] * 0.02 + k[2] * 0.01], rtol=1e-13)
    # continuous, with a continuous tangent across the edge (one-sided differences agree)
    h = 1e-7
    below = (np.array(s.tensions(high[0] - h, 0.01)) - np.array(s.tensions(high[0] - 2 * h, 0.01))) / h
    above = (np.array(s.tensions(high[0] + 2 * h, 0.01)) - np.array(s.tensions(high[0] + h, 0.01))) / h
    np.testing.assert_allclose(above, below, rtol=1e-5)


def test_the_shipped_example_is_the_documented_law_labelled_synthetic(tmp_path):
    text = EXAMPLE_FABRIC_TEST.read_text()
    assert text.startswith("# SYNTHETIC biaxial test: not a measured fabric.")
    again = write_test(tmp_path / "again.csv", example_readings(), EXAMPLE_HEADER)
    assert again.read_text() == text
    law = fit_law(read_test(EXAMPLE_FABRIC_TEST))
    assert law.readings == 50 and law.paths == ("1:1", "2:1", "1:2", "1:0", "0:1")
    points = points_on_paths(read_test(EXAMPLE_FABRIC_TEST))
    error = np.abs(np.array(law.tensions(*points)) - np.array(example_surface().polynomial_tensions(*points)))
    assert np.max(error) < 0.01 * 8000.0


def test_paths_come_from_the_tensions_direction_without_a_load_ratio_column(tmp_path, linear):
    rows = [row.rsplit(",", 1)[0] for row in _rows(linear)]
    test = read_test(_csv(tmp_path, rows, "strain_warp,strain_weft,tension_warp,tension_weft"))
    assert test.path_labels == ("1:1", "2:1", "1:2", "1:0", "0:1")
    assert test.paths == linear.paths
    # columns in any order, extra ones ignored, comments skipped
    path = tmp_path / "shuffled.csv"
    path.write_text("# a comment\nload_ratio,tension_weft,time_s,strain_weft,tension_warp,strain_warp\n" + "\n".join(
        f"{linear.paths[k]},{float(linear.tension_weft[k])!r},{k},{float(linear.strain_weft[k])!r},"
        f"{float(linear.tension_warp[k])!r},{float(linear.strain_warp[k])!r}" for k in range(linear.size)))
    np.testing.assert_array_equal(read_test(path).strain_warp, linear.strain_warp)


def _refused(tmp_path, rows, **kwargs) -> str:
    with pytest.raises(TestFileError) as caught:
        read_test(_csv(tmp_path, rows, **kwargs))
    message = str(caught.value)
    assert "\n" not in message and message.startswith(str(tmp_path / "test.csv"))
    return message


def test_each_bad_file_is_refused_with_one_line(tmp_path, linear):
    rows = _rows(linear)
    assert "readings; a fit needs at least 12" in _refused(tmp_path, rows[:MIN_READINGS - 1])
    one_path = [r for r in rows if r.endswith(",1:1")] * 2
    assert "every reading lies on one load-ratio path (1:1)" in _refused(tmp_path, one_path)
    nan = rows[:5] + [rows[5].replace(rows[5].split(",")[2], "nan", 1)] + rows[6:]
    assert "line 7: tension_warp is 'nan', not a number" in _refused(tmp_path, nan)
    percent = [",".join([str(100 * float(v)) if i < 2 else v for i, v in enumerate(r.split(","))]) for r in rows]
    assert "the strains look like percent; give them as fractions" in _refused(tmp_path, percent)
    falling = list(rows)
    parts = falling[4].split(",")
    parts[2] = str(float(parts[2]) * 0.5)
    falling[4] = ",".join(parts)
    message = _refused(tmp_path, falling)
    assert "path 1:1, lines 5-6: tension_warp falls from" in message and "while strain_warp grows" in message
    assert "no column tension_weft" in _refused(tmp_path, rows, header="strain_warp,strain_weft,tension_warp,t_weft")
    negative = [r.replace(",0.0,1:0", ",-500.0,1:0") for r in rows]
    assert "a fabric carries no compression" in _refused(tmp_path, negative)


def test_readings_given_as_arrays_meet_the_same_checks():
    with pytest.raises(TestFileError, match="a fit needs at least"):
        readings_from_arrays(*np.ones((4, 5)))
    assert set(STANDARD_PATHS) == {(1, 1), (2, 1), (1, 2), (1, 0), (0, 1)}


def test_a_missing_file_is_one_line(tmp_path):
    with pytest.raises(TestFileError, match="cannot read the biaxial test"):
        read_test(tmp_path / "none.csv")
    assert not Path(tmp_path / "none.csv").exists()
