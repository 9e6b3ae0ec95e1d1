"""The one force kernel: fabric tensions and follower pressure on the grid.

Discretisation of paper eq. (10)-(15) on the structured grid of a `Bay`:

* Span edges ``(i+1/2, j)`` and contour edges ``(i, j+1/2)`` carry stretches
  ``lambda = |x_b - x_a| / h`` (eq. 12) against their cut (reference) lengths
  ``h = nominal length / (1 + prestrain)``, and unit vectors (direction
  cosines, eq. 13).
* Each cell ``(i+1/2, j+1/2)`` averages the stretches of its two span edges
  and of its two contour edges (eq. 12) and takes the tensions of the
  fabric's law (`Physics.law`: eq. 10, or a law fitted to a biaxial test,
  `model.fibre_law`) with elongations ``e = lambda - 1``; with
  ``tension_only`` a negative tension is clamped to zero (the fabric
  wrinkles instead).
* The force that the span fibres carry across a cell is ``T11 lambda2 h2``
  (the ``{T11 lambda2}`` terms of eq. 14); half of it acts along each of the
  cell's two span edges, on the edge's current direction (eq. 13). Contour
  fibres likewise with ``T22 lambda1 h1``.
* Pressure is a follower load: a node receives ``p`` times the area vector of
  the eight triangles between it, its edge midpoints and its cell centres
  (eq. 15), which is the quarter-quadrilateral ``(B - O) x (C - A) / 2`` of
  each adjacent cell.
* With a shear stiffness (`Physics.shear_stiffness`), the ``T12`` terms of
  eq. (1) and (6) from the shear angle of eq. (8)-(9) (`shear`).

The law is not conservative in general (eq. 10 with ``nu12 E22 != nu21 E11``
and a follower load), so solvers work on the force residual, not an energy.
Everything here is a pure function of arrays: geometry and parameters are
traced, only the grid shape and the `Physics` switches (the law and the
shear stiffness among them) are static.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import NamedTuple

import jax.numpy as jnp

from .model.cut_field import local_prestrain
from .model.fibre_law import LinearLaw
from .model.rib_shape import rib_offsets
from .shear import shear_forces
from .stencils import (cell_corners, contour_edge_sum, next_j, safe_norm, scatter_cell_corners, scatter_contour_edges,
                       scatter_span_edges, span_edge_sum, this_j)

__all__ = ["Geometry", "KernelInputs", "Physics", "Reference", "Forces", "nominal_nodes", "mounted_nodes", "prepare",
           "forces", "residual", "relative_residual", "static_physics", "node_area_vectors", "surface_area",
           "node_stiffness", "fibres", "Fibres", "rounding_residual_floor", "SHEAR_BOUND"]


class Geometry(NamedTuple):
    """Bay geometry as traced arrays (see `Bay` for meanings, SI units)."""

    contour_root: jnp.ndarray  # (nc, 2) chord-normalised
    contour_tip: jnp.ndarray  # (nc, 2)
    camber_root: jnp.ndarray  # (nc,)
    camber_tip: jnp.ndarray  # (nc,)
    chord_root: jnp.ndarray  # m
    chord_tip: jnp.ndarray  # m
    rib_spacing: jnp.ndarray  # m
    free: jnp.ndarray  # (ns, nc) 1.0 where the node may move, 0.0 where held


class KernelInputs(NamedTuple):
    """The force kernel's inputs: traced physical values, new values never recompile.

    Built by `scene.Scene.params` from the design's `parameters.Parameters`
    and the `fabric.Fabric` (the kernel never sees the design's pytree itself).
    """

    pressure: jnp.ndarray  # Pa, internal overpressure
    prestrain_span: jnp.ndarray  # dimensionless
    prestrain_chord: jnp.ndarray  # dimensionless
    stiffness_span: jnp.ndarray  # E11, N/m
    stiffness_chord: jnp.ndarray  # E22, N/m
    poisson: jnp.ndarray  # nu12 = nu21
    areal_density: jnp.ndarray  # rho0, kg/m^2
    viscosity: jnp.ndarray  # eta, N*s/m
    aerodynamic_damping: jnp.ndarray  # nu_n of eq. (11), s/m
    gravity: jnp.ndarray  # m/s^2 along -z
    rib_thickness_scale: jnp.ndarray  # dimensionless
    rib_chord_scale: jnp.ndarray  # dimensionless
    rib_shape_root: jnp.ndarray  # (2K,) rib-shape coefficients of the root rib (`rib_shape`); (0,): none
    rib_shape_tip: jnp.ndarray  # (2K,) the same for the tip rib
    cut_pattern: jnp.ndarray  # (2K,) cut-pattern coefficients, span then chord (`cut_field`); (0,): uniform


@dataclass(frozen=True)
class Physics:
    """Static switches and the fabric's law: a term that is off is absent from the compiled program.

    ``law`` gives the fibres' tensions (`fibre_law.LinearLaw`, eq. 10, or a
    fitted `fibre_law.SurfaceLaw`); ``shear_stiffness`` is ``G`` of the
    ``T12`` terms (`shear`), N/m, a Python float: 0 leaves them out.
    """

    periodic: bool
    tension_only: bool = True
    viscous: bool = False
    aerodynamic: bool = False
    gravity: bool = False
    law: object = LinearLaw()
    shear_stiffness: float = 0.0


#: The shear term's share of `node_stiffness`'s modulus, in units of the shear stiffness ``G``: a cell's
#: shear energy couples its four corners with a stiffness of order ``G (h2/h1 + 2 + h1/h2)``, which the
#: edges' width-over-length factors carry with this modulus. Measured against the shear forces'
#: Jacobian near the mounted shape: its row sums are at most 1.1 times this share (default bay 5x32,
#: and ribs 0.05 m apart on 9x128), as the fibres' own are 0.8-1.7 times theirs.
SHEAR_BOUND = 2.0


class Reference(NamedTuple):
    """Quantities fixed for one solve (they depend on parameters, not on the state)."""

    nodes: jnp.ndarray  # (ns, nc, 3) nominal (mounted) shape, m
    span_length: jnp.ndarray  # (ns-1, nc) cut length h1 of each span edge, m
    contour_length: jnp.ndarray  # (ns, ne) cut length h2 of each contour edge, m
    node_area: jnp.ndarray  # (ns, nc) undeformed area lumped to each node, m^2
    free: jnp.ndarray  # (ns, nc, 1) 1.0 on free nodes
    skin_area: jnp.ndarray  # nominal skin area A, m^2 (the residual's scale is p A)


class Forces(NamedTuple):
    """Nodal force and the cell tensions it came from."""

    total: jnp.ndarray  # (ns, nc, 3) N, zero on held nodes
    tension_span: jnp.ndarray  # (ns-1, ncell) T11, N/m
    tension_chord: jnp.ndarray  # (ns-1, ncell) T22, N/m
    wrinkled: jnp.ndarray  # (ns-1, ncell) bool: a fibre tension would be compressive


# ------------------------------------------------------------------ reference
def nominal_nodes(geometry: Geometry, rib_thickness_scale=1.0, rib_chord_scale=1.0,
                  rib_shape_root=None, rib_shape_tip=None) -> jnp.ndarray:
    """Mounted shape ``(ns, nc, 3)``: the ruled surface between the rib contours.

    The rib thickness scale multiplies the distance from the camber line, the
    rib shape adds its outward offset (`rib_shape.rib_offsets`, chord-normalised;
    None: none) and the chord scale multiplies x (both about the rib's leading
    edge).
    """
    ns = geometry.free.shape[0]
    t = jnp.linspace(0.0, 1.0, ns, dtype=geometry.contour_root.dtype)[:, None]

    def rib(contour, camber, chord, shape):
        x = contour[:, 0] * chord * rib_chord_scale
        offset = rib_offsets(contour[:, 0], shape)
        z = (camber + rib_thickness_scale * (contour[:, 1] - camber) + offset) * chord
        return x, z

    xr, zr = rib(geometry.contour_root, geometry.camber_root, geometry.chord_root, rib_shape_root)
    xt, zt = rib(geometry.contour_tip, geometry.camber_tip, geometry.chord_tip, rib_shape_tip)
    x = (1.0 - t) * xr[None, :] + t * xt[None, :]
    z = (1.0 - t) * zr[None, :] + t * zt[None, :]
    y = jnp.broadcast_to(t * geometry.rib_spacing, x.shape)
    return jnp.stack([x, y, z], axis=-1)


def mounted_nodes(geometry: Geometry, params: KernelInputs) -> jnp.ndarray:
    """`nominal_nodes` with the rib variables of the kernel ``params`` (scales and shapes)."""
    return nominal_nodes(geometry, params.rib_thickness_scale, params.rib_chord_scale,
                         params.rib_shape_root, params.rib_shape_tip)


def prepare(geometry: Geometry, params: KernelInputs, physics: Physics) -> Reference:
    """Cut lengths and lumped areas for one solve.

    The fabric is cut shorter than the mounted geometry: reference length =
    nominal length / (1 + prestrain) per fibre direction (docs/architecture.md, "Conventions");
    with a cut pattern the prestrain is the local one of `cut_field.local_prestrain`
    (span fibres at their contour node, contour fibres at their edge's midpoint).
    """
    x0 = mounted_nodes(geometry, params)
    prestrain_span, prestrain_chord = local_prestrain(geometry, params, physics.periodic)
    span_length = safe_norm(x0[1:] - x0[:-1]) / (1.0 + prestrain_span)
    contour_length = safe_norm(next_j(x0, physics.periodic) - this_j(x0, physics.periodic))
    contour_length = contour_length / (1.0 + prestrain_chord)
    h1_cell = 0.5 * (this_j(span_length, physics.periodic) + next_j(span_length, physics.periodic))
    h2_cell = 0.5 * (contour_length[:-1] + contour_length[1:])
    quarter = 0.25 * h1_cell * h2_cell
    node_area = scatter_cell_corners(quarter, quarter, quarter, quarter, physics.periodic)
    return Reference(x0, span_length, contour_length, node_area, geometry.free[..., None],
                     surface_area(x0, physics.periodic))


def surface_area(x: jnp.ndarray, periodic: bool) -> jnp.ndarray:
    """Area of the grid's surface, m^2: the sum of its quadrilaterals (half the diagonals' cross product)."""
    n00, n10, n11, n01 = cell_corners(x, periodic)
    return 0.5 * jnp.sum(safe_norm(jnp.cross(n11 - n00, n01 - n10)))


# --------------------------------------------------------------------- forces
def node_area_vectors(x: jnp.ndarray, periodic: bool) -> jnp.ndarray:
    """Area vector of each node's share of the surface (eq. 15), ``(ns, nc, 3)`` m^2.

    Its components are the projections of the eight triangles around the
    node on the coordinate planes; it points along ``e1 x e2`` (outward).
    """
    n00, n10, n11, n01 = cell_corners(x, periodic)
    centre = 0.25 * (n00 + n10 + n11 + n01)
    c00 = 0.25 * jnp.cross(centre - n00, n01 - n10)
    c10 = 0.25 * jnp.cross(centre - n10, n00 - n11)
    c11 = 0.25 * jnp.cross(centre - n11, n10 - n01)
    c01 = 0.25 * jnp.cross(centre - n01, n11 - n00)
    return scatter_cell_corners(c00, c10, c11, c01, periodic)


class Fibres(NamedTuple):
    """Edge and cell kinematics and tensions of the current shape (eq. 10, 12, 13)."""

    unit1: jnp.ndarray  # (ns-1, nc, 3) span-edge directions
    unit2: jnp.ndarray  # (ns, ne, 3) contour-edge directions
    length1: jnp.ndarray  # (ns-1, nc) span-edge lengths, m
    length2: jnp.ndarray  # (ns, ne) contour-edge lengths, m
    edge_force1: jnp.ndarray  # (ns-1, nc) force along each span edge, N
    edge_force2: jnp.ndarray  # (ns, ne) force along each contour edge, N
    width1: jnp.ndarray  # (ns-1, nc) current fabric width carried by each span edge, m
    width2: jnp.ndarray  # (ns, ne) same for each contour edge, m
    tension_span: jnp.ndarray  # (ns-1, ncell) T11, N/m
    tension_chord: jnp.ndarray  # (ns-1, ncell) T22, N/m
    wrinkled: jnp.ndarray  # (ns-1, ncell) bool
    strain_span: jnp.ndarray  # (ns-1, ncell) e11 = lambda1 - 1 of each cell (eq. 12)
    strain_chord: jnp.ndarray  # (ns-1, ncell) e22


def fibres(x, ref: Reference, params: KernelInputs, physics: Physics, v=None) -> Fibres:
    """Stretches (eq. 12), directions (13), tensions (10) and edge forces (14)."""
    periodic = physics.periodic
    d1 = x[1:] - x[:-1]  # span edges (ns-1, nc, 3)
    d2 = next_j(x, periodic) - this_j(x, periodic)  # contour edges (ns, ne, 3)
    len1 = safe_norm(d1)
    len2 = safe_norm(d2)
    stretch1 = len1 / ref.span_length  # eq. (12)
    stretch2 = len2 / ref.contour_length
    unit1 = d1 / jnp.where(len1 > 0, len1, 1.0)[..., None]  # eq. (13)
    unit2 = d2 / jnp.where(len2 > 0, len2, 1.0)[..., None]

    cell_stretch1 = 0.5 * (this_j(stretch1, periodic) + next_j(stretch1, periodic))
    cell_stretch2 = 0.5 * (stretch2[:-1] + stretch2[1:])
    e1 = cell_stretch1 - 1.0
    e2 = cell_stretch2 - 1.0
    t11, t22 = physics.law.tensions(e1, e2, params)  # eq. (10), or the fabric's fitted law
    wrinkled = (t11 < 0.0) | (t22 < 0.0)
    if physics.viscous:
        dv1 = v[1:] - v[:-1]
        dv2 = next_j(v, periodic) - this_j(v, periodic)
        rate1 = jnp.sum(unit1 * dv1, axis=-1) / ref.span_length
        rate2 = jnp.sum(unit2 * dv2, axis=-1) / ref.contour_length
        t11 = t11 + params.viscosity * 0.5 * (this_j(rate1, periodic) + next_j(rate1, periodic))
        t22 = t22 + params.viscosity * 0.5 * (rate2[:-1] + rate2[1:])
    if physics.tension_only:
        t11 = jnp.maximum(t11, 0.0)
        t22 = jnp.maximum(t22, 0.0)

    h1_cell = 0.5 * (this_j(ref.span_length, periodic) + next_j(ref.span_length, periodic))
    h2_cell = 0.5 * (ref.contour_length[:-1] + ref.contour_length[1:])
    # Current cell widths lambda2 h2 and lambda1 h1; the span-fibre force
    # {T11 lambda2} h2 across a cell goes half to each of its span edges (eq. 14).
    half_width2 = 0.5 * cell_stretch2 * h2_cell
    half_width1 = 0.5 * cell_stretch1 * h1_cell
    return Fibres(
        unit1=unit1,
        unit2=unit2,
        length1=len1,
        length2=len2,
        edge_force1=contour_edge_sum(t11 * half_width2, periodic),
        edge_force2=span_edge_sum(t22 * half_width1),
        width1=contour_edge_sum(half_width2, periodic),
        width2=span_edge_sum(half_width1),
        tension_span=t11,
        tension_chord=t22,
        wrinkled=wrinkled,
        strain_span=e1,
        strain_chord=e2,
    )


def forces(x: jnp.ndarray, ref: Reference, params: KernelInputs, physics: Physics,
           pressure: jnp.ndarray | None = None, v: jnp.ndarray | None = None) -> Forces:
    """Net nodal force of fabric tension, pressure and gravity (eq. 10-15).

    Args:
        x: ``(ns, nc, 3)`` current node positions, m.
        ref: cut lengths and lumped areas from `prepare`.
        params: traced parameters.
        physics: static switches; viscosity and aerodynamic damping need ``v``.
        pressure: the pressure to apply now, Pa (default ``params.pressure``;
            the dynamic scheme passes its ramp value).
        v: ``(ns, nc, 3)`` node velocities, m/s (dynamic terms only).

    Returns:
        `Forces`, with the total force zero on held nodes.
    """
    periodic = physics.periodic
    p = params.pressure if pressure is None else pressure
    fib = fibres(x, ref, params, physics, v)
    total = scatter_span_edges(fib.edge_force1[..., None] * fib.unit1)
    total = total + scatter_contour_edges(fib.edge_force2[..., None] * fib.unit2, periodic)
    if physics.shear_stiffness:
        total = total + shear_forces(x, ref, physics)  # the T12 terms of eq. (1), (6)

    area = node_area_vectors(x, periodic)
    if physics.aerodynamic:
        # eq. (11): p (1 - nu_n V_n)^2 sgn(1 - nu_n V_n), V_n the normal velocity.
        norm = safe_norm(area)
        normal = area / jnp.where(norm > 0, norm, 1.0)[..., None]
        factor = 1.0 - params.aerodynamic_damping * jnp.sum(v * normal, axis=-1)
        total = total + (p * factor * jnp.abs(factor))[..., None] * area
    else:
        total = total + p * area
    if physics.gravity:
        weight = params.areal_density * params.gravity * ref.node_area
        total = total.at[..., 2].add(-weight)
    return Forces(total * ref.free, fib.tension_span, fib.tension_chord, fib.wrinkled)


def node_stiffness(x, ref: Reference, params: KernelInputs, physics: Physics) -> jnp.ndarray:
    """Upper estimate of each node's stiffness, ``(ns, nc)`` N/m.

    The sum over the node's edges of the axial stiffness (the law's tangent
    bound, `fibre_law`: for eq. 10 the plane-strain modulus with the Poisson
    coupling; with a shear stiffness, `SHEAR_BOUND` times it more; times the
    carried width over the cut length) and the geometric stiffness (edge
    force over edge length), plus the follower pressure's ``p * h``. Dynamic
    relaxation scales its fictitious masses to it (Gershgorin bound, so every
    node runs at the same stable step).
    """
    periodic = physics.periodic
    fib = fibres(x, ref, params, static_physics(physics))
    modulus = physics.law.stiffness_bound(params, fib.strain_span, fib.strain_chord)
    if physics.shear_stiffness:
        modulus = modulus + SHEAR_BOUND * physics.shear_stiffness
    k1 = modulus * fib.width1 / ref.span_length + fib.edge_force1 / jnp.where(fib.length1 > 0, fib.length1, 1.0)
    k2 = modulus * fib.width2 / ref.contour_length + fib.edge_force2 / jnp.where(fib.length2 > 0, fib.length2, 1.0)
    k1 = k1 + jnp.abs(params.pressure) * fib.length1
    k2 = k2 + jnp.abs(params.pressure) * fib.length2
    node = jnp.pad(k1, ((0, 1), (0, 0))) + jnp.pad(k1, ((1, 0), (0, 0)))
    if periodic:
        node = node + k2 + jnp.roll(k2, 1, axis=1)
    else:
        node = node + jnp.pad(k2, ((0, 0), (0, 1))) + jnp.pad(k2, ((0, 0), (1, 0)))
    return node


def static_physics(physics: Physics) -> Physics:
    """The same switches without the velocity terms (equilibrium does not see them)."""
    return dataclasses.replace(physics, viscous=False, aerodynamic=False)


def residual(x: jnp.ndarray, ref: Reference, params: KernelInputs, physics: Physics) -> jnp.ndarray:
    """Static force residual ``R(x)`` at rest (no velocity terms), ``(ns, nc, 3)`` N."""
    return forces(x, ref, params, static_physics(physics)).total


def relative_residual(x: jnp.ndarray, ref: Reference, params: KernelInputs, physics: Physics) -> jnp.ndarray:
    """``||R_free||_2 / (p A)``: the residual over the total pressure load (dimensionless)."""
    r = residual(x, ref, params, physics)
    return safe_norm(r.reshape(-1)) / (params.pressure * ref.skin_area)


def rounding_residual_floor(ref: Reference, params: KernelInputs, physics: Physics, eps) -> jnp.ndarray:
    """Relative residual ``||R_free|| / (p A)`` that rounding the coordinates can leave.

    Rounding every coordinate to a relative precision ``eps`` (``eps`` of the
    floating-point type, e.g. 1.2e-7 for float32) changes each edge length by
    up to about ``eps |x|_max``, so its stretch (eq. 12) by ``eps |x|_max / h``
    and the fibre force it carries (the ``{T lambda} h`` of eq. 14) by
    ``E' w eps |x|_max / h``, with ``E'`` the stiffest plane-strain modulus
    ``max(E11, E22) / (1 - nu^2)`` and ``w`` the fabric width the edge
    carries. These errors are summed in quadrature over the edges that touch
    a free node and divided by the pressure load ``p A``. Short edges (the
    cosine-spaced leading edge) dominate, so the floor grows as the grid is
    refined and as the fabric stiffens relative to the pressure.

    Measured on the default bay (NACA 2412, 2e5 N/m, 0.5% prestrain, 20 kPa,
    9x64 to 65x512): the float32 relaxation reaches a float64-evaluated
    residual of 0.2-0.3 times this estimate, and the float64 equilibrium
    rounded to float32 has 0.06-0.14 times it; so a tolerance at or above the
    estimate is within float32's reach with a margin of 3-5.

    Args:
        ref: cut lengths and mounted nodes from `prepare`.
        params: traced parameters.
        physics: static switches.
        eps: relative rounding precision of the coordinates.

    Returns:
        The dimensionless floor (a scalar array).
    """
    periodic = physics.periodic
    fib = fibres(ref.nodes, ref, params, static_physics(physics))
    modulus = physics.law.modulus(params)
    if physics.shear_stiffness:
        modulus = modulus + SHEAR_BOUND * physics.shear_stiffness
    free = ref.free[..., 0] > 0
    touches1 = free[1:] | free[:-1]
    touches2 = this_j(free, periodic) | next_j(free, periodic)
    k1 = jnp.where(touches1, fib.width1 / ref.span_length, 0.0)
    k2 = jnp.where(touches2, fib.width2 / ref.contour_length, 0.0)
    spread = jnp.sqrt(jnp.sum(k1 * k1) + jnp.sum(k2 * k2))
    size = jnp.max(jnp.abs(ref.nodes))
    return eps * size * modulus * spread / (params.pressure * ref.skin_area)
