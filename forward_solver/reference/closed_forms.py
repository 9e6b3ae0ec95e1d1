"""Analytic references for validating the solver: closed forms derived from the paper's law.

Pure numpy/scipy, sharing no code with the force kernel, so that the tests
(`tests/`) and the validation report (`benchmarks/validation_report.py`)
check the solver against one set of formulas and the two cannot drift apart.
Every function states the model it solves and the assumption that makes it
exact; the solver's discretisation error against it is what the tests bound.

The fabric law is eq. (10) of the paper at rest (no viscous term), as
`Fabric` writes it, ``e`` the engineering elongation against the cut length
(nominal length / (1 + prestrain)); and Laplace's law ``T = p R`` for a
membrane curved in one direction only.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq

__all__ = ["arc_sag", "circle_contour", "cylinder_radius", "fabric_tensions", "flat_panel_pressure_force",
           "hoop_tension", "strip_arc_radius", "strip_elongation", "strip_sag"]


def fabric_tensions(stiffness_span, stiffness_chord, poisson, elongation_span, elongation_chord):
    """Fibre tensions of eq. (10) at rest, N/m.

    A flat panel mounted on its nominal rectangle with prestrains
    ``(ps, pc)`` has uniform elongations ``e11 = ps`` and ``e22 = pc`` (its
    nodes sit at ``1 + prestrain`` times the cut lengths) and these
    tensions, with zero net force on every node.

    Args:
        stiffness_span, stiffness_chord: E11, E22 in N/m.
        poisson: nu12 = nu21.
        elongation_span, elongation_chord: e11, e22 (dimensionless).

    Returns:
        ``(T11, T22)`` in N/m.
    """
    scale = 1.0 / (1.0 - poisson**2)
    t11 = (stiffness_span * elongation_span + poisson * stiffness_chord * elongation_chord) * scale
    t22 = (stiffness_chord * elongation_chord + poisson * stiffness_span * elongation_span) * scale
    return t11, t22


def hoop_tension(pressure, radius):
    """Laplace's law for a long cylinder: hoop tension ``T22 = p r``, N/m (Pa times m)."""
    return pressure * radius


def cylinder_radius(nominal_radius, pressure, stiffness_span, stiffness_chord, poisson,
                    prestrain_chord, axial_elongation):
    """Inflated radius of a long cylindrical bay (far from its ribs), m.

    The hoop fibres are cut to ``2 pi R / (1 + pc)`` for a nominal radius
    ``R``, so at radius ``r`` their elongation is ``r (1 + pc) / R - 1``.
    Laplace's law ``T22 = p r`` with T22 from eq. (10) gives::

        p r (1 - nu^2) = E22 (r (1 + pc) / R - 1) + nu E11 e11,

    linear in ``r``:
    ``r = (E22 - nu E11 e11) / (E22 (1 + pc) / R - p (1 - nu^2))``.
    A positive denominator is the condition for an equilibrium to exist
    (beyond it the tube inflates without bound).

    Args:
        nominal_radius: mounted radius R, m.
        pressure: Pa.
        stiffness_span, stiffness_chord: E11 (axial), E22 (hoop), N/m.
        poisson: nu.
        prestrain_chord: hoop prestrain pc.
        axial_elongation: e11 at the section (the axial prestrain far from
            the ribs, where the cylinder is uniform).

    Returns:
        The radius r, m.

    Raises:
        ValueError: when ``p R (1 - nu^2) >= E22 (1 + pc)``: no equilibrium.
    """
    denominator = stiffness_chord * (1.0 + prestrain_chord) / nominal_radius - pressure * (1.0 - poisson**2)
    if denominator <= 0:
        raise ValueError(f"a pressure of {pressure!r} Pa inflates this cylinder without bound "
                         "(p R (1 - nu^2) >= E22 (1 + pc)): there is no equilibrium radius")
    return (stiffness_chord - poisson * stiffness_span * axial_elongation) / denominator


