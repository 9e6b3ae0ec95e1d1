"""Figures of one bay: its mid-bay section, the deviation map, the tensions, a designed rib.

The ``plot_*`` functions return `matplotlib.figure.Figure` objects built
without pyplot (no global state, an Agg canvas), so they serve notebooks and
scripts as well as the command line (`folder.write_report` saves them into
the output folder; the figures of a wing and of its design: `wing_figures`).
Maps of the whole bay are drawn on the developed skin: the horizontal axis
is the distance along the rib contour from the trailing edge over the upper
surface, the leading edge and the lower surface (Selig order), with x/chord
marked on the top axis.
"""

from __future__ import annotations

import math

import jax
import numpy as np

from forward_solver import Bay

from ..objectives import section_errors
from ..rib_design import RibGeometry, RibLimits
from .scales import Millimetres, same

__all__ = ["MAGNIFIED_DEVIATION", "RIB_STYLE", "SKIN_STYLE", "TARGET_STYLE", "auto_magnification", "kpa",
           "new_figure", "plot_deviation", "plot_rib_design", "plot_section", "plot_tensions"]

#: Largest magnified deviation in the section plot, fraction of chord
#: (`auto_magnification` picks the largest 1-2-5 factor that stays below it).
MAGNIFIED_DEVIATION = 0.1

TARGET_STYLE = dict(color="black", lw=1.4)
RIB_STYLE = dict(color="C0", lw=1.4)
SKIN_STYLE = dict(color="C3", lw=1.6)


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
        top = ax.secondary_xaxis("top", functions=(same, same))
        top.set_xticks(ticks, labels=labels)
        top.set_xlabel("x / chord  (upper surface | lower surface)")
        ax.set_xlim(self.edges[0], self.edges[-1] if self.periodic else self.s[-1])
        ax.set_ylim(self.y[0], self.y[-1])
        ax.set_xlabel("distance along the contour from the trailing edge, m "
                      "(upper surface, leading edge, lower surface)")
        ax.set_ylabel("span position y, m")


def kpa(pressure: float) -> str:
    """A pressure in kPa, for titles."""
    return f"{pressure / 1e3:.4g} kPa"


def new_figure(width: float, height: float):
    """A constrained-layout figure of ``width`` x ``height`` inches on an Agg canvas (no pyplot)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def plot_section(solution, target, scene, *, magnification: float | None = None,
                 eta: float = 0.5, start_rib=None, bay: int = 0, rib_stations: tuple | None = None):
    """The skin section at ``y = eta * rib_spacing`` against the bay's root rib and the target.

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
        start_rib: the rib's section before its shape was designed (a
            `targets.Airfoil`), drawn beside the designed rib; None: not drawn.
        bay: the bay's index in its wing (its root rib is rib ``bay``).
        rib_stations: the span stations of the bay's two ribs, m (default 0
            and the rib spacing), named in the legend and the title.

    Returns:
        A `matplotlib.figure.Figure`.
    """
    chord = scene.bay.chord
    skin = solution.section(eta) / chord
    rib = solution.section(0.0) / scene.bay.chord_root  # the rib at y = 0 at its own chord (taper)
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
    fig = new_figure(10.0, 7.0)
    top, bottom = fig.subplots(2, 1, height_ratios=(1, 1))
    station = "mid-bay" if eta == 0.5 else f"y = {eta:g} b"
    times = f"\u00d7{factor:g}"
    closed_target = np.stack([target.x, target.z], axis=-1)
    top.plot(closed_target[:, 0], closed_target[:, 1], label=f"target {target.name}", **TARGET_STYLE)
    rib_m, skin_m = magnified(rib), magnified(skin)
    if scene.bay.periodic:
        rib_m, skin_m = np.vstack([rib_m, rib_m[:1]]), np.vstack([skin_m, skin_m[:1]])
    if start_rib is not None:
        start = magnified(_target_stations(start_rib, scene))
        start = np.vstack([start, start[:1]])
        top.plot(start[:, 0], start[:, 1], ls=":", color="0.5", lw=1.2,
                 label=f"starting rib (deviation {times})")
    y0, y1 = (0.0, scene.bay.rib_spacing) if rib_stations is None else (float(rib_stations[0]), float(rib_stations[1]))
    rib_label = f"{'designed ' if start_rib is not None else ''}rib {bay} at y = {y0:g} m"
    top.plot(rib_m[:, 0], rib_m[:, 1], ls="--", label=f"{rib_label} (deviation {times})", **RIB_STYLE)
    top.plot(skin_m[:, 0], skin_m[:, 1], label=f"{station} skin (deviation {times})", **SKIN_STYLE)
    top.set_aspect("equal", adjustable="datalim")  # true shape; the box keeps its size
    top.set_xlabel("x / chord")
    top.set_ylabel("z / chord")
    top.grid(alpha=0.3)
    top.legend(loc="upper center", fontsize="small", ncols=4 if start_rib is not None else 3)
    top.set_title(f"profiles; deviations from the target magnified {times}", fontsize="medium")

    j_le = _leading_edge_index(np.asarray(solution.nodes))
    for surface, idx in _surfaces(skin.shape[0], j_le, scene.bay.periodic).items():
        ls = "-" if surface == "upper" else "--"
        bottom.plot(rib[idx, 0], rib_proj.distance[idx], ls=ls, color=RIB_STYLE["color"],
                    label=f"rib {bay}, {surface} surface")
        bottom.plot(skin[idx, 0], skin_proj.distance[idx], ls=ls, color=SKIN_STYLE["color"],
                    label=f"{station} skin, {surface} surface")
    bottom.axhline(0.0, **TARGET_STYLE, label=f"target {target.name}")
    bottom.set_xlabel("x / chord")
    bottom.set_ylabel("normal distance / chord\n(+ outside the target)")
    mm = bottom.secondary_yaxis("right", functions=(Millimetres(chord).forward, Millimetres(chord).inverse))
    mm.set_ylabel("mm")
    bottom.grid(alpha=0.3)
    bottom.legend(fontsize="small", ncols=3, loc="best")
    bottom.set_title(f"true deviation (not magnified): {station} rms {errors.rms:.2e}, "
                     f"max {errors.max:.2e} chord", fontsize="medium")
    fig.suptitle(f"bay {bay} (ribs {bay} and {bay + 1} at y = {y0:g} and {y1:g} m): {station} section against "
                 f"rib {bay} and the target\n{target.name}, p = {kpa(solution.pressure)}")
    return fig


def _target_stations(target, scene) -> np.ndarray:
    """``(n_contour, 2)`` chord-normalised target points at the grid's contour stations."""
    bay = scene.bay
    return np.asarray(Bay.from_airfoil(target, chord=1.0, rib_spacing=1.0, n_span=3,
                                       n_contour=bay.n_contour).contour_root)


