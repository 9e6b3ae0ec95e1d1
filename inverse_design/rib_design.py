"""Rib design: manufacturability limits of a shaped rib, and the fabric's cut lengths.

A rib shape (`forward_solver.model.rib_shape`, the design variable ``rib_shape``)
must stay a rib that can be made:

* minimum thickness: at every chordwise station the designed rib's
  thickness (upper minus lower surface at the same x) is at least
  ``min_thickness`` times the starting rib's there (room for spars and
  stiffness where the section is thick, no crossing surfaces where it is
  thin);
* curvature bound: nowhere is the contour's radius of curvature below
  ``min_radius`` (fraction of chord; default half the starting rib's
  smallest, its nose radius), so the optimiser cannot buy accuracy with a
  kinked or pinched nose that a cut rib and a draped skin would not follow.

Both are evaluated on the designed section at `RIB_POINTS` points (the
starting rib's cosine spacing; thickness at every pair of upper and lower
points, curvature by the circle through each three consecutive points) as
vectors of smooth inequality constraints ``g >= 0`` for SLSQP, with exact
Jacobians from JAX (they do not involve the equilibrium, so they cost no
solve). `rib_report` measures them at a design, with active and violated
limits named as the tension limits are; on a wing each rib is measured
against its own starting section, and named by its index.

Whatever the limits (there may be none), `rib_crossings` checks every
designed rib for a crossing or a pinch to zero thickness inside the chord:
such a rib cannot be made, and a design with one is a failure with the
depth (``rib_crossing``).

`cut_lengths` gives the fabric's cut pattern: the cut (reference) length of
every grid edge, paper eq. (12) ``h = nominal / (1 + prestrain)``, summed
along the contour (each span row's perimeter strip) and along the span (each
contour node's span fibre).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from forward_solver import Parameters
from forward_solver import forces as fk
from forward_solver.stencils import safe_norm
from forward_solver.model.cut_field import local_prestrain
from forward_solver.model.rib_shape import rib_offsets

from targets.checks import self_crossings


__all__ = ["RIB_POINTS", "RibLimits", "RibGeometry", "rib_report", "rib_crossings", "cut_lengths"]

#: Points of the designed section the limits are evaluated on.
RIB_POINTS = 201
#: A rib limit counts as active within this fraction of its limit, and as broken beyond it.
RIB_TOLERANCE = 1e-3


@dataclass(frozen=True)
class RibLimits:
    """Manufacturability limits of a shaped rib.

    Args:
        min_thickness: least local thickness, as a fraction of the starting
            rib's at the same x (in (0, 1]; 0.8: at most 20% thinner anywhere).
        min_radius: least radius of curvature of the contour, fraction of
            chord (> 0); None: half the starting rib's smallest radius.
    """

    min_thickness: float = 0.8
    min_radius: float | None = None

    def check(self) -> "RibLimits":
        """Raise a ValueError saying what to change for a limit that makes no sense."""
        if not (isinstance(self.min_thickness, (int, float)) and 0 < self.min_thickness <= 1):
            raise ValueError(f"min_thickness is a fraction of the starting rib's thickness in (0, 1], "
                             f"got {self.min_thickness!r}")
        if self.min_radius is not None and not (isinstance(self.min_radius, (int, float))
                                                and math.isfinite(self.min_radius) and self.min_radius > 0):
            raise ValueError(f"min_radius is a positive fraction of chord (or None), got {self.min_radius!r}")
        return self


def _section_z(x, z0, camber, thickness_scale, coefficients):
    """The designed section's z at the starting rib's points (as `forces.nominal_nodes` mounts it)."""
    return camber + thickness_scale * (z0 - camber) + rib_offsets(x, coefficients)


def curvature(x, z):
    """Signed curvature (1/chord) of the circle through each three consecutive points (Menger)."""
    a = jnp.stack([x[:-2], z[:-2]], -1)
    b = jnp.stack([x[1:-1], z[1:-1]], -1)
    c = jnp.stack([x[2:], z[2:]], -1)
    ab, bc, ac = b - a, c - b, c - a
    cross = ab[:, 0] * bc[:, 1] - ab[:, 1] * bc[:, 0]
    return 2.0 * cross / (safe_norm(ab) * safe_norm(bc) * safe_norm(ac))


class RibGeometry:
    """The designed rib of a design vector, and its limits as smooth constraints.

    Args:
        rib: the starting rib section (`targets.Airfoil`, chord-normalised).
        limits: the `RibLimits`.
    """

    def __init__(self, rib, limits: RibLimits):
        self.limits = limits.check()
        section = rib.resample(RIB_POINTS)
        self.x = np.asarray(section.x, np.float64)
        self.z0 = np.asarray(section.z, np.float64)
        self.camber = np.asarray(rib.camber(np.clip(self.x, 0.0, 1.0)), np.float64)
        n = self.x.size
        half = n // 2
        # Upper point k and lower point n-1-k share their x (the resampling is symmetric).
        self.upper = np.arange(1, half)
        self.lower = n - 1 - self.upper
        with jax.enable_x64(True):
            t0 = self.z0[self.upper] - self.z0[self.lower]
            radius0 = 1.0 / np.max(np.abs(np.asarray(curvature(jnp.asarray(self.x), jnp.asarray(self.z0)))))
        self.thickness0 = t0
        # Thickness rows in the units `measure` and `rib_report` judge them in: the shortfall of the
        # thickness ratio where the rib has thickness, else of the thickness relative to its largest.
        self.inside = t0 > 1e-3 * np.max(t0)
        self.thickness_unit = np.where(self.inside, t0, np.max(t0))
        self.start_radius = float(radius0)
        self.min_radius = 0.5 * radius0 if limits.min_radius is None else float(limits.min_radius)

    NAMES = ("rib_min_thickness", "rib_min_radius")

    def section_z(self, parameters: Parameters):
        """z of the designed section at the starting rib's points (chord-normalised)."""
        return _section_z(self.x, self.z0, self.camber, parameters.rib_thickness_scale, parameters.rib_shape)

    def functions(self, parameters: Parameters):
        """``g >= 0``: thickness rows (per station, the thickness ratio's margin, as `measure` and
        `rib_report` judge it; relative to the largest starting thickness where the rib has none) and
        curvature rows (two per point: ``1 -+ kappa r_min``)."""
        z = self.section_z(parameters)
        thickness = z[self.upper] - z[self.lower]
        g_thickness = (thickness - self.limits.min_thickness * self.thickness0) / self.thickness_unit
        kappa = curvature(jnp.asarray(self.x), z) * self.min_radius
        return jnp.concatenate([g_thickness, 1.0 - kappa, 1.0 + kappa])

    def measure(self, parameters: Parameters) -> dict:
        """The limits' measured values at concrete ``parameters``: least thickness ratio and radius."""
        with jax.enable_x64(True):
            z = np.asarray(self.section_z(parameters))
            kappa = np.asarray(curvature(jnp.asarray(self.x), jnp.asarray(z)))
        thickness = z[self.upper] - z[self.lower]
        inside = self.inside  # ratios where the rib has thickness
        return {"rib_min_thickness": float(np.min(thickness[inside] / self.thickness0[inside])),
                "rib_min_thickness_limit": self.limits.min_thickness,
                "rib_min_radius": float(1.0 / np.max(np.abs(kappa))),
                "rib_min_radius_limit": float(self.min_radius),
                "rib_start_radius": self.start_radius}


