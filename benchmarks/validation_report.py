"""Validation report: the solver against closed forms and independent references.

Runs every validation case and writes ``docs/validation.md``: for
each case its reference (a closed form with its formula, or an independent
check), the tolerance and why, the measured error, pass or fail, the grid and
the run time (a fresh process: JAX compilation included); the machine and the
library versions at the top. The closed forms come from
`forward_solver.reference.closed_forms` and the independent residual from
`forward_solver.reference.independent_residual`, the same functions the tests use, so
the report and the tests cannot drift apart.

Usage: python benchmarks/validation_report.py [--out docs/validation.md]

About three to five minutes on two CPU cores.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import scipy

from forward_solver import Bay, Fabric, PressureRamp, Relax, Scene, simulate, solve_equilibrium
from forward_solver import forces as fk
from forward_solver.stencils import safe_norm
from forward_solver.reference.closed_forms import (
    circle_contour,
    cylinder_radius,
    fabric_tensions,
    flat_panel_pressure_force,
    hoop_tension,
    strip_arc_radius,
    strip_elongation,
    strip_sag,
)
from forward_solver.reference.independent_residual import numpy_relative_residual
from forward_solver.solvers.relax import MASS_SAFETY, RelaxOptions, relax_jit
from forward_solver.solve import float32_residual_floor
from forward_solver.model.parameters import PARAMETER_NAMES, Parameters, as_parameters
from targets import Airfoil, naca

PRESSURE = 2e4
PRESTRAIN = (0.005, 0.005)
#: Float32 relaxation steps from the mounted shape to find where it stalls.
STAGNATION_STEPS = 40_000


@dataclass
class Row:
    """One line of the summary table and its details."""

    case: str
    reference: str
    tolerance: str
    measured: str
    passed: bool
    grid: str
    seconds: float = 0.0
    details: list = field(default_factory=list)


def _timed(function):
    start = time.perf_counter()
    rows = function()
    elapsed = time.perf_counter() - start
    rows = rows if isinstance(rows, list) else [rows]
    for row in rows:
        row.seconds = elapsed / len(rows)
    return rows


# ----------------------------------------------------------------- closed forms
def long_cylinder():
    radius, pressure, ps, pc = 0.05, 5e4, 0.005, 0.005
    fabric = Fabric()
    e, nu = fabric.stiffness_span, fabric.poisson
    bay = Bay.from_airfoil(Airfoil(*circle_contour(), name="circle"), chord=2 * radius,
                           rib_spacing=20 * radius, n_span=33, n_contour=64, fix_trailing_edge=False)
    sol = solve_equilibrium(Scene(bay, fabric), pressure, (ps, pc), rtol=1e-10)
    mid = bay.n_span // 2
    ring = sol.nodes[mid]
    r_nodes = np.hypot(ring[:, 0] - radius, ring[:, 2])
    r = r_nodes.mean()
    cut = bay.rib_spacing / (bay.n_span - 1) / (1 + ps)
    e11 = np.linalg.norm(sol.nodes[mid + 1] - ring, axis=-1).mean() / cut - 1
    r_closed = cylinder_radius(radius, pressure, e, e, nu, pc, e11)
    growth_error = abs((r - radius) / (r_closed - radius) - 1)
    hoop = sol.tension_chord[mid - 1: mid + 1].mean()
    hoop_error = abs(hoop / hoop_tension(pressure, r) - 1)
    grid = "33x64 (20 radii between circular ribs)"
    common = [(f"R = {radius} m, p = {pressure:g} Pa, prestrain {ps} both ways, E = {e:g} N/m, "
               f"nu = {nu}; mid-bay ring round to {np.ptp(r_nodes) / radius:.1e} R; axial "
               f"elongation there {e11:.6f} (prestrain {ps})")]
    return [
        Row("Long cylinder: hoop tension", "Laplace: T22 = p r", "0.5%",
            f"{hoop_error:.2%}", hoop_error < 0.005, grid,
            details=common + [f"T22 = {hoop:.2f} N/m, p r = {hoop_tension(pressure, r):.2f} N/m"]),
        Row("Long cylinder: radius growth",
            "hoop law of eq. (10): r = (E22 - nu E11 e11) / (E22 (1+pc)/R - p (1-nu^2))",
            "0.5% of r - R (the 64-gon's apothem cos(pi/64) is 0.1% off the circle)",
            f"{growth_error:.2%}", growth_error < 0.005, grid,
            details=[f"r - R = {r - radius:.4e} m, closed form {r_closed - radius:.4e} m"]),
    ]


def inflated_strip():
    width, length = 0.25, 2.0
    bay = Bay.flat_panel(width=width, length=length, n_span=17, n_contour=129)
    fabric = Fabric()
    sol = solve_equilibrium(Scene(bay, fabric), PRESSURE, PRESTRAIN, rtol=1e-10)
    mid = sol.nodes[:, 64]
    sag = mid[:, 2].max()
    # Elongation along the strip at mid-length, measured on the grid (the bulged ends
    # lengthen the lines, so it exceeds the prestrain; see tests/solver/test_equilibrium.py).
    strain_chord = strip_elongation(sol.nodes, length, PRESTRAIN[1])
    args = (width, PRESSURE, fabric.stiffness_span, fabric.stiffness_chord, fabric.poisson,
            PRESTRAIN[0], strain_chord)
    expected = strip_sag(*args)
    radius = strip_arc_radius(*args)
    centre = np.array([width / 2, expected - radius])
    roundness = np.ptp(np.hypot(mid[:, 1] - centre[0], mid[:, 2] - centre[1])) / expected
    error = abs(sag - expected) / expected
    return Row("Inflated strip: sag", "circular arc: p R = T11 of eq. (10), arc 2 R asin(w/2R)",
               "1% of the sag", f"{error:.2%} (arc roundness {roundness:.2%})",
               error < 0.01 and roundness < 0.01, "17x129 (panel 0.25 x 2 m, aspect 8)",
               details=[(f"sag {sag * 1e3:.4f} mm, closed form {expected * 1e3:.4f} mm, arc radius "
                         f"{radius:.4f} m; elongation along the strip {strain_chord:.5f}")])


def prestressed_panel():
    with jax.enable_x64(True):
        fabric = Fabric(stiffness_span=3e5, stiffness_chord=1e5, poisson=0.3)
        bay = Bay.flat_panel(width=0.3, length=0.7, n_span=6, n_contour=9)
        scene = Scene(bay, fabric)
        physics = scene.physics(dynamic=False)
        params = scene.params(as_parameters(0.0, (0.01, 0.004)))
        ref = fk.prepare(bay.geometry(), params, physics)
        f = fk.forces(ref.nodes, ref, params, physics)
        t11, t22 = fabric_tensions(3e5, 1e5, 0.3, 0.01, 0.004)
        tension_error = max(np.abs(np.asarray(f.tension_span) / t11 - 1).max(),
                            np.abs(np.asarray(f.tension_chord) / t22 - 1).max())
        force = float(jnp.max(jnp.abs(f.total)))
    return [
        Row("Prestressed flat panel: tensions", "eq. (10) with e = prestrain: T11, T22",
            "1e-12 relative (round-off)", f"{tension_error:.1e}", tension_error < 1e-12, "6x9",
            details=[(f"T11 = {t11:.3f} N/m, T22 = {t22:.3f} N/m (E11 3e5, E22 1e5, nu 0.3, "
                      "prestrain 1% / 0.4%, no pressure)")]),
        Row("Prestressed flat panel: at rest", "zero net force on every node", "1e-10 N (round-off "
            "of edge forces ~ 1e2 N)", f"{force:.1e} N", force < 1e-10, "6x9"),
    ]


def _circle_tube(n_span=5, n_contour=20, spacing=0.3):
    contour = np.stack(circle_contour(n_contour, repeat_first=False), axis=-1)
    fixed = np.zeros((n_span, n_contour), bool)
    fixed[0] = fixed[-1] = True
    zeros = np.zeros(n_contour)
    return Bay(contour, contour, zeros, zeros, 0.2, 0.2, spacing, True, fixed, "tube")


def _perturbed(bay, ref, seed, amplitude):
    noise = amplitude * np.random.default_rng(seed).standard_normal(ref.nodes.shape)
    return ref.nodes + jnp.asarray(noise) * (~bay.fixed)[..., None]


def pressure_resultants():
    with jax.enable_x64(True):
        panel = Bay.flat_panel(width=0.3, length=0.7, n_span=6, n_contour=9)
        total = np.asarray(jnp.sum(fk.node_area_vectors(jnp.asarray(panel.nominal_nodes()), False),
                                   axis=(0, 1))) * PRESSURE
        expected = flat_panel_pressure_force(PRESSURE, 0.3, 0.7)
        panel_error = np.abs(total - [0, 0, expected]).max() / expected
        tube = _circle_tube()
        scene = Scene(tube, Fabric())
        params = scene.params(as_parameters(PRESSURE, PRESTRAIN))
        ref = fk.prepare(tube.geometry(), params, scene.physics(dynamic=False))
        x = _perturbed(tube, ref, 0, 0.02)
        area = fk.node_area_vectors(x, True)
        closure = float(safe_norm(jnp.sum(area, axis=(0, 1))) / jnp.sum(safe_norm(area)))
    return [
        Row("Pressure on a flat panel", "p A along the normal (the triangles of eq. 15 tile it)",
            "1e-13 relative (round-off)", f"{panel_error:.1e}", panel_error < 1e-13, "6x9",
            details=[f"sum of nodal forces {total[2]:.6f} N, p A = {expected:.6f} N"]),
        Row("Net pressure force on a closed tube", "zero (a closed surface)",
            "1e-14 of the sum of |nodal forces|", f"{closure:.1e}", closure < 1e-14,
            "5x20 tube, interior nodes moved randomly by 2 cm"),
    ]


def rigid_motion():
    worst_force, worst_tension = 0.0, 0.0
    with jax.enable_x64(True):
        for bay in (Bay.flat_panel(0.3, 0.7, 6, 9), _circle_tube()):
            scene = Scene(bay, Fabric())
            params = scene.params(as_parameters(PRESSURE, PRESTRAIN))
            physics = fk.Physics(bay.periodic, tension_only=True)
            ref = fk.prepare(bay.geometry(), params, physics)
            x = _perturbed(bay, ref, 1, 0.01)
            axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
            k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
            rot = np.eye(3) + np.sin(0.7) * k + (1 - np.cos(0.7)) * k @ k
            moved = x @ jnp.asarray(rot).T + jnp.asarray([0.3, -1.2, 2.0])
            f = fk.forces(x, ref, params, physics)
            g = fk.forces(moved, ref, params, physics)
            scale = float(jnp.max(jnp.abs(f.total)))
            worst_force = max(worst_force, float(np.abs(np.asarray(g.total) - np.asarray(f.total) @ rot.T).max()) / scale)
            tension = np.asarray(f.tension_span)
            worst_tension = max(worst_tension, float(np.abs(np.asarray(g.tension_span) - tension).max()
                                                     / np.abs(tension).max()))
    return Row("Rigid-motion invariance of the forces", "forces rotate with the body, ignore translation",
               "1e-10 of max |F|; tensions 1e-11 of max T11", f"{worst_force:.1e} (tensions {worst_tension:.1e})",
               worst_force < 1e-10 and worst_tension < 1e-11, "6x9 panel, 5x20 tube, rotation 0.7 rad")


# ---------------------------------------------------------- independent checks
def independent_residual():
    fabric = Fabric(stiffness_span=2e5, stiffness_chord=1.5e5, poisson=0.3)
    cases = [
        ("panel 7x21", Bay.flat_panel(width=0.25, length=1.0, n_span=7, n_contour=21), 2e4, (0.005, 0.005)),
        ("NACA 2412 7x32", Bay.from_airfoil(naca("2412"), 1.0, 0.25, n_span=7, n_contour=32), 2e4, (0.005, 0.005)),
        ("NACA 4415 7x32", Bay.from_airfoil(naca("4415"), 0.8, 0.3, n_span=7, n_contour=32), 5e3, (0.01, -0.002)),
    ]
    worst, details = 0.0, []
    for name, bay, pressure, prestrain in cases:
        sol = solve_equilibrium(Scene(bay, fabric), pressure, prestrain, rtol=1e-10)
        relative = numpy_relative_residual(bay, fabric, sol.nodes, pressure, prestrain)
        mounted = numpy_relative_residual(bay, fabric, bay.nominal_nodes(), pressure, prestrain)
        worst = max(worst, relative)
        details.append(f"{name}: numpy residual {relative:.2e} at the JAX equilibrium "
                       f"(JAX {sol.residual:.2e}); {mounted:.2e} at the mounted shape")
    return Row("Independent numpy residual", "cell-by-cell numpy residual of eq. (10), (12)-(15), "
               "no shared code", "1e-10 + 1e-12 (the solve's rtol plus round-off)", f"{worst:.1e}",
               worst < 1e-10 + 1e-12, "7x21, 7x32, 7x32", details=details)


def paper_scheme_invariance():
    panel = Bay.flat_panel(width=0.25, length=1.0, n_span=9, n_contour=33)
    relaxed = solve_equilibrium(Scene(panel, Fabric()), PRESSURE, PRESTRAIN, rtol=1e-11)
    sets = [(0.3, 20.0, 0.02, 0.5), (1.2, 5.0, 0.2, 0.5), (0.3, 20.0, 0.02, 0.25), (0.3, 20.0, 0.02, 0.9)]
    worst, details, ok = 0.0, [], True
    for density, viscosity, aero, courant in sets:
        scene = Scene(panel, Fabric(areal_density=density, viscosity=viscosity), aerodynamic_damping=aero)
        sol = simulate(scene, PressureRamp(PRESSURE, 0.005), PRESTRAIN, courant=courant, rtol=1e-9,
                       max_steps=300_000, throw=False)
        difference = np.abs(sol.nodes - relaxed.nodes).max()
        worst = max(worst, difference)
        ok = ok and sol.converged
        details.append(f"rho0 {density} kg/m^2, eta {viscosity} N s/m, nu_n {aero} s/m, Courant "
                       f"{courant} (dt {sol.extra['dt']:.2e} s): {sol.result.name} in {sol.steps} "
                       f"steps, {difference:.1e} m from the relaxation")
    rows = [Row("Paper scheme vs relaxation: mass, damping, time step",
                "relaxation equilibrium (no mass, no damping)", "1e-7 m (both to rtol 1e-9 or below)",
                f"{worst:.1e} m", ok and worst < 1e-7, "9x33 panel", details=details)]
    bay = Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=9, n_contour=32)
    relaxed = solve_equilibrium(Scene(bay, Fabric()), PRESSURE, PRESTRAIN, rtol=1e-11)
    sol = simulate(Scene(bay, Fabric(viscosity=5.0), aerodynamic_damping=0.05),
                   PressureRamp(PRESSURE, 0.002), PRESTRAIN, rtol=1e-9, max_steps=600_000, throw=False)
    difference = np.abs(sol.nodes - relaxed.nodes).max()
    rows.append(Row("Paper scheme vs relaxation: wing bay", "relaxation equilibrium",
                    "1e-6 chord", f"{difference:.1e} chord", sol.converged and difference < 1e-6,
                    "9x32 NACA 2412",
                    details=[f"{sol.result.name} in {sol.steps} steps of {sol.extra['dt']:.2e} s"]))
    return rows


def _outward_displacement(bay, nodes, row):
    with jax.enable_x64(True):
        x0 = np.asarray(bay.nominal_nodes())
        area = np.asarray(fk.node_area_vectors(jnp.asarray(x0), bay.periodic))
    normal = area / np.linalg.norm(area, axis=-1, keepdims=True)
    return np.sum((nodes[row] - x0[row]) * normal[row], axis=-1)


def grid_convergence():
    grids = [(9, 64), (17, 128), (33, 256)]
    rows, details = [], []
    for n_span, n_contour in grids:
        bay = Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=n_span, n_contour=n_contour)
        sol = solve_equilibrium(Scene(bay, Fabric()), PRESSURE, PRESTRAIN, rtol=1e-10)
        bulge = _outward_displacement(bay, sol.nodes, n_span // 2).max()
        thickness = np.ptp(sol.section(0.5)[:, 1])
        rows.append((bulge, thickness))
        details.append(f"{n_span}x{n_contour}: mid-bay bulge {bulge:.7f} m, thickness {thickness:.7f} m")
    h = np.array([1.0 / g[1] for g in grids])
    orders = []
    for column in np.array(rows).T:
        orders.append(np.polyfit(np.log(h[1:]), np.log(np.abs(np.diff(column))), 1)[0])
    details.append("order fitted to the successive differences (polyfit of log difference on log h)")
    return Row("Grid convergence of the default bay", "successive refinements (no closed form)",
               "fitted order within 0.3 of 2 (bulge) and 1 (thickness)",
               f"bulge {orders[0]:.2f}, thickness {orders[1]:.2f}",
               abs(orders[0] - 2.0) < 0.3 and abs(orders[1] - 1.0) < 0.3, "9x64, 17x128, 33x256",
               details=details)


def starting_shapes():
    bay = Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=9, n_contour=64)
    scene = Scene(bay, Fabric())
    reference = solve_equilibrium(scene, PRESSURE, PRESTRAIN, rtol=1e-11)
    mounted = np.asarray(bay.nominal_nodes())
    i = np.linspace(0, np.pi, bay.n_span)[:, None]
    j = np.linspace(0, 2 * np.pi, bay.n_contour, endpoint=False)[None, :]
    worst, details = 0.0, []
    for sign, modes in ((1.0, (3, 2)), (-1.0, (5, 1))):
        bump = sign * 0.01 * np.sin(i)[..., None] * np.stack(
            [np.sin(modes[0] * j), 0 * j, np.cos(modes[1] * j)], axis=-1)
        sol = solve_equilibrium(scene, PRESSURE, PRESTRAIN, rtol=1e-11,
                                initial=mounted + bump * (~bay.fixed)[..., None])
        difference = np.abs(sol.nodes - reference.nodes).max()
        worst = max(worst, difference)
        details.append(f"start pushed {'out' if sign > 0 else 'in'} by up to 1 cm (modes {modes}): "
                       f"{difference:.1e} m from the cold-start equilibrium")
    return Row("Same equilibrium from different starting shapes", "the cold-start equilibrium "
               "(taut skin: one equilibrium)", "1e-8 chord (solves to rtol 1e-11)", f"{worst:.1e} chord",
               worst < 1e-8, "9x64 NACA 2412", details=details)


def gradients():
    bay = Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=9, n_contour=32)
    scene = Scene(bay)
    theta = Parameters(pressure=2e4, prestrain_span=0.004, prestrain_chord=0.006, stiffness_span=2e5,
                       rib_thickness_scale=0.95).resolved(scene.fabric)
    weights = np.random.default_rng(0).normal(size=(9, 32, 3))

    def solve(q, initial=None):
        return solve_equilibrium(scene, q, rtol=1e-12, method="relax+newton", initial=initial)

    reference = solve(theta)
    with jax.enable_x64(True):
        grad = jax.grad(lambda q: jnp.sum(weights * solve(q, reference).nodes))(theta)
    worst, details = 0.0, []
    for name in PARAMETER_NAMES:
        value = getattr(theta, name)
        h = 1e-4 * abs(value)
        plus = solve(theta.replace(**{name: value + h}), reference).nodes
        minus = solve(theta.replace(**{name: value - h}), reference).nodes
        fd = float(np.sum(weights * (plus - minus)) / (2 * h))
        error = abs(float(getattr(grad, name)) - fd) / abs(fd)
        worst = max(worst, error)
        details.append(f"{name}: implicit {float(getattr(grad, name)):.8e}, central difference {fd:.8e}, "
                       f"relative {error:.1e}")
    return Row("Gradient (adjoint) vs central differences", "central differences, step 1e-4 of each "
               "parameter, solves to rtol 1e-12", "1e-5 relative", f"{worst:.1e}", worst < 1e-5,
               "9x32 NACA 2412", details=details)


def float32_error():
    details, ok, worst = [], True, 0.0
    for n_span, n_contour in [(9, 64), (17, 128), (33, 256)]:
        bay = Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=n_span, n_contour=n_contour)
        scene = Scene(bay, Fabric())
        reference = solve_equilibrium(scene, PRESSURE, PRESTRAIN, rtol=1e-11)
        floor = float32_residual_floor(scene, PRESSURE, PRESTRAIN)
        single = solve_equilibrium(scene, PRESSURE, PRESTRAIN, rtol=floor, method=Relax(precision="float32"),
                                   throw=False)
        stalled, stalled_residual = _float32_stagnation(scene, STAGNATION_STEPS)
        error_at_floor = np.abs(single.nodes - reference.nodes).max() / bay.chord
        error = np.abs(stalled - reference.nodes).max() / bay.chord
        passed = single.converged and single.residual <= floor and error < 1e-5
        ok, worst = ok and passed, max(worst, error)
        details.append(
            f"{n_span}x{n_contour}: floor {floor:.2e}. Asked for rtol = floor, float32 "
            f"{single.result.name} at residual {single.residual:.2e} in {single.steps} steps, "
            f"{error_at_floor:.1e} chord from the float64 equilibrium. Run on for {STAGNATION_STEPS} steps, it "
            f"stalls at residual {stalled_residual:.2e}, {error:.1e} chord from it.")
    details.append("The floor (forces.rounding_residual_floor) bounds the residual that rounding the "
                   "coordinates to float32 can leave; a float32 solve refuses an rtol below it. The "
                   "residual is always evaluated in float64 at the returned nodes.")
    details.append("Shapes: float32 iterated to stagnation lies within the 1e-5 chord accuracy goal "
                   "(docs/architecture.md, Conventions) of the float64 equilibrium, but its residual cannot certify "
                   "it: use float64 (the default) whenever the tolerance matters.")
    details.append(_float32_speed())
    return Row("float32 vs float64", "float64 equilibrium (rtol 1e-11)",
               "float32 converges at rtol = its floor; run to stagnation, within 1e-5 chord",
               f"{worst:.1e} chord at stagnation (worst grid)", ok,
               "9x64, 17x128, 33x256 default bay", details=details)


def _float32_stagnation(scene, steps):
    """Float32 relaxation (half bay) from the mounted shape for ``steps`` steps with an
    unreachable tolerance: the shape float32 stalls at, and its float64 residual."""
    bay = scene.bay
    with jax.enable_x64(True):
        params = scene.params(as_parameters(PRESSURE, PRESTRAIN))
        out, _, nodes = relax_jit(jnp.asarray(bay.nominal_nodes()), bay.geometry(), params,
                                  jnp.asarray(1e-14), jnp.asarray(bay.divergence_bound),
                                  MASS_SAFETY, scene.physics(dynamic=False),
                                  RelaxOptions(steps // 100, half=True, precision="float32", with_forces=False))
        return np.asarray(nodes), float(out.residual)


def _float32_speed() -> str:
    """Time per relaxation step in each precision: same run, alternated, best of 3 after a warm-up."""
    lines = []
    for n_span, n_contour in [(17, 128), (33, 256)]:
        bay = Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=n_span, n_contour=n_contour)
        scene = Scene(bay, Fabric())
        floor = float32_residual_floor(scene, PRESSURE, PRESTRAIN)
        best = {}
        for repeat in range(4):
            for precision in ("float64", "float32"):
                # From the mounted shape, one grid level, to float32's floor (an rtol both accept).
                sol = solve_equilibrium(scene, PRESSURE, PRESTRAIN, rtol=floor, throw=False,
                                        method=Relax(sequencing=False, precision=precision))
                if repeat:  # the first round compiles
                    best[precision] = min(best.get(precision, np.inf), sol.wall_time / sol.steps)
        lines.append(f"{n_span}x{n_contour}: {best['float64'] / best['float32']:.2f}x "
                     f"({best['float64'] * 1e6:.0f} us vs {best['float32'] * 1e6:.0f} us per step)")
    return ("Cost of a relaxation step, float64 over float32 (same run, alternated, best of 3 after "
            "a warm-up): " + "; ".join(lines))


CASES = [long_cylinder, inflated_strip, prestressed_panel, pressure_resultants, rigid_motion,
         independent_residual, paper_scheme_invariance, grid_convergence, starting_shapes, gradients,
         float32_error]


def _header() -> list[str]:
    versions = ", ".join(f"{m.__name__} {m.__version__}" for m in (jax, np, scipy))
    import jaxlib

    return [
        "# Validation report",
        "",
        ("Generated by `python benchmarks/validation_report.py` (do not edit by hand; rerun it). "
         "Every case compares the solver with a closed form from `forward_solver/reference/closed_forms.py` "
         "or an independent check (`forward_solver/reference/independent_residual.py`); the tests in "
         "`tests/` assert the same cases against the same functions and tolerances, on the same "
         "or smaller grids."),
        "",
        f"- Date: {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M UTC}",
        (f"- Machine: {platform.machine()}, {os.cpu_count()} CPU cores, {platform.system()} "
         f"{platform.release()}, JAX devices: {', '.join(str(d) for d in jax.devices())}"),
        f"- Python {platform.python_version()}; {versions}, jaxlib {jaxlib.__version__}",
        ("- Times are wall seconds in one fresh process, JAX compilation included (the first "
         "case on a grid pays it); cases that share one solve split its time."),
        "",
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path,
                        default=Path(__file__).resolve().parent.parent / "docs" / "validation.md")
    args = parser.parse_args()
    rows = []
    for case in CASES:
        new = _timed(case)
        for row in new:
            print(f"{'pass' if row.passed else 'FAIL'}  {row.case}: {row.measured} ({row.seconds:.1f} s)",
                  flush=True)
        rows.extend(new)
    lines = _header()
    passed = sum(r.passed for r in rows)
    lines += [f"**{passed} of {len(rows)} cases pass.**", "",
              "| case | reference | tolerance | measured | pass | grid | time (s) |",
              "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        cells = [r.case, r.reference, r.tolerance, r.measured, "yes" if r.passed else "**no**",
                 r.grid, f"{r.seconds:.1f}"]
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    lines += ["", "## Details", ""]
    for r in rows:
        if r.details:
            lines.append(f"### {r.case}")
            lines.append("")
            lines += [f"- {d}" for d in r.details]
            lines.append("")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines))
    print(f"wrote {args.out}")
    sys.exit(0 if passed == len(rows) else 1)


if __name__ == "__main__":
    main()
