"""Reports of a design: plots, surface files and the output folder (DESIGN section 7).

`write_report` turns a `DesignResult` (or a single equilibrium `Solution`)
into a folder::

    summary.json          inputs, results, errors before and after, constraints,
                          timings, package version, the files written
    equilibrium.npz       nodes, tensions, wrinkled cells, deviation, target, parameters
    skin.obj, skin.stl    the equilibrium skin as a mesh (metres)
    mid_bay_section.png   the mid-bay section against the rib and the target,
                          deviations magnified (`plot_section`)
    deviation.png         the deviation from the target over the whole bay (`plot_deviation`)
    tensions.png          fibre tensions with the wrinkled cells marked (`plot_tensions`)
    history.png           the optimiser's iterates (`plot_history`; skipped for a
                          single equilibrium)

The folder is written atomically (`staged_folder`): into a hidden temporary
folder next to the destination, renamed into place when complete. An
earlier folder of the same name is replaced only then, and only if it is
empty or holds a ``summary.json`` (so a mistyped ``out_dir`` never deletes
unrelated files).

The ``plot_*`` functions return `matplotlib.figure.Figure` objects built
without pyplot (no global state, an Agg canvas), so they serve notebooks and
scripts as well as the command line. Maps of the whole bay are drawn on the
developed skin: the horizontal axis is the distance along the rib contour
from the trailing edge over the upper surface, the leading edge and the
lower surface (Selig order), with x/chord marked on the top axis.
"""

from __future__ import annotations

import json
import math
import os
import platform
import shutil
import tempfile
import time
import uuid
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from forward_solver import Solution

from .objectives import design_errors, section_errors
from .optimise import DesignResult

__all__ = [
    "REPORT_FILES",
    "auto_magnification",
    "check_output_folder",
    "deviation",
    "plot_deviation",
    "plot_history",
    "plot_section",
    "plot_tensions",
    "staged_folder",
    "summarise",
    "write_npz",
    "write_obj",
    "write_report",
    "write_stl",
]

#: Files `write_report` writes, in order (``history.png`` only for an optimisation).
REPORT_FILES = ("equilibrium.npz", "skin.obj", "skin.stl", "mid_bay_section.png", "deviation.png",
                "tensions.png", "history.png", "summary.json")

#: Largest magnified deviation in the section plot, fraction of chord
#: (`auto_magnification` picks the largest 1-2-5 factor that stays below it).
MAGNIFIED_DEVIATION = 0.1

_DPI = 150
_TARGET_STYLE = dict(color="black", lw=1.4)
_RIB_STYLE = dict(color="C0", lw=1.4)
_SKIN_STYLE = dict(color="C3", lw=1.6)


# ------------------------------------------------------------------ inputs
def _unpack(result) -> tuple[Solution, DesignResult | None]:
    if isinstance(result, DesignResult):
        return result.solution, result
    if isinstance(result, Solution):
        return result, None
    raise TypeError(f"expected an inverse_design.DesignResult or a forward_solver.Solution, "
                    f"got {type(result).__name__}")


def _parameter_values(solution: Solution, result: DesignResult | None, values: dict | None) -> dict:
    """Pressure, prestrain and rib scales of the reported equilibrium."""
    merged = {"pressure": float(solution.pressure), "prestrain_span": float(solution.prestrain[0]),
              "prestrain_chord": float(solution.prestrain[1]), "rib_thickness_scale": 1.0,
              "rib_chord_scale": 1.0}
    if result is not None:
        merged.update({k: float(v) for k, v in result.values.items()})
    merged.update({k: float(v) for k, v in (values or {}).items()})
    return merged


def deviation(solution: Solution, target, chord: float) -> np.ndarray:
    """Signed normal distance of every node from the target, ``(n_span, n_contour)``, fraction of chord.

    Positive outside the target. ``chord`` (m) scales the nodes to the target's
    chord-normalised frame (the bay's mean chord, as the objectives use).
    """
    points = np.asarray(solution.nodes)[..., [0, 2]] / chord
    return np.asarray(target.distance(points), dtype=np.float64)


