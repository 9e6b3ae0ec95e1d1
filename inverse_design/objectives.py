"""Distances between the inflated skin and the target profile (DESIGN section 6).

Every error is the signed normal distance of a skin section's nodes from the
target contour (`targets.Airfoil.distance`, positive outside the target), in
fractions of chord. The sections are the skin's rows at span stations
``y = eta * rib_spacing``:

* ``"mid_bay"``: the section half-way between the ribs (``eta = 0.5``),
  where the bulge is largest;
* ``"average"``: every grid row from rib to rib, each weighted equally (the
  mean square over the bay);
* ``"worst"``: the row whose RMS distance is largest (a minimax objective;
  non-smooth where two rows tie).

RMS and maximum are taken over the section's nodes (each node weighted
equally, as `section_errors`).

The JAX side (`target_distance`, `objective_residuals`) is differentiable:
the distance's derivative in the query point is the target's outward unit
normal at the foot of the perpendicular (`Airfoil.project`), so gradients
flow from the objective to the skin nodes and, through the implicit
derivative of `forward_solver.solve_equilibrium`, to the design variables. Like the
equilibrium, the distance is computed on the host: call it eagerly (under
``jax.grad`` / ``jax.jvp`` but not ``jax.jit``).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "OBJECTIVES",
    "SectionErrors",
    "section_errors",
    "station_etas",
    "section_points",
    "target_distance",
    "section_distances",
    "objective_residuals",
    "objective_value",
    "design_errors",
]

#: Objective names accepted by `objective_residuals` and `optimise_pressure`.
OBJECTIVES = ("mid_bay", "average", "worst")


class SectionErrors(NamedTuple):
    """Normal distance of one section from the target, in fractions of chord."""

    distance: np.ndarray  # (n_contour,) signed, positive outside the target
    rms: float
    max: float  # largest absolute distance


def section_errors(solution, target, chord: float, eta: float = 0.5) -> SectionErrors:
    """Signed normal distance of the section at ``y = eta * rib_spacing`` from the target.

    Args:
        solution: a `forward_solver.Solution`.
        target: a `targets.Airfoil` (chord-normalised).
        chord: the chord the target is scaled to, m.
        eta: span station as a fraction of the rib spacing (0.5 is mid-bay).

    Returns:
        `SectionErrors` in fractions of chord.
    """
    points = solution.section(eta) / chord
    distance = np.asarray(target.distance(points), dtype=np.float64)
    return SectionErrors(distance, float(np.sqrt(np.mean(distance**2))), float(np.max(np.abs(distance))))


def check_objective(objective: str) -> None:
    """Raise a clear ValueError for an unknown objective name."""
    if objective not in OBJECTIVES:
        raise ValueError(f"objective must be one of {OBJECTIVES}, got {objective!r}")


def station_etas(objective: str, n_span: int) -> np.ndarray:
    """Span stations (fractions of the rib spacing) that an objective looks at."""
    check_objective(objective)
    if objective == "mid_bay":
        return np.array([0.5])
    return np.linspace(0.0, 1.0, n_span)


def section_points(nodes, eta: float, chord: float):
    """Chord-normalised ``(n_contour, 2)`` x-z section at ``y = eta * rib_spacing`` (as `Solution.section`)."""
    n_span = nodes.shape[0]
    s = eta * (n_span - 1)
    i0 = min(int(np.floor(s)), n_span - 2)
    w = s - i0
    row = nodes[i0] if w == 0.0 else (1.0 - w) * nodes[i0] + w * nodes[i0 + 1]
    return jnp.stack([row[:, 0], row[:, 2]], axis=-1) / chord


def target_distance(target, points):
    """Signed normal distance of ``points`` from ``target`` (chord units), differentiable.

    Args:
        target: anything with ``project(points)`` returning ``distance`` and
            ``normal`` (a `targets.Airfoil`).
        points: ``(..., 2)`` chord-normalised x-z points (concrete, or a JAX
            value under an eager ``jax.grad`` / ``jax.jvp``).

    Returns:
        ``(...)`` distances; the derivative in a point is the unit normal of
        the target at its foot.
    """

    @jax.custom_jvp
    def distance(p):
        return jnp.asarray(target.distance(np.asarray(p)), jnp.float64)

    @distance.defjvp
    def distance_jvp(primals, tangents):
        (p,), (dp,) = primals, tangents
        projection = target.project(np.asarray(p))
        normal = jnp.asarray(projection.normal, jnp.float64)
        return jnp.asarray(projection.distance, jnp.float64), jnp.sum(normal * dp, axis=-1)

    return distance(points)


@partial(jax.jit, static_argnames=("etas", "chord"))
def _stations(nodes, etas, chord):
    return jnp.stack([section_points(nodes, eta, chord) for eta in etas])


def section_distances(nodes, target, chord: float, etas) -> jnp.ndarray:
    """``(n_stations, n_contour)`` signed distances of the sections at ``etas`` (chord units)."""
    points = _stations(nodes, tuple(float(e) for e in etas), float(chord))
    return target_distance(target, points)


def objective_residuals(nodes, target, chord: float, objective: str = "mid_bay") -> jnp.ndarray:
    """Residual vector whose sum of squares is the objective (mean square distance, chord^2).

    Args:
        nodes: ``(n_span, n_contour, 3)`` equilibrium nodes, m.
        target: the target `targets.Airfoil`.
        chord: m.
        objective: one of `OBJECTIVES`.

    Returns:
        ``(n,)`` residuals: the distances scaled by ``1/sqrt(count)``, so that
        ``sum(r**2)`` is the RMS error squared.
    """
    etas = station_etas(objective, nodes.shape[0])
    d = section_distances(nodes, target, chord, etas)
    if objective == "worst":
        worst = jnp.argmax(jnp.mean(jax.lax.stop_gradient(d) ** 2, axis=1))
        d = d[worst]
    return d.reshape(-1) / np.sqrt(d.size)


#: Sharpness of the smooth maximum over rows of the "worst" objective in `objective_value`:
#: it exceeds the true worst row's mean square by at most ``log(n_rows) / WORST_SHARPNESS``
#: of it (2.8% on 17 rows; 0.7% when two rows tie), and is smooth where rows swap places.
WORST_SHARPNESS = 100.0


def objective_value(nodes, target, chord: float, objective: str = "mid_bay"):
    """The objective as one smooth scalar, chord^2 (what SLSQP minimises).

    "mid_bay" and "average": the mean square distance, ``sum(objective_residuals**2)``.
    "worst": a smooth (Kreisselmeier-Steinhauser) maximum of the rows' mean
    square distances, so that its gradient does not jump when another row
    becomes the worst (the plain maximum made SLSQP spend its budget where the
    rib and mid-bay rows tie).
    """
    if objective != "worst":
        r = objective_residuals(nodes, target, chord, objective)
        return jnp.sum(r * r)
    d = section_distances(nodes, target, chord, station_etas(objective, nodes.shape[0]))
    rows = jnp.mean(d * d, axis=1)
    top = jnp.maximum(jax.lax.stop_gradient(jnp.max(rows)), np.finfo(np.float64).tiny)  # a perfect fit
    return top * (1.0 + jnp.log(jnp.sum(jnp.exp(WORST_SHARPNESS * (rows / top - 1.0)))) / WORST_SHARPNESS)


def design_errors(nodes, target, chord: float, objective: str = "mid_bay") -> tuple[float, float]:
    """``(rms, max)`` normal distance in fractions of chord, over the objective's sections.

    For ``"worst"`` both refer to the worst row (largest RMS). Computed in
    float64 whatever the caller's JAX configuration (a thread-local scope).
    """
    nodes = np.asarray(nodes, dtype=np.float64)
    with jax.enable_x64(True):
        etas = station_etas(objective, nodes.shape[0])
        d = np.asarray(section_distances(nodes, target, chord, etas))
    if objective == "worst":
        d = d[np.argmax(np.mean(d**2, axis=1))]
    return float(np.sqrt(np.mean(d**2))), float(np.max(np.abs(d)))
