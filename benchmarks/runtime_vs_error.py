"""Run time against mid-bay shape error for every equilibrium method.

Case: the default wing bay, NACA 2412 ribs, chord 1 m, rib spacing 0.25 m,
fabric stiffness 2e5 N/m both ways, Poisson 0.25, prestrain 0.5% both ways,
inflated to 5, 20 and 50 kPa.

Methods:

* ``paper``: the paper's physical-mass explicit scheme (`simulate`,
  eq. 14/16/17) with light viscosity (5 N s/m) and aerodynamic damping
  (0.05 s/m) so that it comes to rest, pressure ramped over 2 ms. Its step
  is set by the CFL condition on the smallest (leading-edge) cell, so it only
  runs on coarse grids and under a step cap.
* ``relax``: dynamic relaxation with Gershgorin masses, kinetic damping,
  grid sequencing and half-bay symmetry (`solve_equilibrium`, default).
* ``relax+newton``: relaxation to a relative residual of 1e-5, then sparse
  Newton.

Tolerance ``rtol`` is the same stop test for all methods: the 2-norm of the
static force residual on the free nodes over the pressure times the nominal
skin area, ``||R_free|| / (p A) <= rtol`` (the paper scheme must in addition
be at rest, see `explicit.kinetic_rest_threshold`).

Mid-bay shape error (column ``error``, in fractions of chord):
    The mid-bay section is the grid row at ``y = rib_spacing / 2`` (odd
    ``n_span``), an (x, z) curve. Its error is the largest *normal* distance
    from any of the grid's mid-bay nodes to the reference mid-bay curve,
    divided by the chord. The distance to the curve, not to a matched
    reference point, is used so that nodes sliding along the surface (which
    leaves the shape unchanged) do not count as error. The reference curve is
    a cubic spline through the reference points in the contour parameter
    ``s = j / n_contour`` (the trailing-edge node at both ends, ``s = 0`` and
    ``s = 1``; it is a fixed seam with a corner, so the spline is not made
    periodic across it); the foot of the normal is found by Newton's method
    on ``(C(s) - p) . C'(s) = 0`` started at the node's own ``s``.

Reference (never the method being measured):
    Grids of a nested sequence (each halves both spacings of the previous
    one; node ``j`` of ``n_contour`` sits at the cosine station
    ``2 pi j / n_contour``, so node ``j`` of one grid is node ``2 j`` of the
    next and mid-bay nodes coincide) are solved with relax+newton to
    ``rtol = 1e-11`` (if relaxation stalls on a grid, plain Newton started
    from the interpolated previous grid's solution). The full run uses
    17x128, 33x256, 65x512, so every table grid (up to 33x256) is measured
    against a reference built from finer grids than itself. The quantity
    extrapolated is the (x, z) position of
    the mid-bay nodes. The observed order ``p`` is fitted from the three
    finest grids at the stations they share,
    ``p = log2(max|Q1 - Q2| / max|Q2 - Q3|)``, and the reference is
    ``Q3 + (Q3 - Q2) / (2^p - 1)`` at the stations shared by the two finest
    grids. Printed with it: ``p``, the size of the Richardson correction
    (an error estimate of the finest grid), the change in the reference if
    ``p = 2`` were used instead of the fitted one, and the spline
    interpolation floor (the error the finest grid's own nodes show against
    a spline through its shared stations only) -- errors near these numbers
    are not resolved.

Timing:
    ``solve_s`` is the median wall time of ``repeats`` calls after a warm-up
    call (only the first row of each (method, grid) group needs the warm-up:
    pressure and rtol are traced, so later rows run compiled code and all
    their calls are timed), each measured with ``time.perf_counter`` around the whole public
    call, which blocks until its results are NumPy arrays (the solvers call
    ``jax.block_until_ready`` inside). ``compile_s`` is the first-call wall
    time minus that warm median, for each (method, grid) after
    ``jax.clear_caches()``, so it counts everything the method compiles on
    that grid, coarse sequencing levels included (in a fresh process, the
    first call costs ``compile_s + solve_s``). It is reported on the row
    that made the first call and repeated for the others of that (method,
    grid) group. Relaxation runs are capped at ``relax_max_steps`` per grid
    level (it stalls on some grids, see the table's ``step cap`` rows); a
    capped run is timed once and the tighter tolerances of that (method,
    grid, pressure) are marked ``skipped``. ``--quick`` does not clear the caches (the reference solves
    have compiled the shared kernels), so there it counts only new
    compilation. Runs of the paper scheme longer than ``LONG_RUN_S`` get one
    timed repeat.

Also reported, each measured in this one run:
    (a) paper scheme vs relax on a coarse grid at 20 kPa to the same
        tolerance: largest node difference (chord fractions) and speed ratio
        (a lower bound if the paper scheme hits its step cap);
    (b) the fastest grid/method/tolerance reaching 1e-4 and 1e-5 chord
        mid-bay error at 20 kPa, with its solve time;
    (c) warm start after a 1% pressure rise vs a cold start (relax and
        relax+newton), steps and time.

Outputs: a fixed-width table on stdout, ``benchmarks/results/
runtime_vs_error.csv`` and ``runtime_vs_error.png`` (solve time against
error, log-log, one curve per method: the fastest time reaching each error,
the other runs as faint markers). ``--quick`` runs coarse grids only (9x64,
paper scheme on 9x32 with a 20k-step cap), 20 kPa, one repeat, with a coarse
reference (5x32, 9x64, 17x128): its errors are indicative only; it checks
that everything runs (about a minute, for CI). The table and the three
comparisons are also saved as ``benchmarks/results/runtime_vs_error.json``
(``runtime_vs_error_quick.json`` with ``--quick``) for
``benchmarks/performance_doc.py``.

Usage::

    PYTHONPATH=. python benchmarks/runtime_vs_error.py [--quick]
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import platform
import statistics
import time
from pathlib import Path

import jax
import matplotlib
import matplotlib.ticker

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.interpolate import CubicSpline  # noqa: E402

import sys  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.results import save_result  # noqa: E402
from forward_solver import Bay, Fabric, PressureRamp, Scene, simulate, solve_equilibrium  # noqa: E402
from targets import naca  # noqa: E402

# ----------------------------------------------------------------- the case
AIRFOIL = "2412"
CHORD = 1.0  # m
RIB_SPACING = 0.25  # m
FABRIC = Fabric(stiffness_span=2e5, stiffness_chord=2e5, poisson=0.25)
PRESTRAIN = (0.005, 0.005)
#: Dynamic terms for the paper scheme only (they do not change the equilibrium).
PAPER_VISCOSITY = 5.0  # N s/m
PAPER_AERODYNAMIC_DAMPING = 0.05  # s/m
PAPER_RAMP_TIME = 0.002  # s
DEFAULT_PRESSURE = 2e4  # Pa

#: Runs longer than this (s) are timed once after the warm-up.
LONG_RUN_S = 5.0

FULL = dict(
    pressures=(5e3, 2e4, 5e4),
    grids={
        "relax": [(9, 64), (9, 128), (17, 128), (17, 256), (33, 128), (33, 256)],
        "relax+newton": [(9, 64), (9, 128), (17, 128), (17, 256), (33, 128), (33, 256)],
        "paper": [(9, 32), (9, 64)],
    },
    tolerances={"relax": (1e-4, 1e-6, 1e-8), "relax+newton": (1e-4, 1e-6, 1e-8, 1e-10),
                "paper": (1e-4, 1e-6)},
    paper_max_steps=100_000,
    relax_max_steps=20_000,
    reference_grids=[(17, 128), (33, 256), (65, 512)],
    reference_method=("relax+newton", 1e-11),
    repeats=3,
    clear_caches=True,
    comparison_grid=(9, 32),
    comparison_rtol=1e-8,
    comparison_max_steps=1_000_000,
    warm_grid=(17, 128),
)
QUICK = dict(
    pressures=(2e4,),
    grids={"relax": [(9, 64)], "relax+newton": [(9, 64)], "paper": [(9, 32)]},
    tolerances={"relax": (1e-4, 1e-8), "relax+newton": (1e-8,), "paper": (1e-4,)},
    paper_max_steps=20_000,
    relax_max_steps=10_000,
    reference_grids=[(5, 32), (9, 64), (17, 128)],
    reference_method=("relax", 1e-10),  # no Newton compile on three extra shapes
    repeats=1,
    clear_caches=False,
    comparison_grid=(9, 32),
    comparison_rtol=1e-4,
    comparison_max_steps=20_000,
    warm_grid=(9, 64),
)

RESULTS = Path(__file__).resolve().parent / "results"


# ----------------------------------------------------------------- helpers
def make_scene(grid, paper=False) -> Scene:
    bay = Bay.from_airfoil(naca(AIRFOIL), chord=CHORD, rib_spacing=RIB_SPACING, n_span=grid[0],
                           n_contour=grid[1])
    if paper:
        fabric = Fabric(stiffness_span=FABRIC.stiffness_span, stiffness_chord=FABRIC.stiffness_chord,
                        poisson=FABRIC.poisson, viscosity=PAPER_VISCOSITY)
        return Scene(bay, fabric, aerodynamic_damping=PAPER_AERODYNAMIC_DAMPING)
    return Scene(bay, FABRIC)


def run_method(method, scene, pressure, rtol, max_steps=None, initial=None):
    """One solve; returns the `Solution` (never raises on non-convergence)."""
    if method == "paper":
        return simulate(scene, PressureRamp(pressure, PAPER_RAMP_TIME), PRESTRAIN, rtol=rtol,
                        max_steps=max_steps, initial=initial, throw=False)
    kwargs = {} if max_steps is None else {"max_steps": max_steps}
    return solve_equilibrium(scene, pressure, PRESTRAIN, rtol=rtol, method=method,
                             initial=initial, throw=False, **kwargs)


def timed(fn):
    start = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - start


def warm_times(fn, repeats):
    """Median wall time of ``repeats`` calls (one if a call exceeds `LONG_RUN_S`), and the count."""
    times = [timed(fn)[1]]
    if times[0] <= LONG_RUN_S:
        times += [timed(fn)[1] for _ in range(repeats - 1)]
    return statistics.median(times), len(times)


def mid_row(nodes) -> np.ndarray:
    """Mid-bay (x, z) of an odd-``n_span`` grid, ``(n_contour, 2)`` m."""
    ns = nodes.shape[0]
    assert ns % 2 == 1, "mid-bay must be a grid row"
    return nodes[(ns - 1) // 2][:, [0, 2]]


def prolong(u: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of a nodal field to the nested grid (periodic contour)."""
    ns, nc = u.shape[:2]
    mid = 0.5 * (u + np.roll(u, -1, axis=1))
    rows = np.stack([u, mid], axis=2).reshape(ns, 2 * nc, 3)
    mid_rows = 0.5 * (rows[:-1] + rows[1:])
    out = np.stack([rows[:-1], mid_rows], axis=1).reshape(2 * (ns - 1), 2 * nc, 3)
    return np.concatenate([out, rows[-1:]], axis=0)