def auto_magnification(largest_deviation: float, goal: float = MAGNIFIED_DEVIATION) -> float:
    """The largest factor 1, 2, 5, 10, 20, ... that keeps ``factor * largest_deviation <= goal``.

    Never below 1 (a deviation larger than ``goal`` is drawn true to scale).
    """
    if not (math.isfinite(largest_deviation) and largest_deviation > 0):
        return 1.0
    best = 1.0
    for exponent in range(7):
        for mantissa in (1, 2, 5):
            factor = mantissa * 10.0**exponent
            if factor * largest_deviation <= goal:
                best = factor
    return best


def _leading_edge_index(nodes: np.ndarray) -> int:
    """Contour index of the rib's leading edge (smallest x of the root row)."""
    return int(np.argmin(nodes[0, :, 0]))


def _surfaces(n_contour: int, j_le: int, periodic: bool) -> dict:
    """Contour indices of the upper (TE -> LE) and lower (LE -> TE) surfaces."""
    upper = np.arange(0, j_le + 1)
    lower = np.arange(j_le, n_contour)
    if periodic:
        lower = np.append(lower, 0)  # back to the trailing edge
    return {"upper": upper, "lower": lower}


class _Developed:
    """The developed skin: distance along the nominal rib contour (m) against span (m)."""

    def __init__(self, scene):
        bay = scene.bay
        contour = np.asarray(bay.contour_root) * bay.chord_root
        closed = np.concatenate([contour, contour[:1]]) if bay.periodic else contour
        self.edges = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(closed, axis=0).T))])
        self.s = self.edges[: bay.n_contour]  # node positions (the last edge closes the loop)
        self.y = np.linspace(0.0, bay.rib_spacing, bay.n_span)
        self.periodic = bay.periodic
        self.j_le = int(np.argmin(contour[:, 0]))
        self.contour_x = np.asarray(bay.contour_root)[:, 0]

    def wrap(self, values: np.ndarray) -> np.ndarray:
        """Node values with the first column repeated at the closing edge (periodic contour)."""
        return np.concatenate([values, values[:, :1]], axis=1) if self.periodic else values

    @property
    def node_s(self) -> np.ndarray:
        return self.edges if self.periodic else self.s

    def decorate(self, ax, with_labels: bool = True) -> None:
        """Leading-edge line and an x/chord scale on the top axis."""
        ax.axvline(self.edges[self.j_le], color="0.3", ls="--", lw=1.0,
                   label="leading edge" if with_labels else None)
        x = self.contour_x
        upper_s, upper_x = self.edges[: self.j_le + 1][::-1], x[: self.j_le + 1][::-1]
        lower_x = np.append(x[self.j_le:], x[0]) if self.periodic else x[self.j_le:]
        lower_s = self.edges[self.j_le: self.j_le + lower_x.size]
        stations = (1.0, 0.75, 0.5, 0.25)
        ticks = [float(np.interp(t, upper_x, upper_s)) for t in stations]
        ticks += [float(self.edges[self.j_le])]
        ticks += [float(np.interp(t, lower_x, lower_s)) for t in stations[::-1]]
        labels = [f"{t:g}" for t in stations] + ["0"] + [f"{t:g}" for t in stations[::-1]]
        top = ax.secondary_xaxis("top")
        top.set_xticks(ticks, labels=labels)
        top.set_xlabel("x / chord  (upper surface | lower surface)")
        ax.set_xlim(self.edges[0], self.edges[-1] if self.periodic else self.s[-1])
        ax.set_ylim(self.y[0], self.y[-1])
        ax.set_xlabel("distance along the contour from the trailing edge, m "
                      "(upper surface, leading edge, lower surface)")
        ax.set_ylabel("span position y, m")


def _kpa(pressure: float) -> str:
    return f"{pressure / 1e3:.4g} kPa"


