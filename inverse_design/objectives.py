"""Distances between the inflated skin and the target (paper eq. 17 compares the same sections).

Every error is the signed normal distance of a skin section's nodes from its
target contour (`targets.Airfoil.distance`, positive outside the target), in
fractions of the local chord. The sections are a bay's span rows at
``y = eta * rib_spacing`` (`station_etas`):

* ``"mid_bay"``: the section half-way between the ribs (``eta = 0.5``),
  where the bulge is largest;
* ``"average"``: every grid row from rib to rib, each weighted equally (the
  mean square over the bay);
* ``"worst"``: the row whose RMS distance is largest (a minimax objective;
  non-smooth where two rows tie; `mean_square` takes a smooth maximum);
* ``"robust"``: the rows of "average", and the design minimises the
  linearised 95th percentile of their rms under the manufacturing
  tolerances (`tolerance.robust`); here, at one equilibrium, it is "average".

RMS and maximum are taken over the section's nodes (each node weighted
equally, as `section_errors`).

The target of a row (`row_targets`). Bay ``k`` runs from rib ``k`` (chord
``c_r``, target ``A_r``) to rib ``k + 1`` (``c_t``, ``A_t``). At the row
``eta`` the target is the ruled surface between the two target sections at
their chords, the surface the bay's mounted skin follows
(`forward_solver.forces.nominal_nodes`), chord-normalised by the local chord
``c(eta) = (1 - eta) c_r + eta c_t``::

    T(eta) = ((1 - eta) c_r A_r + eta c_t A_t) / c(eta)

with ``A_r`` and ``A_t`` resampled at the same cosine stations
(`BLEND_POINTS`). Where both ribs carry the same section ``T(eta) = A_r``
exactly (the target airfoil itself, its analytic surface); the skin's row is
likewise divided by ``c(eta)`` (`section_points`).

A wing's objective is the sum of its bays' objectives weighted by bay
planform area ``(c_r + c_t) / 2 * (y_t - y_r)`` over the wing's
(`bay_weights`); for one bay between equal ribs it is the bay's objective
itself. `WingTargets` holds a wing's rows, local chords, stations and
weights, built once: the design problem, the tolerance model,
`optimise.evaluate_design` and the command's report measure through it.

The JAX side (`target_distance`, `bay_distances`, `mean_square`,
`distance_residuals`) is differentiable: the distance's derivative in the
query point is the target's outward unit normal at the foot of the
perpendicular (`Airfoil.project`), so gradients flow from the objective to the
skin nodes and, through the implicit derivative of the forward solve, to the
design variables. Like the equilibrium, the distance is computed on the host:
call it eagerly (under ``jax.grad`` / ``jax.jvp`` but not ``jax.jit``).
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from targets import Airfoil

from . import defaults
from .stacked import joined

__all__ = [
    "DEFAULT_OBJECTIVE",
    "OBJECTIVES",
    "WingTargets",
    "SectionErrors",
    "section_errors",
    "station_etas",
    "section_points",
    "target_distance",
    "section_distances",
    "objective_residuals",
    "design_errors",
    "BLEND_POINTS",
    "same_section",
    "row_targets",
    "local_chords",
    "bay_weights",
    "bay_distances",
    "bay_projections",
    "row_points",
    "distance_residuals",
    "mean_square",
    "weighted_mean_square",
    "distance_errors",
]

#: Points of each target section when two different sections are blended along a bay.
BLEND_POINTS = 401

#: Objective names accepted by `objective_residuals` and `optimise_pressure`.
OBJECTIVES = defaults.OBJECTIVES

#: The objective of `optimise.optimise_wing`, `optimise.optimise_pressure`, `optimise.evaluate_design`
#: and the ``optimise-pressure`` command when none is given: every row of every bay.
DEFAULT_OBJECTIVE = defaults.OBJECTIVE


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
        return jnp.asarray(projection.distance, jnp.float64), _along(normal, dp)

    return distance(points)


@jax.jit
def _along(normal, dp):
    return jnp.sum(normal * dp, axis=-1)


@partial(jax.jit, static_argnames=("etas",))
def row_points(nodes, etas, chords):
    """``(n_rows, n_contour, 2)`` chord-normalised x-z points of the sections at ``etas`` (a tuple of
    floats), row ``i`` in units of ``chords[i]`` (`section_points`), one program: linear in ``nodes``."""
    # The chords are an operand, not static: a wing's bays differ in chord, and one program serves
    # them all (static chords compiled it once per bay, and again for its tangents: 80 compilations
    # and 28 s of the 40-cell design).
    return jnp.stack([section_points(nodes, eta, chords[i]) for i, eta in enumerate(etas)])


def same_section(a, b) -> bool:
    """Whether two airfoils are one section (the same object, or equal points)."""
    return a is b or (np.array_equal(np.asarray(a.x), np.asarray(b.x))
                      and np.array_equal(np.asarray(a.z), np.asarray(b.z)))


def row_targets(root, tip, chord_root: float, chord_tip: float, etas) -> list:
    """The target `targets.Airfoil` of each span row ``eta`` of a bay (module docstring).

    Args:
        root, tip: the target sections of the bay's ribs (chord-normalised).
        chord_root, chord_tip: the rib chords, m.
        etas: span rows, fractions of the rib spacing.

    Returns:
        One `targets.Airfoil` per ``eta``, chord-normalised by the local chord:
        ``root`` itself for every row when both sections are the same, else
        the blend of the two at their chords (``root`` at 0, ``tip`` at 1).
    """
    
    if same_section(root, tip):
        return [root] * len(etas)
    a, b = root.resample(BLEND_POINTS), tip.resample(BLEND_POINTS)
    rows = []
    for eta in etas:
        if eta == 0.0:
            rows.append(root)
        elif eta == 1.0:
            rows.append(tip)
        else:
            wr, wt = (1.0 - eta) * chord_root, eta * chord_tip
            local = wr + wt
            rows.append(Airfoil((wr * a.x + wt * b.x) / local, (wr * a.z + wt * b.z) / local,
                                name=f"{root.name}-{tip.name} at {eta:.3g} b"))
    return rows


def local_chords(bay, etas) -> list:
    """The local chord ``c(eta)`` of a bay's rows, m (the bay's chord itself between equal ribs)."""
    if bay.chord_root == bay.chord_tip:
        return [bay.chord] * len(etas)
    return [(1.0 - e) * bay.chord_root + e * bay.chord_tip for e in etas]


def bay_weights(bays) -> np.ndarray:
    """``(n_bays,)`` weights of the bays in a wing's objective: planform area over the wing's, summing to 1.

    Args:
        bays: the `forward_solver.Bay` of each, or a `forward_solver.Wing`.
    """
    if hasattr(bays, "stations"):  # a Wing
        chords, stations = np.asarray(bays.chords, float), np.asarray(bays.stations, float)
        area = 0.5 * (chords[:-1] + chords[1:]) * np.diff(stations)
    else:
        area = np.array([0.5 * (b.chord_root + b.chord_tip) * b.rib_spacing for b in bays])
    return area / np.sum(area)


def bay_distances(nodes, rows: list, etas, chords) -> jnp.ndarray:
    """``(n_rows, n_contour)`` signed distances of a bay's rows from their targets, fractions of the
    local chords (``rows``: `row_targets`; ``chords``: `local_chords`); JAX nodes allowed."""
    points = row_points(nodes, tuple(float(e) for e in etas), np.asarray(chords, np.float64))
    if all(r is rows[0] for r in rows):
        return target_distance(rows[0], points)
    return jnp.stack([target_distance(r, points[i]) for i, r in enumerate(rows)])


def bay_projections(nodes, rows: list, etas, chords) -> tuple:
    """`bay_distances` of concrete ``nodes`` with what their derivative takes: ``(distances, normals)``,
    ``(n_rows, n_contour)`` signed distances (chord fractions) and ``(n_rows, n_contour, 2)`` the
    targets' unit normals at the feet. A row point's motion ``dp`` (`row_points` of the nodes' motion)
    moves its distance by ``normal . dp`` (`target_distance`'s derivative)."""
    points = np.asarray(row_points(nodes, tuple(float(e) for e in etas), np.asarray(chords, np.float64)))
    if all(r is rows[0] for r in rows):
        found = rows[0].project(points)
        return np.asarray(found.distance, np.float64), np.asarray(found.normal, np.float64)
    found = [r.project(points[i]) for i, r in enumerate(rows)]
    return (np.stack([np.asarray(f.distance, np.float64) for f in found]),
            np.stack([np.asarray(f.normal, np.float64) for f in found]))


def section_distances(nodes, target, chord: float, etas) -> jnp.ndarray:
    """``(n_stations, n_contour)`` signed distances of the sections at ``etas`` from one target (chord units)."""
    return bay_distances(nodes, [target] * len(etas), etas, [chord] * len(etas))


def distance_residuals(d, objective: str) -> jnp.ndarray:
    """Residual vector whose sum of squares is the bay's mean square distance over the objective's
    rows (for "worst" the worst row's): ``d`` scaled by ``1/sqrt(count)``."""
    if objective == "worst":
        worst = jnp.argmax(jnp.mean(jax.lax.stop_gradient(d) ** 2, axis=1))
        d = d[worst]
    return d.reshape(-1) / np.sqrt(d.size)


@partial(jax.jit, static_argnames=("objective",))
def _weighted_residuals(d, weight, objective: str):
    """``sqrt(weight) * distance_residuals(d, objective)``: one program under a design's transformation
    for what were six eager operations per bay."""
    return jnp.sqrt(weight) * distance_residuals(d, objective)


#: Sharpness of the smooth maximum over rows of the "worst" objective in `mean_square`:
#: it exceeds the true worst row's mean square by at most ``log(n_rows) / WORST_SHARPNESS``
#: of it (2.8% on 17 rows; 0.7% when two rows tie), and is smooth where rows swap places.
WORST_SHARPNESS = 100.0


def mean_square(d, objective: str):
    """A bay's objective as one smooth scalar from its row distances ``d``, chord^2 (what SLSQP minimises).

    "mid_bay" and "average": the mean square distance, ``sum(distance_residuals**2)``.
    "worst": a smooth (Kreisselmeier-Steinhauser) maximum of the rows' mean
    square distances, so that its gradient does not jump when another row
    becomes the worst (the plain maximum made SLSQP spend its budget where the
    rib and mid-bay rows tie).
    """
    if objective != "worst":
        r = distance_residuals(d, objective)
        return jnp.sum(r * r)
    rows = jnp.mean(d * d, axis=1)
    top = jnp.maximum(jax.lax.stop_gradient(jnp.max(rows)), np.finfo(np.float64).tiny)  # a perfect fit
    return top * (1.0 + jnp.log(jnp.sum(jnp.exp(WORST_SHARPNESS * (rows / top - 1.0)))) / WORST_SHARPNESS)


@partial(jax.jit, static_argnames=("objective",))
def weighted_mean_square(distances, weights, objective: str):
    """``sum_k weights[k] * mean_square(distances[k])``: a wing's objective from its bays' row
    distances (one compiled program for what were a dozen eager operations per bay)."""
    return sum(weights[k] * mean_square(d, objective) for k, d in enumerate(distances))


def distance_errors(d, objective: str) -> tuple[float, float]:
    """``(rms, max)`` of concrete row distances ``d`` over the objective's rows (the worst row for "worst")."""
    d = np.asarray(d, np.float64)
    if objective == "worst":
        d = d[np.argmax(np.mean(d**2, axis=1))]
    return float(np.sqrt(np.mean(d**2))), float(np.max(np.abs(d)))


def objective_residuals(nodes, target, chord: float, objective: str = DEFAULT_OBJECTIVE) -> jnp.ndarray:
    """One bay's residual vector whose sum of squares is the objective (mean square distance, chord^2).

    Args:
        nodes: ``(n_span, n_contour, 3)`` equilibrium nodes, m.
        target: the target `targets.Airfoil` (both ribs).
        chord: m.
        objective: one of `OBJECTIVES`.

    Returns:
        ``(n,)`` residuals (`distance_residuals`).
    """
    etas = station_etas(objective, nodes.shape[0])
    return distance_residuals(section_distances(nodes, target, chord, etas), objective)


def design_errors(nodes, target, chord: float, objective: str = DEFAULT_OBJECTIVE) -> tuple[float, float]:
    """``(rms, max)`` normal distance of one bay in fractions of chord, over the objective's sections.

    For ``"worst"`` both refer to the worst row (largest RMS). Computed in
    float64 whatever the caller's JAX configuration (a thread-local scope).
    """
    nodes = np.asarray(nodes, dtype=np.float64)
    with jax.enable_x64(True):
        etas = station_etas(objective, nodes.shape[0])
        d = np.asarray(section_distances(nodes, target, chord, etas))
    return distance_errors(d, objective)


class WingTargets:
    """A wing's bays measured against their targets, built once (module docstring).

    Args:
        bays: the `forward_solver.Bay` of each bay, root to tip (one grid).
        targets: the target section (`targets.Airfoil`) of each rib, ``len(bays) + 1``.
        objective: one of `OBJECTIVES`: the rows measured (`station_etas`).

    Attributes:
        etas: the rows' span stations, fractions of the rib spacing.
        weights: ``(n_bays,)`` planform-area weights (`bay_weights`).
        chords: per bay, the local chord of each row, m (`local_chords`).
        rows: per bay, the target `targets.Airfoil` of each row (`row_targets`).

    Raises:
        ValueError: for an unknown objective.
    """

    def __init__(self, bays, targets, objective: str = DEFAULT_OBJECTIVE):
        self.bays, self.targets, self.objective = list(bays), list(targets), objective
        self.etas = station_etas(objective, self.bays[0].n_span)
        self.weights = bay_weights(self.bays)
        self.chords = [local_chords(bay, self.etas) for bay in self.bays]
        self.rows = [row_targets(self.targets[k], self.targets[k + 1], bay.chord_root, bay.chord_tip, self.etas)
                     for k, bay in enumerate(self.bays)]

    @property
    def n_distances(self) -> int:
        """Distances of one bay: ``len(etas) * n_contour``."""
        return len(self.etas) * self.bays[0].n_contour

    @property
    def residual_size(self) -> int:
        """Length of `residuals` over the wing (for "worst", one row per bay)."""
        per_bay = self.bays[0].n_contour * (1 if self.objective == "worst" else len(self.etas))
        return per_bay * len(self.bays)

    def distances(self, k: int, nodes):
        """``(n_rows, n_contour)`` signed distances of bay ``k``'s rows from their targets, fractions of
        the local chord (`bay_distances`; JAX nodes allowed)."""
        return bay_distances(nodes, self.rows[k], self.etas, self.chords[k])

    def projections(self, k: int, nodes) -> tuple:
        """Bay ``k``'s concrete distances and the targets' normals at their feet (`bay_projections`)."""
        return bay_projections(nodes, self.rows[k], self.etas, self.chords[k])

    def residuals(self, distances):
        """The stacked residuals whose sum of squares is the wing's objective ("mid_bay", "average"):
        each bay's `distance_residuals` times the square root of its weight."""
        return joined(*[_weighted_residuals(d, np.float64(w), self.objective) for w, d in zip(self.weights, distances)])

    def objective_value(self, distances):
        """The wing's objective, chord^2: the bays' `mean_square`, weighted by area."""
        return weighted_mean_square(list(distances), np.asarray(self.weights, np.float64), self.objective)

    def deviation(self, nodes) -> list:
        """Per bay, the concrete ``(n_rows, n_contour)`` distances of its rows at the stacked
        ``(n_bays, n_span, n_contour, 3)`` ``nodes`` (m), fractions of the local chord, in float64
        whatever the caller's JAX configuration."""
        with jax.enable_x64(True):
            return [np.asarray(self.distances(k, np.asarray(nodes[k]))) for k in range(len(self.bays))]

    def errors(self, distances) -> dict:
        """``rms``, ``max`` (``(n_bays,)``, fractions of the local chord, over the objective's rows:
        `distance_errors`) and ``wing_rms`` (one bay: its own; a wing: the square root of the bays'
        mean squares weighted by area) of concrete per-bay ``distances``."""
        errors = [distance_errors(d, self.objective) for d in distances]
        mean_squares = np.array([np.mean(np.asarray(d) ** 2) if self.objective != "worst" else e[0] ** 2
                                 for d, e in zip(distances, errors)])
        rms = np.array([e[0] for e in errors])
        wing = float(rms[0]) if len(errors) == 1 else float(np.sqrt(np.sum(self.weights * mean_squares)))
        return {"rms": rms, "max": np.array([e[1] for e in errors]), "wing_rms": wing}

    def mid_bay_targets(self) -> list:
        """Each bay's target at mid-bay: its two ribs' targets blended at the local chord (`row_targets`;
        the rib's own when both ribs carry the same section)."""
        return [row_targets(self.targets[k], self.targets[k + 1], bay.chord_root, bay.chord_tip, [0.5])[0]
                for k, bay in enumerate(self.bays)]