# --------------------------------------------------------------- reference
class ReferenceCurve:
    """The Richardson-extrapolated mid-bay section and the normal-distance error."""

    def __init__(self, points: np.ndarray):
        n = points.shape[0]
        closed = np.concatenate([points, points[:1]], axis=0)  # TE node at s = 0 and s = 1
        self.n = n
        self.spline = CubicSpline(np.linspace(0.0, 1.0, n + 1), closed, axis=0)
        self.d1 = self.spline.derivative(1)
        self.d2 = self.spline.derivative(2)

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Normal distance (m) of each mid-bay node (contour order) to the curve."""
        s = np.arange(points.shape[0]) / points.shape[0]
        for _ in range(8):
            r = self.spline(s) - points
            t = self.d1(s)
            g = np.sum(r * t, axis=1)
            dg = np.sum(t * t, axis=1) + np.sum(r * self.d2(s), axis=1)
            s = np.clip(s - g / dg, 0.0, 1.0)
        return np.linalg.norm(self.spline(s) - points, axis=1)

    def error(self, nodes) -> float:
        """Mid-bay shape error in chord fractions."""
        return float(np.max(self.distance(mid_row(nodes)))) / CHORD


def reference_solutions(pressure, grids, reference_method, max_steps, log):
    """Mid-bay rows of the reference grids, tightly solved."""
    method, rtol = reference_method
    rows = []
    previous = None
    for grid in grids:
        scene = make_scene(grid)
        sol, wall = timed(lambda: solve_equilibrium(scene, pressure, PRESTRAIN, rtol=rtol,
                                                    method=method, max_steps=max_steps, throw=False))
        how = f"{method} to rtol {rtol:.0e}"
        if not sol.converged and previous is not None:
            # Relaxation stalls on the finest grid (reported); plain Newton
            # from the interpolated previous grid converges.
            coarse_scene, coarse_nodes = previous
            x0 = scene.bay.nominal_nodes() + prolong(
                coarse_nodes - coarse_scene.bay.nominal_nodes()) * (~scene.bay.fixed)[..., None]
            sol, wall = timed(lambda: solve_equilibrium(scene, pressure, PRESTRAIN,
                                                        rtol=rtol, method="newton",
                                                        initial=x0, throw=False))
            how = "newton from interpolated coarser grid"
        if not sol.converged:
            raise RuntimeError(f"reference solve failed on {grid}: {sol.message}")
        log(f"  reference {grid[0]}x{grid[1]} at {pressure / 1e3:g} kPa: {how}, "
            f"residual {sol.residual:.1e}, {wall:.1f} s")
        rows.append(mid_row(sol.nodes))
        previous = (scene, sol.nodes)
    return rows


def richardson(rows):
    """Observed order and extrapolated mid-bay points from nested-grid rows."""
    q1, q2, q3 = rows[-3], rows[-2], rows[-1]
    n = q1.shape[0]
    a = q1
    b = q2[:: q2.shape[0] // n]
    c = q3[:: q3.shape[0] // n]
    order = math.log2(np.max(np.abs(a - b)) / np.max(np.abs(b - c)))
    fine = q3[:: q3.shape[0] // q2.shape[0]]
    correction = (fine - q2) / (2.0 ** order - 1.0)
    points = fine + correction
    points_p2 = fine + (fine - q2) / 3.0
    curve = ReferenceCurve(points)
    info = {
        "order": order,
        "correction": float(np.max(np.linalg.norm(correction, axis=1))) / CHORD,
        "order_sensitivity": float(np.max(np.linalg.norm(points - points_p2, axis=1))) / CHORD,
        "spline_floor": float(np.max(ReferenceCurve(fine).distance(q3))) / CHORD,
        "stations": points.shape[0],
    }
    return curve, info


# -------------------------------------------------------------------- table
COLUMNS = [("method", "<12", "{}"), ("pressure_kPa", ">6", "{:g}"), ("grid", ">7", "{}"),
           ("rtol", ">7", "{:.0e}"), ("result", "<9", "{}"), ("steps", ">7", "{}"),
           ("residual", ">8", "{:.1e}"), ("compile_s", ">9", "{:.2f}"),
           ("solve_s", ">8", "{:.4f}"), ("repeats", ">3", "{}"), ("error_chord", ">11", "{:.2e}")]
HEADERS = {"pressure_kPa": "kPa", "repeats": "n", "error_chord": "error/c"}


def format_row(row) -> str:
    out = []
    for key, fmt, spec in COLUMNS:
        value = row[key]
        text = spec.format(value) if value is not None else "-"
        out.append(format(text, fmt))
    return "  ".join(out)


def header() -> str:
    return "  ".join(format(HEADERS.get(k, k), fmt) for k, fmt, _ in COLUMNS)


# --------------------------------------------------------------- the parts
def benchmark_table(cfg, references, log):
    rows = []
    log("\n" + header())
    for method in ("relax", "relax+newton", "paper"):
        for grid in cfg["grids"][method]:
            paper = method == "paper"
            scene = make_scene(grid, paper=paper)
            max_steps = cfg["paper_max_steps"] if paper else cfg["relax_max_steps"]
            pressures = cfg["pressures"]
            if cfg["clear_caches"]:
                jax.clear_caches()
            compile_s = None
            for pressure in pressures:
                stalled = False
                for rtol in cfg["tolerances"][method]:
                    if stalled:
                        # A tighter tolerance cannot succeed where a looser one hit the cap.
                        rows.append(skipped_row(method, pressure, grid, rtol, compile_s))
                        log(format_row(rows[-1]))
                        continue

                    def call():
                        return run_method(method, scene, pressure, rtol, max_steps)
                    if compile_s is None:
                        # First call of the group compiles: it is the warm-up.
                        sol, first_s = timed(call)
                        solve_s, n = warm_times(call, 1 if not sol.converged else cfg["repeats"])
                        compile_s = max(first_s - solve_s, 0.0)
                    else:
                        # Already compiled (pressure and rtol are traced): every call is timed.
                        sol, first_s = timed(call)
                        times = [first_s]
                        if first_s <= LONG_RUN_S and sol.converged:
                            times += [timed(call)[1] for _ in range(cfg["repeats"] - 1)]
                        solve_s, n = statistics.median(times), len(times)
                    row = {
                        "method": method, "pressure_kPa": pressure / 1e3,
                        "grid": f"{grid[0]}x{grid[1]}", "rtol": rtol,
                        "result": sol.result.name if not sol.converged else "converged",
                        "steps": sol.steps, "residual": sol.residual, "compile_s": compile_s,
                        "solve_s": solve_s, "repeats": n,
                        "error_chord": references[pressure][0].error(sol.nodes),
                    }
                    if row["result"] == "max_steps_reached":
                        row["result"] = "step cap"
                        stalled = method != "paper"
                    rows.append(row)
                    log(format_row(row))
    return rows


def skipped_row(method, pressure, grid, rtol, compile_s):
    return {"method": method, "pressure_kPa": pressure / 1e3, "grid": f"{grid[0]}x{grid[1]}",
            "rtol": rtol, "result": "skipped", "steps": None, "residual": None,
            "compile_s": compile_s, "solve_s": None, "repeats": 0, "error_chord": None}


def compare_paper(cfg, log):
    """(a) paper scheme vs relax to the same tolerance on a coarse grid at 20 kPa."""
    grid, rtol = cfg["comparison_grid"], cfg["comparison_rtol"]
    pressure = DEFAULT_PRESSURE
    paper_scene, relax_scene = make_scene(grid, paper=True), make_scene(grid)
    paper, paper_first = timed(lambda: run_method("paper", paper_scene, pressure, rtol,
                                                  cfg["comparison_max_steps"]))
    relax_call = lambda: run_method("relax", relax_scene, pressure, rtol)  # noqa: E731
    relax, _ = timed(relax_call)
    relax_s, _ = warm_times(relax_call, max(cfg["repeats"], 3))
    paper_s, _ = warm_times(lambda: run_method("paper", paper_scene, pressure, rtol,
                                               cfg["comparison_max_steps"]), cfg["repeats"])
    tight = run_method(*cfg["reference_method"][:1], relax_scene, pressure,
                       cfg["reference_method"][1], max_steps=1_000_000)
    diff = float(np.max(np.linalg.norm(paper.nodes - relax.nodes, axis=-1))) / CHORD
    paper_err = float(np.max(np.linalg.norm(paper.nodes - tight.nodes, axis=-1))) / CHORD
    relax_err = float(np.max(np.linalg.norm(relax.nodes - tight.nodes, axis=-1))) / CHORD
    reached = paper.converged
    g = f"{grid[0]}x{grid[1]}"
    log(f"\n(a) paper scheme vs relax, {g}, 20 kPa, rtol {rtol:.0e}:")
    log(f"    paper: {paper.result.name}, {paper.steps} steps (dt {paper.extra['dt']:.2e} s), "
        f"residual {paper.residual:.2e}, {paper_s:.3f} s warm")
    log(f"    relax: {relax.result.name}, {relax.steps} steps, residual {relax.residual:.2e}, "
        f"{relax_s:.4f} s warm")
    log(f"    largest node difference paper - relax: {diff:.2e} chord "
        f"({'below' if diff < 1e-6 else 'ABOVE'} 1e-6); against a {cfg['reference_method'][0]} solve to "
        f"rtol {cfg['reference_method'][1]:.0e} on the same grid: "
        f"paper {paper_err:.2e}, relax {relax_err:.2e} chord")
    ratio = paper_s / relax_s
    if reached:
        log(f"    speed ratio paper / relax: {ratio:.0f}x")
        ratio_note = "ratio"
    else:
        log(f"    paper scheme did NOT reach rtol {rtol:.0e} within {paper.steps} steps; "
            f"its final residual is {paper.residual:.2e}.")
        # Paper took paper_s and still had not reached rtol; relax reached it in
        # relax_s: paper_s / relax_s bounds the ratio at rtol from below.
        log(f"    LOWER BOUND on the speed ratio at rtol {rtol:.0e}: paper time to its final "
            f"residual / relax time to rtol = {paper_s:.3f} / {relax_s:.4f} = {ratio:.0f}x "
            f"(at least)")
        relax_same = lambda: run_method("relax", relax_scene, pressure,  # noqa: E731
                                        min(max(paper.residual, 1e-12), 0.5))
        relax_same_s, _ = warm_times(relax_same, max(cfg["repeats"], 3))
        log(f"    at equal residual {paper.residual:.1e}: paper {paper_s:.3f} s / relax "
            f"{relax_same_s:.4f} s = {paper_s / relax_same_s:.0f}x")
        ratio_note = "lower bound"
    return {"grid": g, "rtol": rtol, "paper_result": paper.result.name, "paper_steps": paper.steps,
            "paper_residual": paper.residual, "paper_s": paper_s, "relax_s": relax_s,
            "node_difference_chord": diff, "ratio": ratio, "ratio_kind": ratio_note}


def accuracy_targets(rows, log):
    """(b) fastest run reaching 1e-4 and 1e-5 chord error at 20 kPa."""
    log("\n(b) fastest run to a mid-bay error target at 20 kPa (relax, relax+newton):")
    out = {}
    for target, budget in ((1e-4, 0.25), (1e-5, 3.0)):
        hits = [r for r in rows if r["pressure_kPa"] == DEFAULT_PRESSURE / 1e3
                and r["method"] != "paper" and r["result"] == "converged"
                and r["error_chord"] <= target]
        if not hits:
            log(f"    {target:.0e} chord: no grid in this run reaches it")
            out[target] = None
            continue
        best = min(hits, key=lambda r: r["solve_s"])
        verdict = "meets" if best["solve_s"] < budget else "MISSES"
        log(f"    {target:.0e} chord: {best['grid']} {best['method']} rtol {best['rtol']:.0e}, "
            f"error {best['error_chord']:.2e}, {best['solve_s']:.3f} s "
            f"({verdict} the {budget:g} s target)")
        out[target] = best
    return out


def warm_start(cfg, log):
    """(c) warm start after a 1% pressure rise vs a cold start."""
    grid = cfg["warm_grid"]
    scene = make_scene(grid)
    p0, p1, rtol = DEFAULT_PRESSURE, 1.01 * DEFAULT_PRESSURE, 1e-8
    log(f"\n(c) warm start, {grid[0]}x{grid[1]}, {p0 / 1e3:g} -> {p1 / 1e3:g} kPa, rtol {rtol:.0e}:")
    out = []
    for method in ("relax", "relax+newton"):
        base = run_method(method, scene, p0, rtol)
        cold_call = lambda: run_method(method, scene, p1, rtol)  # noqa: E731
        warm_call = lambda: run_method(method, scene, p1, rtol, initial=base)  # noqa: E731
        cold, cold_first = timed(cold_call)
        warm, warm_first = timed(warm_call)
        cold_s, _ = warm_times(cold_call, max(cfg["repeats"], 3))
        warm_s, _ = warm_times(warm_call, max(cfg["repeats"], 3))
        diff = float(np.max(np.linalg.norm(cold.nodes - warm.nodes, axis=-1))) / CHORD
        log(f"    {method:<12} cold {cold.steps:>5} steps {cold_s:.4f} s | warm {warm.steps:>5} "
            f"steps {warm_s:.4f} s | speed-up {cold_s / warm_s:.1f}x | "
            f"max node difference {diff:.1e} chord")
        out.append({"method": method, "cold_steps": cold.steps, "cold_s": cold_s,
                    "warm_steps": warm.steps, "warm_s": warm_s})
    return out


# ------------------------------------------------------------------- plot
def pareto(points):
    """Fastest time reaching each error level: (error, time) sorted by time."""
    front, best = [], math.inf
    for t, e in sorted(points):
        if e < best:
            front.append((e, t))
            best = e
    return front


def plot(rows, path, title_extra):
    pressures = sorted({float(r["pressure_kPa"]) for r in rows})
    fig, axes = plt.subplots(1, len(pressures), figsize=(max(7.8, 5.2 * len(pressures)), 4.8),
                             squeeze=False, sharey=True)
    styles = {"paper": ("tab:red", "s"), "relax": ("tab:blue", "o"),
              "relax+newton": ("tab:green", "^")}
    for ax, p in zip(axes[0], pressures):
        for method, (colour, marker) in styles.items():
            mine = [r for r in rows if float(r["pressure_kPa"]) == p and r["method"] == method]
            if not mine:
                continue
            pts = [(float(r["solve_s"]), float(r["error_chord"])) for r in mine
                   if r["result"] == "converged"]
            capped = [(float(r["solve_s"]), float(r["error_chord"])) for r in mine
                      if r["result"] not in ("converged", "skipped")]
            name = label = method if method != "paper" else "paper (physical mass)"
            if pts:
                t, e = zip(*pts)
                ax.scatter(e, t, color=colour, marker=marker, alpha=0.25, s=18)
                front = pareto(pts)
                ax.plot([f[0] for f in front], [f[1] for f in front], color=colour,
                        marker=marker, label=label)
                label = None
            if capped:
                t, e = zip(*capped)
                ax.scatter(e, t, facecolors="none", edgecolors=colour, marker=marker, s=40,
                           label=name + ", step cap (not converged)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel("mid-bay shape error (fraction of chord)")
        ax.set_title(f"{p:g} kPa")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("solve time after warm-up (s)")
    handles = {}
    for ax in axes[0]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(lab, h)
    fig.legend(handles.values(), handles.keys(), loc="lower center", ncol=min(5, len(handles)),
               fontsize=8, frameon=False)
    fig.suptitle(f"Solve time vs mid-bay shape error, NACA {AIRFOIL} bay (chord {CHORD:g} m, "
                 f"rib spacing {RIB_SPACING:g} m){title_extra}\nlines: fastest converged run "
                 f"reaching each error; faint: all runs", fontsize=10)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ------------------------------------------------------------------ record
def save_record(rows, comparison, targets, warm, references, quick):
    """The table and the three comparisons as one result file (``benchmarks/results.py``)."""
    def cell(value, spec):
        return None if value is None else spec.format(value)

    table = [[r["method"], r["pressure_kPa"], r["grid"], cell(r["rtol"], "{:.0e}"), r["result"], r["steps"],
              cell(r["residual"], "{:.1e}"), cell(r["compile_s"], "{:.2f}"), cell(r["solve_s"], "{:.4f}"),
              r["repeats"], cell(r["error_chord"], "{:.2e}")] for r in rows]
    notes = [f"Default bay (NACA {AIRFOIL}, chord {CHORD:g} m, ribs {RIB_SPACING:g} m apart, prestrain "
             f"{PRESTRAIN[0]:.1%} span, {PRESTRAIN[1]:.1%} chord); error: the largest normal distance of the mid-bay nodes from a reference "
             "mid-bay curve Richardson-extrapolated from finer grids, in fractions of chord (the module "
             "docstring defines every column); solve s: median of warm calls; compile s: first call "
             "minus that median."]
    for pressure, (_, info) in sorted(references.items()):
        notes.append(f"Reference at {pressure / 1e3:g} kPa: observed order {info['order']:.2f}, Richardson "
                     f"correction {info['correction']:.1e} chord, spline floor {info['spline_floor']:.1e} "
                     "(errors near these are not resolved).")
    c = comparison
    notes.append(f"Paper's scheme against relaxation, {c['grid']}, rtol {c['rtol']:.0e}: paper "
                 f"{c['paper_result']} after {c['paper_steps']} steps in {c['paper_s']:.3f} s, relaxation "
                 f"{c['relax_s']:.4f} s ({c['ratio_kind']} {c['ratio']:.0f}x); largest node difference "
                 f"{c['node_difference_chord']:.1e} chord.")
    for target, best in targets.items():
        notes.append(f"Fastest run to {target:.0e} chord mid-bay error at {DEFAULT_PRESSURE / 1e3:g} kPa: "
                     + ("none in this run" if best is None else
                        f"{best['method']} {best['grid']} rtol {best['rtol']:.0e}, error "
                        f"{best['error_chord']:.2e} in {best['solve_s']:.4f} s"))
    for w in warm:
        notes.append(f"Warm start after +1% pressure, {w['method']}: {w['warm_steps']} steps, {w['warm_s']:.4f} s "
                     f"against {w['cold_steps']} steps, {w['cold_s']:.4f} s cold "
                     f"({w['cold_s'] / w['warm_s']:.1f}x).")
    if quick:
        notes.append("--quick: coarse grids, one repeat and a coarse reference: the errors are indicative only.")
    return save_result("runtime_vs_error_quick" if quick else "runtime_vs_error",
                       title="Solve time against mid-bay error" + (" (quick run)" if quick else ""),
                       command="python benchmarks/runtime_vs_error.py" + (" --quick" if quick else ""),
                       columns=["method", "pressure, kPa", "grid", "rtol", "result", "steps", "residual",
                                "compile, s", "solve, s", "repeats", "mid-bay error, chord"],
                       rows=table, notes=notes)


# -------------------------------------------------------------------- main
def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="coarse grids, 20 kPa, one repeat (CI-sized, under a minute)")
    parser.add_argument("--out", type=Path, default=RESULTS, help="folder for the CSV and PNG")
    parser.add_argument("--replot", action="store_true",
                        help="only redraw the PNG from the CSV in --out")
    args = parser.parse_args(argv)
    cfg = QUICK if args.quick else FULL
    if args.replot:
        with open(args.out / "runtime_vs_error.csv") as fh:
            plot(list(csv.DictReader(fh)), args.out / "runtime_vs_error.png",
                 " (--quick)" if args.quick else "")
        return None
    start = time.perf_counter()

    def log(text):
        print(text, flush=True)

    machine = (f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPU cores, "
               f"{jax.default_backend()} backend, jax {jax.__version__}, Python "
               f"{platform.python_version()}")
    log(f"runtime_vs_error{' --quick' if args.quick else ''}: {machine}")
    log(f"Reference: Richardson extrapolation over grids "
        f"{', '.join(f'{a}x{b}' for a, b in cfg['reference_grids'])} "
        f"({cfg['reference_method'][0]}, rtol {cfg['reference_method'][1]:.0e})")
    references = {}
    for pressure in cfg["pressures"]:
        rows = reference_solutions(pressure, cfg["reference_grids"], cfg["reference_method"],
                                   cfg["relax_max_steps"], log)  # same cap: shares compiled loops
        curve, info = richardson(rows)
        references[pressure] = (curve, info)
        log(f"  {pressure / 1e3:g} kPa: observed order {info['order']:.2f}; Richardson correction "
            f"{info['correction']:.1e} chord; change if order 2 were used {info['order_sensitivity']:.1e}; "
            f"spline floor {info['spline_floor']:.1e}; {info['stations']} stations")

    rows = benchmark_table(cfg, references, log)
    comparison = compare_paper(cfg, log)
    targets = accuracy_targets(rows, log)
    warm = warm_start(cfg, log)

    args.out.mkdir(parents=True, exist_ok=True)
    csv_path = args.out / "runtime_vs_error.csv"
    with open(csv_path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=[k for k, _, _ in COLUMNS])
        writer.writeheader()
        writer.writerows(rows)
    png_path = args.out / "runtime_vs_error.png"
    plot(rows, png_path, " (--quick)" if args.quick else "")
    json_path = save_record(rows, comparison, targets, warm, references, args.quick)
    log(f"\nwrote {csv_path}, {png_path} and {json_path}; total {time.perf_counter() - start:.0f} s on {machine}")
    return {"rows": rows, "comparison": comparison, "targets": targets, "warm": warm,
            "references": {p: info for p, (_, info) in references.items()}}


if __name__ == "__main__":
    main()