def _figure(width: float, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


# ------------------------------------------------------------------ plots
def plot_section(solution: Solution, target, scene, *, magnification: float | None = None,
                 eta: float = 0.5):
    """The skin section at ``y = eta * rib_spacing`` against the rib (y = 0) and the target.

    Top: the profiles with their deviation from the target magnified, as a
    structural engineer draws a deformed shape: each grid node ``p`` is drawn
    at ``q + magnification * (p - q)``, where ``q`` is the target's point at
    the same contour station (the target resampled as the bay resamples its
    rib); the target itself is drawn true. (Offsetting along the target's
    normal instead folds the curve wherever a magnified inward deviation
    exceeds the local radius of curvature, as at a pulled-back leading edge.)
    Bottom: the true signed normal distances along x/chord, upper and lower
    surfaces.

    Args:
        solution: the equilibrium.
        target: the target `targets.Airfoil` (chord-normalised).
        scene: the `forward_solver.Scene` it was solved on (chord, grid).
        magnification: deviation factor of the top panel; default
            `auto_magnification` of the largest deviation shown.
        eta: span station of the skin section, fraction of the rib spacing.

    Returns:
        A `matplotlib.figure.Figure`.
    """
    chord = scene.bay.chord
    skin = solution.section(eta) / chord
    rib = solution.section(0.0) / chord
    skin_proj, rib_proj = target.project(skin), target.project(rib)
    stations = _target_stations(target, scene)
    largest = float(max(np.max(np.linalg.norm(skin - stations, axis=1)),
                        np.max(np.linalg.norm(rib - stations, axis=1))))
    factor = auto_magnification(largest) if magnification is None else float(magnification)
    if not (math.isfinite(factor) and factor > 0):
        raise ValueError(f"magnification must be a positive number, got {magnification!r}")

    def magnified(points):
        return stations + factor * (points - stations)

    errors = section_errors(solution, target, chord, eta)
    fig = _figure(10.0, 7.0)
    top, bottom = fig.subplots(2, 1, height_ratios=(1, 1))
    station = "mid-bay" if eta == 0.5 else f"y = {eta:g} b"
    times = f"\u00d7{factor:g}"
    closed_target = np.stack([target.x, target.z], axis=-1)
    top.plot(closed_target[:, 0], closed_target[:, 1], label=f"target {target.name}", **_TARGET_STYLE)
    rib_m, skin_m = magnified(rib), magnified(skin)
    if scene.bay.periodic:
        rib_m, skin_m = np.vstack([rib_m, rib_m[:1]]), np.vstack([skin_m, skin_m[:1]])
    top.plot(rib_m[:, 0], rib_m[:, 1], ls="--", label=f"rib at y = 0 (deviation {times})", **_RIB_STYLE)
    top.plot(skin_m[:, 0], skin_m[:, 1], label=f"{station} skin (deviation {times})", **_SKIN_STYLE)
    top.set_aspect("equal", adjustable="datalim")  # true shape; the box keeps its size
    top.set_xlabel("x / chord")
    top.set_ylabel("z / chord")
    top.grid(alpha=0.3)
    top.legend(loc="upper center", fontsize="small", ncols=3)
    top.set_title(f"profiles; deviations from the target magnified {times}", fontsize="medium")

    j_le = _leading_edge_index(np.asarray(solution.nodes))
    for surface, idx in _surfaces(skin.shape[0], j_le, scene.bay.periodic).items():
        ls = "-" if surface == "upper" else "--"
        bottom.plot(rib[idx, 0], rib_proj.distance[idx], ls=ls, color=_RIB_STYLE["color"],
                    label=f"rib, {surface} surface")
        bottom.plot(skin[idx, 0], skin_proj.distance[idx], ls=ls, color=_SKIN_STYLE["color"],
                    label=f"{station} skin, {surface} surface")
    bottom.axhline(0.0, **_TARGET_STYLE, label=f"target {target.name}")
    bottom.set_xlabel("x / chord")
    bottom.set_ylabel("normal distance / chord\n(+ outside the target)")
    mm = bottom.secondary_yaxis("right", functions=(lambda d: d * chord * 1e3,
                                                    lambda m: m / (chord * 1e3)))
    mm.set_ylabel("mm")
    bottom.grid(alpha=0.3)
    bottom.legend(fontsize="small", ncols=3, loc="best")
    bottom.set_title(f"true deviation (not magnified): {station} rms {errors.rms:.2e}, "
                     f"max {errors.max:.2e} chord", fontsize="medium")
    fig.suptitle(f"{target.name}: {station} section against the rib and the target, "
                 f"p = {_kpa(solution.pressure)}")
    return fig


def _target_stations(target, scene) -> np.ndarray:
    """``(n_contour, 2)`` chord-normalised target points at the grid's contour stations."""
    from forward_solver import Bay

    bay = scene.bay
    return np.asarray(Bay.from_airfoil(target, chord=1.0, rib_spacing=1.0, n_span=3,
                                       n_contour=bay.n_contour).contour_root)


def plot_deviation(solution: Solution, target, scene):
    """Signed normal distance of the skin from the target over the whole bay, on the developed skin.

    Args:
        solution: the equilibrium.
        target: the target `targets.Airfoil`.
        scene: the `forward_solver.Scene` it was solved on.

    Returns:
        A `matplotlib.figure.Figure`.
    """
    chord = scene.bay.chord
    dev = deviation(solution, target, chord)
    grid = _Developed(scene)
    limit = float(np.max(np.abs(dev))) or 1.0
    fig = _figure(10.0, 5.0)
    ax = fig.subplots()
    mesh = ax.pcolormesh(grid.node_s, grid.y, grid.wrap(dev), shading="gouraud", cmap="RdBu_r",
                         vmin=-limit, vmax=limit)
    bar = fig.colorbar(mesh, ax=ax)
    bar.set_label("normal distance from the target / chord\n(red: outside, blue: inside)")
    bar.formatter.set_powerlimits((-2, 2))
    grid.decorate(ax)
    ax.axhline(0.5 * scene.bay.rib_spacing, color="0.2", ls=":", lw=1.0, label="mid-bay section")
    i, j = np.unravel_index(np.argmax(np.abs(dev)), dev.shape)
    ax.plot(grid.s[j], grid.y[i], marker="*", ms=13, color="gold", mec="black", ls="none",
            label=f"largest deviation {dev[i, j]:+.2e} chord ({dev[i, j] * chord * 1e3:+.2f} mm)")
    ax.legend(loc="upper left", fontsize="small", framealpha=0.9)
    rms = float(np.sqrt(np.mean(dev**2)))
    ax.set_title(f"{target.name}: deviation of the skin from the target over the bay "
                 f"(true scale, not magnified)\np = {_kpa(solution.pressure)}; rms over all nodes "
                 f"{rms:.2e} chord; ribs at y = 0 and y = {scene.bay.rib_spacing:g} m", fontsize="medium")
    return fig


def plot_tensions(solution: Solution, scene):
    """Fibre tensions T11 (span) and T22 (contour) of every cell, wrinkled cells marked.

    Args:
        solution: the equilibrium (tensions as the solver reports them: with
            ``tension_only`` a compressive fibre is clamped to zero and its
            cell flagged in ``solution.wrinkled``).
        scene: the `forward_solver.Scene` it was solved on.

    Returns:
        A `matplotlib.figure.Figure`.
    """
    grid = _Developed(scene)
    s_edges = grid.edges if grid.periodic else grid.s
    s_mid = 0.5 * (s_edges[:-1] + s_edges[1:])
    y_mid = 0.5 * (grid.y[:-1] + grid.y[1:])
    wrinkled = np.asarray(solution.wrinkled, dtype=bool)
    count, total = int(wrinkled.sum()), wrinkled.size
    fig = _figure(10.0, 8.0)
    axes = fig.subplots(2, 1, sharex=True)
    panels = (("span fibres T11", np.asarray(solution.tension_span)),
              ("contour fibres T22", np.asarray(solution.tension_chord)))
    for k, (ax, (name, tension)) in enumerate(zip(axes, panels)):
        mesh = ax.pcolormesh(s_edges, grid.y, tension, shading="flat", cmap="viridis",
                             vmin=min(0.0, float(tension.min())))
        bar = fig.colorbar(mesh, ax=ax)
        bar.set_label(f"{name.split()[-1]}, N/m")
        grid.decorate(ax)
        if k == 0:
            ax.set_xlabel("")
        if count:
            ii, jj = np.nonzero(wrinkled)
            ax.plot(s_mid[jj], y_mid[ii], ls="none", marker="x", ms=5, mew=1.2, color="red",
                    label=f"wrinkled cell ({count} of {total})")
        else:
            ax.plot([], [], ls="none", marker="x", color="red", label="wrinkled cells: none")
        ax.legend(loc="upper left", fontsize="small", framealpha=0.9)
        ax.set_title(f"{name}: min {tension.min():.4g} N/m, max {tension.max():.4g} N/m",
                     fontsize="medium")
    fig.suptitle(f"{scene.bay.name} bay: fibre tensions per unit width at p = {_kpa(solution.pressure)}; "
                 f"{100 * count / total:.1f}% of cells wrinkled (a fibre would be in compression)",
                 fontsize="medium")
    return fig


_UNITS = {"pressure": ("pressure, kPa", 1e-3), "prestrain_span": ("span prestrain, %", 100.0),
          "prestrain_chord": ("chord prestrain, %", 100.0),
          "rib_thickness_scale": ("rib thickness scale", 1.0), "rib_chord_scale": ("rib chord scale", 1.0)}


def plot_history(result: DesignResult, bounds: dict | None = None):
    """The optimiser's iterates: the objective and each design variable against the iterate.

    Args:
        result: a `DesignResult` with a non-empty history.
        bounds: ``{name: (lower, upper)}`` to draw (as passed to `optimise_pressure`).

    Returns:
        A `matplotlib.figure.Figure`.

    Raises:
        ValueError: if the result has no history (a single equilibrium).
    """
    history = list(getattr(result, "history", None) or [])
    if not history:
        raise ValueError("the result has no optimiser history to plot (a single equilibrium)")
    from matplotlib.ticker import FormatStrFormatter, MaxNLocator, NullFormatter

    names = list(result.variables)
    it = np.arange(1, len(history) + 1)
    objective = np.array([h["objective"] for h in history], dtype=np.float64)
    fig = _figure(8.0, 2.4 + 1.9 * len(names))
    axes = np.atleast_1d(fig.subplots(len(names) + 1, 1, sharex=True))
    ax = axes[0]
    if result.method == "root":
        ax.semilogy(it, np.abs(objective), "o-", color="C3", label="|root condition|, chord")
        ax.set_ylabel("|condition|, chord")
    else:
        ax.semilogy(it, np.sqrt(np.maximum(objective, 0.0)), "o-", color="C3",
                    label="objective: rms distance, incl. constraint penalties")
        ax.axhline(result.rms_error, color="0.3", ls=":", label=f"result: rms {result.rms_error:.3e}")
        ax.set_ylabel("rms distance / chord")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize="small")
    bounds = bounds or {}
    for ax, name in zip(axes[1:], names):
        label, unit = _UNITS.get(name, (name, 1.0))
        ax.plot(it, [h["values"][name] * unit for h in history], "o-", color="C0", label="iterate")
        ax.axhline(result.values[name] * unit, color="0.3", ls=":",
                   label=f"result: {result.values[name] * unit:.5g}")
        if name in bounds:
            for k, b in enumerate(bounds[name]):
                ax.axhline(b * unit, color="0.5", ls="--", lw=1.0, label="bounds" if k == 0 else None)
        if name == "pressure" and name in bounds and bounds[name][1] > 10 * bounds[name][0]:
            ax.set_yscale("log")  # bounds over decades; plain numbers, not powers of ten
            ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
            ax.yaxis.set_minor_formatter(NullFormatter())
        ax.set_ylabel(label)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize="small", loc="best")
    axes[-1].set_xlabel("iterate (one forward solve each)")
    axes[-1].xaxis.set_major_locator(MaxNLocator(integer=True))
    status = "converged" if result.success else "did not converge"
    fig.suptitle(f"optimiser history: {result.method}, {result.objective} objective, "
                 f"{len(history)} iterates, {status}")
    return fig


