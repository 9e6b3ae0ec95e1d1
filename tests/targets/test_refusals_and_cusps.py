"""A NACA code whose section folds over itself is refused by the library as by the command; an open
trailing edge whose surfaces end in a cusp projects without NumPy's 0/0 warnings."""

import warnings

import numpy as np
import pytest

from targets import Airfoil, naca


def test_a_section_that_folds_over_itself_is_refused_by_the_library():
    with pytest.raises(ValueError, match="NACA 9999: x turns back along the upper surface near x = 1.0000; .* "
                                         "choose a thinner or less cambered code"):
        naca("9999")
    assert naca("2412").surface_error is None


def test_the_command_refuses_it_naming_the_option():
    from inverse_design.app.case import Case
    from inverse_design.app.options import InputError

    with pytest.raises(InputError, match="^--target naca9999: NACA 9999: x turns back"):
        Case.from_arguments(["--target", "naca9999", "--out", "unused"])


def test_an_open_trailing_edge_cusp_projects_without_warnings():
    # NACA 0012 with its trailing-edge points moved to z = +-0.01 (a user's open edge): the end normals of the
    # surfaces and of the base are opposite there, and their sum, normalised, was 0/0 (three console warnings)
    section = naca("0012", n_points=81)
    z = section.z.copy()
    z[0], z[-1] = 0.01, -0.01
    opened = Airfoil(section.x, z, name="open")
    points = np.array([[1.0, 0.0], [1.0, 0.02], [0.999, 0.0101], [0.5, 0.1]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        projection = opened.project(points)
    assert np.all(np.isfinite(projection.normal)) and np.all(np.isfinite(projection.distance))