def plot_deviation(solution, target, scene, deviation: np.ndarray):
    """Signed normal distance of the skin from the target over the whole bay, on the developed skin.

    Args:
        solution: the equilibrium.
        target: the target `targets.Airfoil` (named in the title).
        scene: the `forward_solver.Scene` it was solved on.
        deviation: ``(n_span, n_contour)`` each node's distance from its row's target, fraction of
            chord (`measures.wing_deviation`).

    Returns:
        A `matplotlib.figure.Figure`.
    """
    chord = scene.bay.chord
    dev = np.asarray(deviation, np.float64)
    grid = _Developed(scene)
    limit = float(np.max(np.abs(dev))) or 1.0
    fig = new_figure(10.0, 5.0)
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
                 f"(true scale, not magnified)\np = {kpa(solution.pressure)}; rms over all nodes "
                 f"{rms:.2e} chord; ribs at y = 0 and y = {scene.bay.rib_spacing:g} m", fontsize="medium")
    return fig


def plot_tensions(solution, scene):
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
    fig = new_figure(10.0, 8.0)
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
    fig.suptitle(f"{scene.bay.name} bay: fibre tensions per unit width at p = {kpa(solution.pressure)}; "
                 f"{100 * count / total:.1f}% of cells wrinkled (a fibre would be in compression)",
                 fontsize="medium")
    return fig


def plot_rib_design(parameters, start_rib, chord: float, limits=None):
    """The designed rib against its starting section: the offset to cut, and the thickness kept.

    Top: the outward offset of the upper and lower surfaces (mm; what the
    rib's template changes). Bottom: the local thickness as a fraction of the
    starting rib's, with the minimum-thickness limit.

    Args:
        parameters: the design's `forward_solver.Parameters` (``rib_shape`` set).
        start_rib: the starting rib section (`targets.Airfoil`).
        chord: the rib chord, m.
        limits: the `rib_design.RibLimits` (default: the defaults).

    Returns:
        A `matplotlib.figure.Figure`.
    """
    geometry = RibGeometry(start_rib, limits or RibLimits())
    with jax.enable_x64(True):
        z = np.asarray(geometry.section_z(parameters))
    start = geometry.z0
    x = geometry.x
    values = geometry.measure(parameters)
    fig = new_figure(9.0, 6.0)
    top, bottom = fig.subplots(2, 1, sharex=True)
    n_nose = int(np.argmin(x))
    top.plot(x[: n_nose + 1], (z - start)[: n_nose + 1] * chord * 1e3, color="C0", label="upper surface")
    top.plot(x[n_nose:], -(z - start)[n_nose:] * chord * 1e3, color="C0", ls="--", label="lower surface")
    top.axhline(0.0, color="0.3", lw=0.8)
    top.set_ylabel("outward offset, mm")
    top.grid(alpha=0.3)
    top.legend(fontsize="small")
    top.set_title(f"designed rib minus starting rib {start_rib.name} (chord {chord:g} m)", fontsize="medium")
    thickness = z[geometry.upper] - z[geometry.lower]
    bottom.plot(x[geometry.upper], thickness / geometry.thickness0, color="C0", label="thickness / starting")
    bottom.axhline(geometry.limits.min_thickness, color="C3", ls="--",
                   label=f"limit {geometry.limits.min_thickness:g}")
    bottom.set_xlabel("x / chord")
    bottom.set_ylabel("thickness ratio")
    bottom.grid(alpha=0.3)
    bottom.legend(fontsize="small")
    bottom.set_title(f"least radius of curvature {values['rib_min_radius']:.4f} chord (limit "
                     f"{values['rib_min_radius_limit']:.4f}; starting rib {values['rib_start_radius']:.4f})",
                     fontsize="medium")
    fig.suptitle("rib design: the template offset and the thickness kept")
    return fig