# ------------------------------------------------------------------ surface files
def _quads(n_span: int, n_contour: int, periodic: bool) -> np.ndarray:
    """``(n_quads, 4)`` zero-based node indices of the grid's cells, counter-clockwise seen from outside."""
    index = np.arange(n_span * n_contour).reshape(n_span, n_contour)
    j = np.arange(n_contour if periodic else n_contour - 1)
    j1 = (j + 1) % n_contour
    # (i, j) -> (i+1, j) -> (i+1, j+1) -> (i, j+1): the normal e1 x e2 points out of the section.
    quads = np.stack([index[:-1][:, j], index[1:][:, j], index[1:][:, j1], index[:-1][:, j1]], axis=-1)
    return quads.reshape(-1, 4)


def write_obj(path, nodes, periodic: bool, name: str = "skin") -> Path:
    """Write the skin as a Wavefront OBJ: one vertex per node, one quad per cell.

    Args:
        path: file to write.
        nodes: ``(n_span, n_contour, 3)`` m.
        periodic: close the contour (a wing section) with a last column of quads.
        name: object name in the file.

    Returns:
        The path. Vertex ``1 + i * n_contour + j`` is node ``(i, j)``; faces
        wind counter-clockwise seen from outside the wing.
    """
    nodes = np.asarray(nodes, dtype=np.float64)
    n_span, n_contour, _ = nodes.shape
    quads = _quads(n_span, n_contour, periodic) + 1
    lines = [
        "# inflatable-wing equilibrium skin; units: metres (x chordwise, y spanwise, z up)",
        f"# grid {n_span} x {n_contour} nodes (span x contour); vertex 1 + i*{n_contour} + j is node (i, j)",
        f"o {name}",
    ]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in nodes.reshape(-1, 3)]
    lines += [f"f {a} {b} {c} {d}" for a, b, c, d in quads]
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path