def strip_arc_radius(width, pressure, stiffness_span, stiffness_chord, poisson, prestrain_span,
                     elongation_chord):
    """Radius of the circular arc an inflated strip takes across its width, m.

    A long panel clamped along both sides (``width`` apart, along the span)
    bulges, far from its ends, into a circular arc of radius ``R`` (plane
    strain along the strip). Laplace gives ``T11 = p R``; the arc length
    ``2 R asin(w / 2R)`` over the cut width ``w / (1 + ps)`` gives ``e11``;
    the elongation along the strip ``e22`` is given (the clamped ends fix
    it). Eq. (10) closes it::

        p R = (E11 e11 + nu E22 e22) / (1 - nu^2),

    solved for the shallow branch ``R > w / 2`` by Brent's method.

    Args:
        width: clamped width w, m.
        pressure: Pa.
        stiffness_span, stiffness_chord: E11 (across), E22 (along), N/m.
        poisson: nu.
        prestrain_span: prestrain across the strip.
        elongation_chord: e22 along the strip.

    Returns:
        R in m.
    """

    def balance(radius):
        arc = 2.0 * radius * np.arcsin(width / (2.0 * radius))
        e11 = arc * (1.0 + prestrain_span) / width - 1.0
        t11, _ = fabric_tensions(stiffness_span, stiffness_chord, poisson, e11, elongation_chord)
        return pressure * radius - t11

    return brentq(balance, width / 2.0 * (1.0 + 1e-12), 1e3 * width, xtol=1e-15)


def arc_sag(chord_length, radius):
    """Sag (height) of a circular arc of ``radius`` over a chord ``chord_length``, m."""
    return radius - np.sqrt(radius**2 - chord_length**2 / 4.0)


def strip_sag(width, pressure, stiffness_span, stiffness_chord, poisson, prestrain_span,
              elongation_chord):
    """Mid-width sag of the inflated strip, m (`strip_arc_radius`, then `arc_sag`)."""
    radius = strip_arc_radius(width, pressure, stiffness_span, stiffness_chord, poisson,
                              prestrain_span, elongation_chord)
    return arc_sag(width, radius)


def flat_panel_pressure_force(pressure, width, length):
    """Net pressure force on a flat ``width x length`` panel: ``p A`` along its normal, N.

    The eight triangles of eq. (15) around every node tile the panel, so the
    nodal forces sum to this exactly (to round-off).
    """
    return pressure * width * length


def circle_contour(n_points: int = 257, repeat_first: bool = True):
    """A circle of diameter 1 in Selig order, from ``(1, 0)`` over the top and back.

    The section of the long-cylinder case (``targets.Airfoil(x, z)`` turns
    it into a rib): with ``repeat_first`` the last point repeats the first
    exactly. Without it, ``n_points`` distinct points, equally spaced, the
    contour of a periodic `Bay` built directly (the closed-tube checks).

    Returns:
        ``(x, z)`` arrays of ``n_points`` chord-normalised coordinates.
    """
    intervals = n_points - 1 if repeat_first else n_points
    phi = 2 * np.pi * np.arange(n_points) / intervals
    x, z = (1 + np.cos(phi)) / 2, np.sin(phi) / 2
    if repeat_first:
        x[-1], z[-1] = x[0], z[0]  # closed exactly (sin(2 pi) is 2e-16, not 0)
    return x, z


def strip_elongation(nodes, length, prestrain_chord):
    """Elongation along an inflated strip at its centre, measured on a flat-panel grid.

    The strip closed form takes ``e22`` as given: with zero shear stiffness
    T22 is uniform along each strip line, and the bulged ends lengthen the
    line, so at mid-length it exceeds the prestrain. This measures it on the
    ``(n_span, n_contour, 3)`` nodes of ``Bay.flat_panel(..., length=length)``
    by a central difference at the middle node, against the cut spacing.
    """
    nodes = np.asarray(nodes)
    i, j = nodes.shape[0] // 2, nodes.shape[1] // 2
    spacing = length / (nodes.shape[1] - 1)
    stretched = np.linalg.norm(nodes[i, j + 1] - nodes[i, j - 1]) / (2 * spacing)
    return stretched * (1 + prestrain_chord) - 1