def rib_report(geometries: list, parameters: Parameters, rib_shapes=None) -> tuple[list, dict, dict, list, list]:
    """Active and violated rib limits at a design, and the measured values.

    Args:
        geometries: ``(rib, RibGeometry)`` pairs: the rib's index and its
            starting section's limits (one pair for a single bay's shared shape).
        parameters: the design's shared `Parameters` (its ``rib_shape`` when shared).
        rib_shapes: ``(n_ribs, 2 K)`` per-rib shapes, or None (shared).

    Returns:
        ``(active, violated, values, per_rib, messages)``: names of limits
        within `RIB_TOLERANCE` of their bound (``"rib_min_thickness"``; with
        several ribs ``"rib_min_thickness@rib 2"``); ``{name: {rib: amount}}`` of
        each limit broken by more than it at some rib, relative to the limit
        (the thickness ratio's shortfall, or the radius's in fractions of
        chord); the measured values (`RibGeometry.measure`) of the rib with
        the least margin on each limit; every rib's ``{"rib": k, ...}``
        values; and one sentence per broken limit and rib.
    """
    if not geometries or (rib_shapes is None and parameters.rib_shape is None):
        return [], {}, {}, [], []
    active, where, values, per_rib, messages = [], {}, {}, [], []
    margin = {}
    one = len(geometries) == 1
    for rib, geometry in geometries:
        shaped = parameters if rib_shapes is None else parameters.replace(rib_shape=np.asarray(rib_shapes)[rib])
        measured = geometry.measure(shaped)
        per_rib.append({"rib": rib, **measured})
        at = "" if one else f" at rib {rib}"
        for name in RibGeometry.NAMES:
            value, limit = measured[name], measured[f"{name}_limit"]
            if (value - limit) / limit <= RIB_TOLERANCE:
                active.append(name if one else f"{name}@rib {rib}")
            if (limit - value) / limit > RIB_TOLERANCE:
                where.setdefault(name, {})[rib] = float(limit - value)
                messages.append(
                    f"rib_min_thickness violated{at}: the rib is {value:.4g} of its starting thickness "
                    f"somewhere, below the limit {limit:.4g}" if name == "rib_min_thickness" else
                    f"rib_min_radius violated{at}: the rib's smallest radius of curvature is {value:.4g} "
                    f"chord, below the limit {limit:.4g}")
            if (value - limit) / limit < margin.get(name, math.inf):
                margin[name] = (value - limit) / limit
                values.update({name: value, f"{name}_limit": limit})
                if name == "rib_min_radius":
                    values["rib_start_radius"] = measured["rib_start_radius"]
    return active, where, values, per_rib, messages