def write_stl(path, nodes, periodic: bool) -> Path:
    """Write the skin as a binary STL (two triangles per cell, outward normals), metres."""
    nodes = np.asarray(nodes, dtype=np.float64)
    n_span, n_contour, _ = nodes.shape
    quads = _quads(n_span, n_contour, periodic)
    flat = nodes.reshape(-1, 3)
    triangles = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    corners = flat[triangles]  # (n, 3, 3)
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
    record = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    data = np.zeros(len(triangles), dtype=record)
    data["normal"], data["corners"] = normals, corners
    header = b"inflatable-wing equilibrium skin, units: metres".ljust(80, b" ")
    path = Path(path)
    with open(path, "wb") as f:
        f.write(header)
        f.write(np.uint32(len(triangles)).tobytes())
        f.write(data.tobytes())
    return path


def write_npz(path, solution: Solution, target, scene, values: dict, result: DesignResult | None = None) -> Path:
    """Write the equilibrium and its parameters as a compressed ``.npz`` (no pickles).

    Arrays: ``nodes`` (n_span, n_contour, 3) m; ``tension_span``,
    ``tension_chord`` (n_span - 1, n_cells) N/m; ``wrinkled`` (same, bool);
    ``fixed`` (n_span, n_contour) bool; ``deviation`` (n_span, n_contour)
    signed normal distance from the target, fraction of chord;
    ``target_xz`` (n, 2) the chord-normalised target; ``mid_bay_section``
    and ``rib_section`` (n_contour, 2) x-z in m; scalars ``pressure`` (Pa),
    ``prestrain`` (span, chord), ``rib_thickness_scale``, ``rib_chord_scale``,
    ``chord`` and ``rib_spacing`` (m); ``variables`` (names) and, after an
    optimisation, ``history_objective`` and ``history_values`` (iterate x
    variable).
    """
    bay = scene.bay
    arrays = dict(
        nodes=np.asarray(solution.nodes), tension_span=np.asarray(solution.tension_span),
        tension_chord=np.asarray(solution.tension_chord), wrinkled=np.asarray(solution.wrinkled, bool),
        fixed=np.asarray(bay.fixed, bool), deviation=deviation(solution, target, bay.chord),
        target_xz=np.stack([np.asarray(target.x), np.asarray(target.z)], axis=-1),
        mid_bay_section=solution.section(0.5), rib_section=solution.section(0.0),
        pressure=np.float64(values["pressure"]),
        prestrain=np.array([values["prestrain_span"], values["prestrain_chord"]]),
        rib_thickness_scale=np.float64(values["rib_thickness_scale"]),
        rib_chord_scale=np.float64(values["rib_chord_scale"]),
        chord=np.float64(bay.chord), rib_spacing=np.float64(bay.rib_spacing),
        target_name=np.array(str(target.name)),
    )
    if result is not None:
        names = list(result.variables)
        arrays["variables"] = np.array(names, dtype=str)
        arrays["history_objective"] = np.array([h["objective"] for h in result.history], dtype=np.float64)
        arrays["history_values"] = np.array([[h["values"][n] for n in names] for h in result.history],
                                            dtype=np.float64).reshape(-1, len(names))
    path = Path(path)
    with open(path, "wb") as f:
        np.savez_compressed(f, **arrays)
    return path