def rib_crossings(sections: list, parameters: Parameters, rib_shapes=None) -> tuple[dict, list[str]]:
    """Designed ribs that cross or pinch themselves, whatever the rib limits (none may be set).

    Each rib's designed section (`RibGeometry.section_z`: thickness scale and
    shape applied to its starting section, at `RIB_POINTS` points) is
    searched for a crossing or a pinch to zero thickness inside the chord
    (`targets.checks.self_crossings`). Such a rib cannot be made, so a design
    that has one is a failure, with the amount: the largest negative
    thickness (lower surface above the upper one at the same x), chord.

    Args:
        sections: each rib's starting section (`targets.Airfoil`), root to
            tip; a section object given twice (one shape shared) is checked once.
        parameters: the design's shared `Parameters` (its thickness scale,
            and its ``rib_shape`` when shared).
        rib_shapes: ``(n_ribs, 2 K)`` per-rib shapes, or None (shared).

    Returns:
        ``({"rib_crossing": {rib: amount}} or {}, messages)``: the amount per
        crossed rib, chord (0 for a pinch), and one sentence per crossed rib
        saying where (x/c) and what to change.
    """
    where, messages, seen = {}, [], set()
    for rib, section in enumerate(sections):
        shape = parameters.rib_shape if rib_shapes is None else np.asarray(rib_shapes)[rib]
        if shape is None or (rib_shapes is None and id(section) in seen):
            continue
        seen.add(id(section))
        resampled = section.resample(RIB_POINTS)
        x = np.asarray(resampled.x, np.float64)
        camber = np.asarray(section.camber(np.clip(x, 0.0, 1.0)), np.float64)
        with jax.enable_x64(True):
            z = np.asarray(_section_z(x, np.asarray(resampled.z, np.float64), camber,
                                      float(parameters.rib_thickness_scale), jnp.asarray(shape, jnp.float64)))
        crossings = self_crossings(x, z)
        upper = np.arange(1, x.size // 2)
        depth = max(0.0, -float(np.min(z[upper] - z[x.size - 1 - upper])))
        start = np.asarray(resampled.z, np.float64)
        if not crossings or (self_crossings(x, start)
                             and depth <= max(0.0, -float(np.min(start[upper] - start[x.size - 1 - upper])))):
            continue  # (a thin tail that the points already pinch, unshaped, is the section's own)
        where[rib] = depth
        at = "" if len(sections) == 1 or (rib_shapes is None and len(set(map(id, sections))) == 1) else f" {rib}"
        first = crossings[0]
        messages.append(
            f"the designed rib{at} {'pinches to zero thickness' if first.touching else 'crosses itself'} at "
            f"x/c = {first.x:.4g} (its lower surface up to {depth:.3g} chord above the upper one"
            f"{f', at {len(crossings)} places' if len(crossings) > 1 else ''}): such a rib cannot be made; keep "
            f"the rib limits on (min_thickness) or narrow the rib_shape bounds")
    return ({"rib_crossing": where} if where else {}), messages


@partial(jax.jit, static_argnames=("physics",))
def _cut_reference(geometry, params, physics):
    """``(span_length, contour_length, local span prestrain, local chord prestrain)`` of `forces.prepare`
    and `cut_field.local_prestrain`: one compiled program (eagerly, some thirty operations compiled
    one by one, most of a second of a report)."""
    ref = fk.prepare(geometry, params, physics)
    return (ref.span_length, ref.contour_length) + tuple(local_prestrain(geometry, params, physics.periodic))


def cut_lengths(scene, parameters: Parameters) -> dict:
    """The fabric's cut pattern: reference lengths of eq. (12) summed along the grid lines.

    Args:
        scene: the `forward_solver.Scene` (bay and fabric).
        parameters: the design's `Parameters` (prestrain and cut pattern, rib scales and shape).

    Returns:
        ``{"contour_cut_m": (n_span,) cut perimeter of each span row's strip
        (rib to rib), "contour_mounted_m": the mounted perimeters,
        "span_cut_m": (n_contour,) cut length of each contour node's span
        fibre (rib to rib), "span_mounted_m": the mounted lengths,
        "contour_edge_cut_m": (n_span, n_edges) every contour edge's cut
        length, "span_edge_cut_m": (n_span - 1, n_contour) every span
        edge's}``, metres.
    """
    physics = fk.static_physics(scene.physics(dynamic=False))
    with jax.enable_x64(True):
        params = scene.params(parameters.as_floats())
        span, contour, local_span, local_chord = (np.asarray(a, np.float64) for a in _cut_reference(
            scene.bay.geometry(), params, physics))
        local_span = np.broadcast_to(local_span, span.shape[1:])
        local_chord = np.broadcast_to(local_chord, contour.shape[1:])
    return {"contour_cut_m": contour.sum(axis=1), "contour_mounted_m": (contour * (1 + local_chord)).sum(axis=1),
            "span_cut_m": span.sum(axis=0), "span_mounted_m": span.sum(axis=0) * (1 + local_span),
            "contour_edge_cut_m": contour, "span_edge_cut_m": span,
            "span_prestrain": np.array(local_span), "contour_prestrain": np.array(local_chord)}