# ------------------------------------------------------------------ summary
def _version(distribution: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(distribution)
    except PackageNotFoundError:
        return "unknown"


def _jsonable(value):
    """Plain JSON types; non-finite floats become None (JSON has no inf or NaN)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, Path):
        return str(value)
    return value


def summarise(result, target, scene, *, objective: str | None = None, values: dict | None = None,
              inputs: dict | None = None, timings: dict | None = None) -> dict:
    """The summary of a design or a single equilibrium, as `write_report` stores it.

    Args:
        result: a `DesignResult`, or a `Solution` (a single equilibrium).
        target: the target `targets.Airfoil`.
        scene: the `forward_solver.Scene`.
        objective: the sections the errors are measured on (default the
            result's objective, or "mid_bay" for a `Solution`).
        values: parameter values to report for a `Solution` (rib scales).
        inputs: the caller's options (stored as given).
        timings: seconds, e.g. ``{"setup": ..., "optimisation": ...}``.

    Returns:
        A JSON-ready dict. Errors are fractions of chord; ``null`` marks a
        value that does not exist (no upper tension limit, a gradient not
        computed).
    """
    solution, design = _unpack(result)
    objective = objective or (design.objective if design is not None else "mid_bay")
    params = _parameter_values(solution, design, values)
    chord = scene.bay.chord
    rms, largest = design_errors(solution.nodes, target, chord, objective)
    mid = section_errors(solution, target, chord)
    bay, fabric = scene.bay, scene.fabric
    summary = {
        "package": {"name": "inflatable-wing", "version": _version("inflatable-wing")},
        "versions": {"python": platform.python_version(), "jax": _version("jax"),
                     "numpy": np.__version__},
        "mode": "optimise" if design is not None else "evaluate",
        "inputs": dict(inputs or {}),
        "case": {
            "target": str(target.name), "rib": bay.name, "chord_m": chord,
            "rib_spacing_m": bay.rib_spacing, "grid": [bay.n_span, bay.n_contour],
            "fabric": {"stiffness_span_n_per_m": fabric.stiffness_span,
                       "stiffness_chord_n_per_m": fabric.stiffness_chord, "poisson": fabric.poisson},
        },
        "results": {
            "success": bool(design.success if design is not None else solution.converged),
            "message": design.message if design is not None else solution.message,
            "values": {"pressure_pa": params["pressure"], "prestrain_span": params["prestrain_span"],
                       "prestrain_chord": params["prestrain_chord"],
                       "rib_thickness_scale": params["rib_thickness_scale"],
                       "rib_chord_scale": params["rib_chord_scale"]},
            "variables": list(design.variables) if design is not None else [],
            "method": design.method if design is not None else None,
            "iterations": len(design.history) if design is not None else 0,
            "forward_solves": design.solves if design is not None else 1,
            "equilibrium": {"result": solution.result.name, "converged": solution.converged,
                            "steps": int(solution.steps), "relative_residual": solution.residual,
                            "method": solution.method,
                            "wrinkled_fraction": solution.wrinkled_fraction},
        },
        "errors": {
            "unit": "fraction of chord",
            "objective": objective,
            "before": (None if design is None else
                       {"rms": design.initial_rms_error, "max": design.initial_max_error}),
            "after": {"rms": rms, "max": largest},
            "mid_bay_after": {"rms": mid.rms, "max": mid.max},
        },
        "constraints": {
            "active": list(design.active_constraints) if design is not None else None,
            "values": (dict(design.constraint_values) if design is not None else
                       {"min_tension": float(min(np.min(solution.tension_span), np.min(solution.tension_chord))),
                        "max_tension": float(max(np.max(solution.tension_span), np.max(solution.tension_chord)))}),
            "unit": "N/m",
        },
        "timings_s": dict(timings or {}),
        "history": list(design.history) if design is not None else [],
    }
    if design is None:
        summary["constraints"]["note"] = ("a single equilibrium: constraints are not enforced; "
                                          "tensions are the solver's (compression clamped to zero)")
    return _jsonable(summary)


# ------------------------------------------------------------------ the folder
def check_output_folder(out_dir) -> Path:
    """The absolute output path, after checking that `write_report` may write (and replace) it.

    Raises:
        ValueError: if ``out_dir`` is a file, or a non-empty folder that holds
            no ``summary.json`` of an earlier report (it is never replaced), or
            its nearest existing parent is not a writable folder.
    """
    out = Path(os.path.abspath(os.fspath(out_dir)))
    if out.exists() or out.is_symlink():
        if not out.is_dir():
            raise ValueError(f"the output folder {out} exists and is not a folder; choose another path")
        if any(out.iterdir()) and not (out / "summary.json").is_file():
            raise ValueError(f"refusing to replace {out}: it is not empty and holds no summary.json of "
                             f"an earlier report; choose another output folder or empty this one")
    parent = out.parent
    while not parent.exists():
        parent = parent.parent
    try:  # a real probe: permission bits do not tell everything (read-only mounts, /proc)
        os.rmdir(tempfile.mkdtemp(prefix=f".{out.name}.probe-", dir=parent))
    except OSError as exc:
        raise ValueError(f"cannot create the output folder {out}: {parent} is not a writable folder "
                         f"({exc.strerror or exc})") from None
    return out


@contextmanager
def staged_folder(out_dir):
    """Write a folder atomically: yield a temporary folder, rename it to ``out_dir`` on success.

    The temporary folder (``.NAME.partial-*``) sits next to ``out_dir``, so the
    final rename stays on one file system. An existing ``out_dir`` (checked by
    `check_output_folder`) is moved aside and deleted only after the new
    folder is in place. On any exception, KeyboardInterrupt included, the
    temporary folder is removed and ``out_dir`` is left as it was.
    """
    out = check_output_folder(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = out.parent / f".{out.name}.partial-{uuid.uuid4().hex[:8]}"
    staging.mkdir()  # (not mkdtemp: the folder keeps the user's umask permissions)
    try:
        yield staging
        old = None
        if out.exists() or out.is_symlink():
            old = out.parent / f".{out.name}.old-{uuid.uuid4().hex[:8]}"
            os.rename(out, old)
        try:
            os.rename(staging, out)
        except BaseException:
            if old is not None:
                os.rename(old, out)
            raise
        if old is not None:
            if old.is_dir() and not old.is_symlink():
                shutil.rmtree(old, ignore_errors=True)
            else:
                old.unlink()
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise


def write_report(out_dir, result, target, *, scene, objective: str | None = None,
                 values: dict | None = None, bounds: dict | None = None, inputs: dict | None = None,
                 timings: dict | None = None, magnification: float | None = None) -> dict:
    """Write the output folder of a design (or of a single equilibrium) and return its summary.

    Args:
        out_dir: the folder to create (or replace: see `staged_folder`).
        result: a `DesignResult` from `optimise_pressure`, or a `Solution`.
        target: the target `targets.Airfoil` (chord-normalised).
        scene: the `forward_solver.Scene` it was solved on.
        objective, values, inputs: as `summarise`.
        bounds: variable bounds to draw in the history plot.
        timings: seconds spent before the report (e.g. ``setup``,
            ``optimisation``); ``report`` and, unless given, ``total`` (their
            sum) are added.
        magnification: deviation factor of the section plot (default automatic).

    Returns:
        The summary (as written to ``summary.json``), with ``files`` (names in
        the folder), ``skipped`` (files not written and why) and ``out`` (the
        folder's absolute path).

    Raises:
        ValueError: if ``out_dir`` cannot be written (`check_output_folder`).
        TypeError: if ``result`` is neither a `DesignResult` nor a `Solution`.
    """
    start = time.perf_counter()
    out = check_output_folder(out_dir)
    solution, design = _unpack(result)
    params = _parameter_values(solution, design, values)
    summary = summarise(result, target, scene, objective=objective, values=values, inputs=inputs,
                        timings=timings)
    files, skipped = [], {}
    with staged_folder(out) as staging:
        write_npz(staging / "equilibrium.npz", solution, target, scene, params, design)
        write_obj(staging / "skin.obj", solution.nodes, scene.bay.periodic, name=scene.bay.name)
        write_stl(staging / "skin.stl", solution.nodes, scene.bay.periodic)
        files += ["equilibrium.npz", "skin.obj", "skin.stl"]
        figures = [("mid_bay_section.png", lambda: plot_section(solution, target, scene,
                                                                magnification=magnification)),
                   ("deviation.png", lambda: plot_deviation(solution, target, scene)),
                   ("tensions.png", lambda: plot_tensions(solution, scene))]
        if design is not None and design.history:
            figures.append(("history.png", lambda: plot_history(design, bounds)))
        else:
            skipped["history.png"] = "a single equilibrium has no optimiser history"
        for name, make in figures:
            make().savefig(staging / name, dpi=_DPI)
            files.append(name)
        times = dict(summary["timings_s"])
        times["report"] = time.perf_counter() - start
        times.setdefault("total", sum(v for v in times.values() if isinstance(v, (int, float))))
        summary.update(timings_s=times, files=files + ["summary.json"], skipped=skipped, out=str(out))
        text = json.dumps(_jsonable(summary), indent=2, allow_nan=False)
        (staging / "summary.json").write_text(text + "\n")
    return summary
