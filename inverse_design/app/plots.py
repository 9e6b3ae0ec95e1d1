"""Figures of a design: the mid-bay section, the deviation map, the tensions, the optimiser's history.

The ``plot_*`` functions return `matplotlib.figure.Figure` objects built
without pyplot (no global state, an Agg canvas), so they serve notebooks and
scripts as well as the command line (`inverse_design.app.report.write_report`
saves them into the output folder). Maps of the whole bay are drawn on the
developed skin: the horizontal axis is the distance along the rib contour
from the trailing edge over the upper surface, the leading edge and the
lower surface (Selig order), with x/chord marked on the top axis.
"""

from __future__ import annotations

import math

import numpy as np

from forward_solver import Solution

from .export import deviation
from .scales import Millimetres, same
from ..objectives import section_errors
from ..optimise import DesignResult

__all__ = [
    "MAGNIFIED_DEVIATION",
    "auto_magnification",
    "plot_aero",
    "plot_deviation",
    "plot_history",
    "plot_rib_design",
    "plot_section",
    "plot_tensions",
    "plot_tolerance",
    "plot_wing_overview",
]

#: Largest magnified deviation in the section plot, fraction of chord
#: (`auto_magnification` picks the largest 1-2-5 factor that stays below it).
MAGNIFIED_DEVIATION = 0.1

_TARGET_STYLE = dict(color="black", lw=1.4)
_RIB_STYLE = dict(color="C0", lw=1.4)
_SKIN_STYLE = dict(color="C3", lw=1.6)


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
    fig = _figure(10.0, 7.0)
    top, bottom = fig.subplots(2, 1, height_ratios=(1, 1))
    station = "mid-bay" if eta == 0.5 else f"y = {eta:g} b"
    times = f"\u00d7{factor:g}"
    closed_target = np.stack([target.x, target.z], axis=-1)
    top.plot(closed_target[:, 0], closed_target[:, 1], label=f"target {target.name}", **_TARGET_STYLE)
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
    top.plot(rib_m[:, 0], rib_m[:, 1], ls="--", label=f"{rib_label} (deviation {times})", **_RIB_STYLE)
    top.plot(skin_m[:, 0], skin_m[:, 1], label=f"{station} skin (deviation {times})", **_SKIN_STYLE)
    top.set_aspect("equal", adjustable="datalim")  # true shape; the box keeps its size
    top.set_xlabel("x / chord")
    top.set_ylabel("z / chord")
    top.grid(alpha=0.3)
    top.legend(loc="upper center", fontsize="small", ncols=4 if start_rib is not None else 3)
    top.set_title(f"profiles; deviations from the target magnified {times}", fontsize="medium")

    j_le = _leading_edge_index(np.asarray(solution.nodes))
    for surface, idx in _surfaces(skin.shape[0], j_le, scene.bay.periodic).items():
        ls = "-" if surface == "upper" else "--"
        bottom.plot(rib[idx, 0], rib_proj.distance[idx], ls=ls, color=_RIB_STYLE["color"],
                    label=f"rib {bay}, {surface} surface")
        bottom.plot(skin[idx, 0], skin_proj.distance[idx], ls=ls, color=_SKIN_STYLE["color"],
                    label=f"{station} skin, {surface} surface")
    bottom.axhline(0.0, **_TARGET_STYLE, label=f"target {target.name}")
    bottom.set_xlabel("x / chord")
    bottom.set_ylabel("normal distance / chord\n(+ outside the target)")
    mm = bottom.secondary_yaxis("right", functions=(Millimetres(chord).forward, Millimetres(chord).inverse))
    mm.set_ylabel("mm")
    bottom.grid(alpha=0.3)
    bottom.legend(fontsize="small", ncols=3, loc="best")
    bottom.set_title(f"true deviation (not magnified): {station} rms {errors.rms:.2e}, "
                     f"max {errors.max:.2e} chord", fontsize="medium")
    fig.suptitle(f"bay {bay} (ribs {bay} and {bay + 1} at y = {y0:g} and {y1:g} m): {station} section against "
                 f"rib {bay} and the target\n{target.name}, p = {_kpa(solution.pressure)}")
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


#: Each variable's axis label, its factor from SI and the unit of a value on that axis.
_UNITS = {"pressure": ("pressure, kPa", 1e-3, " kPa"), "prestrain_span": ("span prestrain, %", 100.0, "%"),
          "prestrain_chord": ("chord prestrain, %", 100.0, "%"),
          "rib_thickness_scale": ("rib thickness scale\n(x starting thickness)", 1.0, " x starting thickness"),
          "rib_chord_scale": ("rib chord scale\n(x starting chord)", 1.0, " x starting chord"),
          "rib_shape": ("rib shape coefficients\n(chord)", 1.0, " chord"),
          "cut_pattern": ("cut pattern coefficients, %", 100.0, "%")}
#: A legend beside its axes, outside them: it never covers a curve.
_OUTSIDE = dict(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize="small")


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
    from ..rib_design import RibGeometry, RibLimits

    geometry = RibGeometry(start_rib, limits or RibLimits())
    import jax

    with jax.enable_x64(True):
        z = np.asarray(geometry.section_z(parameters))
    start = geometry.z0
    x = geometry.x
    values = geometry.measure(parameters)
    fig = _figure(9.0, 6.0)
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
    fig = _figure(10.0, 2.4 + 1.9 * len(names))
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
    ax.legend(**_OUTSIDE)
    bounds = bounds or {}
    for ax, name in zip(axes[1:], names):
        label, unit, suffix = _UNITS.get(name, (name, 1.0, ""))
        if np.ndim(result.values[name]) > 0:  # a vector variable: one line per component
            track = np.array([h["values"][name] for h in history], dtype=np.float64) * unit
            for k in range(track.shape[1]):
                ax.plot(it, track[:, k], ".-", lw=1.0, label=f"[{k}]" if track.shape[1] <= 8 else None)
        else:
            ax.plot(it, [h["values"][name] * unit for h in history], "o-", color="C0", label="iterate")
            ax.axhline(result.values[name] * unit, color="0.3", ls=":",
                       label=f"result: {result.values[name] * unit:.5g}{suffix}")
        if name in bounds:
            for k, b in enumerate(bounds[name]):
                ax.axhline(b * unit, color="0.5", ls="--", lw=1.0, label="bounds" if k == 0 else None)
        if name == "pressure" and name in bounds and bounds[name][1] > 10 * bounds[name][0]:
            ax.set_yscale("log")  # bounds over decades; plain numbers, not powers of ten
            ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
            ax.yaxis.set_minor_formatter(NullFormatter())
        ax.set_ylabel(label)
        ax.grid(alpha=0.3, which="both")
        ax.legend(**_OUTSIDE)
    axes[-1].set_xlabel("iterate (one forward solve each)")
    axes[-1].xaxis.set_major_locator(MaxNLocator(integer=True))
    status = "converged" if result.success else "did not converge"
    fig.suptitle(f"optimiser history: {result.method}, {result.objective} objective, "
                 f"{len(history)} iterate{'' if len(history) == 1 else 's'}, {status}")
    return fig


def plot_aero(comparison):
    """Lift, drag and moment against angle of attack: target, mid-bay and bay-average sections.

    Top row: CL, CD and CM (quarter chord) of the three sections; bottom row:
    section minus target. Angles where NeuralFoil's analysis confidence is
    below 0.5 are marked with open circles.

    Args:
        comparison: an `inverse_design.aero.AeroComparison`.

    Returns:
        A `matplotlib.figure.Figure`.
    """
    alphas = np.asarray(comparison.alphas)
    styles = {"target": dict(label=f"target {comparison.target_name}", **_TARGET_STYLE),
              "bay_average": dict(label="bay-average section", ls="--", **_RIB_STYLE),
              "mid_bay": dict(label="mid-bay section", **_SKIN_STYLE)}
    differences = {"mid_bay": comparison.mid_bay_difference, "bay_average": comparison.bay_average_difference}
    fig = _figure(12.0, 7.0)
    axes = fig.subplots(2, 3, sharex=True)
    for column, (key, name) in enumerate((("cl", "CL"), ("cd", "CD"), ("cm", "CM (c/4)"))):
        top, bottom = axes[0, column], axes[1, column]
        for section, style in styles.items():
            polar = getattr(comparison, section)
            values = getattr(polar, key)
            top.plot(alphas, values, marker=".", ms=4, **style)
            doubtful = polar.confidence < 0.5
            if doubtful.any():
                top.plot(alphas[doubtful], values[doubtful], ls="none", marker="o", mfc="none",
                         color=style["color"], ms=8)
            if section in differences:
                bottom.plot(alphas, getattr(differences[section], key), marker=".", ms=4,
                            label=f"{style['label']} \u2212 target", color=style["color"], ls=style.get("ls", "-"))
        bottom.axhline(0.0, color="black", lw=1.0)
        top.set_ylabel(name)
        bottom.set_ylabel(f"\u0394{name.split()[0]}")
        bottom.set_xlabel("angle of attack, deg")
        for ax in (top, bottom):
            ax.grid(alpha=0.3)
        if key == "cd":
            bottom.ticklabel_format(axis="y", style="sci", scilimits=(-2, 2))
    axes[0, 0].legend(fontsize="small", loc="best")
    axes[1, 0].legend(fontsize="small", loc="best")
    worst = differences["mid_bay"].largest()
    fig.suptitle(f"{comparison.target_name} at Re = {comparison.reynolds:.3g} (NeuralFoil, "
                 f"{comparison.model_size}): mid-bay max |\u0394CL| {worst['cl']:.3g}, "
                 f"|\u0394CD| {worst['cd']:.3g}, |\u0394CM| {worst['cm']:.3g}; open circles: "
                 f"confidence < 0.5", fontsize="medium")
    return fig


def _symlog_limits(values, linthresh: float, margin: float = 0.15) -> tuple[float, float]:
    """Axis limits of a symlog axis that hold ``values`` with ``margin`` of the axis's height to spare at
    each end (autoscaling a symlog axis leaves the largest value on its edge, its marker cut in half)."""
    data = np.concatenate([np.ravel(np.asarray(v, np.float64)) for v in values])
    data = data[np.isfinite(data)]

    def forward(v):
        return np.sign(v) * np.log10(1.0 + np.abs(v) / linthresh)

    def inverse(t):
        return np.sign(t) * linthresh * (10.0 ** np.abs(t) - 1.0)

    low, high = forward(np.min(data)), forward(np.max(data))
    spare = margin * max(high - low, 1.0)
    return float(inverse(low - spare)), float(inverse(high + spare))


def plot_wing_overview(result, deviation: np.ndarray):
    """One figure of every bay of a wing design: the deviation over the whole skin and the per-bay figures.

    Top: the signed normal distance of every node from its row's target
    (fractions of the local chord, ``deviation`` of `report.wing_deviation`)
    over the span (rows of all bays joined, y from the root rib) and around
    the contour (node index: trailing edge, upper surface, leading edge,
    lower surface). Middle: each bay's RMS and largest distance, before and
    after, at its mid-span station. Bottom: each bay's smallest and largest
    fibre tension at the design, with the tension floor.

    Args:
        result: the wing's `optimise.DesignResult`.
        deviation: ``(n_bays, n_span, n_contour)`` fractions of the local chord.

    Returns:
        A `matplotlib.figure.Figure`.
    """
    stations = np.asarray(result.wing.stations, np.float64)
    n_bays, n_span, n_contour = deviation.shape
    rows = [stations[k] + np.linspace(0.0, stations[k + 1] - stations[k], n_span) for k in range(n_bays)]
    y = np.concatenate([r if k == 0 else r[1:] for k, r in enumerate(rows)])
    joined = np.concatenate([deviation[k] if k == 0 else deviation[k][1:] for k in range(n_bays)])
    middle = 0.5 * (stations[:-1] + stations[1:])
    fig = _figure(10.0, 9.0)
    ax_map, ax_err, ax_ten = fig.subplots(3, 1, sharex=True, height_ratios=(1.4, 1.0, 1.0))
    limit = float(np.max(np.abs(joined))) or 1.0
    mesh = ax_map.pcolormesh(y, np.arange(n_contour), joined.T, cmap="RdBu_r", vmin=-limit, vmax=limit,
                             shading="nearest")
    fig.colorbar(mesh, ax=ax_map, label="distance / local chord (+ outside)")
    for s in stations:
        ax_map.axvline(s, color="0.4", lw=0.3)
    ax_map.set_ylabel("contour node\n(TE, upper, LE, lower)")
    ax_err.plot(middle, result.initial_bay_rms_error, "o--", color="0.5", ms=3, label="rms, start")
    ax_err.plot(middle, result.bay_rms_error, "o-", color="C0", ms=3, label="rms, design")
    ax_err.plot(middle, result.bay_max_error, "s-", color="C3", ms=3, label="max, design")
    ax_err.set_yscale("log")
    ax_err.set_ylabel("distance / local chord")
    ax_err.grid(alpha=0.3, which="both")
    ax_err.legend(**_OUTSIDE)
    ax_ten.plot(middle, result.bay_min_tension, "o-", color="C2", ms=3, label="min fibre tension")
    ax_ten.plot(middle, result.bay_max_tension, "s-", color="C1", ms=3, label="max fibre tension")
    floor = result.constraint_values.get("min_tension_floor")
    if floor is not None:
        ax_ten.axhline(floor, color="0.3", ls="--", lw=1.0, label=f"floor {floor:g} N/m")
    ax_ten.set_yscale("symlog", linthresh=10.0)
    ax_ten.set_ylim(*_symlog_limits([result.bay_min_tension, result.bay_max_tension, [floor or 0.0]], 10.0))
    ax_ten.set_ylabel("tension, N/m")
    ax_ten.set_xlabel("span station y, m (ribs: grey lines above)")
    ax_ten.grid(alpha=0.3, which="both")
    ax_ten.legend(**_OUTSIDE)
    status = "success" if result.success else "not a success"
    bays = "1 bay" if n_bays == 1 else f"{n_bays} bays"
    if result.variables:
        what = (f"rms {result.initial_rms_error:.3e} -> {result.rms_error:.3e} of the local chord, {status} "
                f"({result.method}, {result.solves} wing solves)")
    else:
        what = f"rms {result.rms_error:.3e} of the local chord (a single equilibrium)"
    fig.suptitle(f"{bays} at {_kpa(float(result.parameters.pressure))}: {what}")
    return fig


def plot_tolerance(section: dict, linear_rms, sampled_rms=None):
    """The tolerance analysis: the budget (or each source's share) and the distribution of the rms.

    Left: with a shape spec, the largest multiple of each given tolerance that
    alone keeps 95% of wings within the spec, and the common multiple of all
    (1 is the tolerance as given; a bar past 1 has room to spare); without
    one, each source's share of the rms's variance. Right: the linearised
    model's distribution of the wing's rms distance (mm), the Monte Carlo
    samples' histogram beside it, the spec and the nominal.

    Args:
        section: ``summary["tolerance"]`` (`inverse_design.tolerance.ToleranceAnalysis.summary`).
        linear_rms: draws of the rms from the linearised model, mm.
        sampled_rms: the Monte Carlo samples' rms, mm (None: none).

    Returns:
        A `matplotlib.figure.Figure`.
    """
    fig = _figure(11.0, 4.2)
    left, right = fig.subplots(1, 2)
    budget = section.get("budget")
    if budget is not None:
        names = list(budget["sources"]) + ["all together"]
        scales = [budget["sources"][n]["scale"] for n in budget["sources"]] + [budget["common_scale"]]
        known = [s for s in scales if s is not None and s > 0] + [1.0]
        cap, base = max(known) * 2.0, min(known) / 3.0  # (a log axis: the bars start at base)
        shown = [cap if s is None else max(s, base) for s in scales]
        colours = ["C2" if s is None or s >= 1 else "C3" for s in scales]
        bars = left.barh(names, [v - base for v in shown], left=base, color=colours)
        left.set_xscale("log")
        for bar, scale in zip(bars, scales):
            text = "no limit" if scale is None else "none" if scale == 0 else f"x{scale:.3g}"
            left.text(bar.get_x() + bar.get_width(), bar.get_y() + bar.get_height() / 2, f" {text}", va="center",
                      fontsize="small")
        left.axvline(1.0, color="black", lw=1.0, ls="--", label="as given")
        left.set_xlim(base, cap * 3.0)
        from matplotlib.ticker import FuncFormatter, NullFormatter

        left.xaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
        left.xaxis.set_minor_formatter(NullFormatter())
        left.set_xlabel("largest multiple of the given tolerance (red: tighten)")
        missed = "" if budget["met_at_nominal"] else " (the nominal design misses it)"
        left.set_title(f"budget: 95% of wings within {budget['spec']:g} mm rms{missed}", fontsize="medium")
        left.legend(fontsize="small", loc="lower right")
        left.invert_yaxis()
    else:
        shares = section["shares"]["rms"]
        left.barh(list(shares), [100 * v for v in shares.values()], color="C0")
        left.set_xlabel("share of the rms distance's variance, %")
        left.set_title("sources of scatter", fontsize="medium")
        left.invert_yaxis()
    linear_rms = np.asarray(linear_rms, np.float64)
    values = [linear_rms] + ([] if sampled_rms is None else [np.asarray(sampled_rms, np.float64)])
    finite = np.concatenate([v[np.isfinite(v)] for v in values])
    bins = np.linspace(finite.min(), finite.max(), 41) if finite.size and np.ptp(finite) > 0 else 20
    right.hist(linear_rms, bins=bins, density=True, histtype="step", color="C0", lw=1.6,
               label=f"first order (p95 {section['linear']['rms']['p95']:.3g} mm)")
    if sampled_rms is not None and np.isfinite(values[1]).any():
        right.hist(values[1][np.isfinite(values[1])], bins=bins, density=True, alpha=0.4, color="C1",
                   label=f"{section['samples']} samples (p95 {section['sampled']['rms']['p95']:.3g} mm)")
    if budget is not None:
        right.axvline(budget["spec"], color="C3", lw=1.4, label=f"spec {budget['spec']:g} mm")
        right.axvline(budget["nominal_rms"], color="black", lw=1.0, ls=":", label="nominal")
    right.set_xlabel("rms distance of the wing from its target, mm")
    right.set_ylabel("density")
    right.legend(fontsize="small", loc="best")
    right.grid(alpha=0.3)
    return fig


def plot_cut_fields(arc: np.ndarray, span_prestrain: np.ndarray, contour_prestrain: np.ndarray,
                    leading_edge: float | None = None):
    """One figure of a wing's per-bay cut fields: the local prestrain along the contour, bay by bay.

    Two images side by side, the span fibres' local prestrain and the contour
    fibres' (`rib_design.cut_lengths`: the uniform prestrain plus the bay's
    cut field, `forward_solver.model.cut_field`), bays on the vertical axis (root at
    the bottom) and the contour arc on the horizontal one, on one colour
    scale. Whatever the number of bays, one figure.

    Args:
        arc: ``(n_bays, n_contour)`` each contour node's arc length from the
            trailing edge at the bay's root rib, as a fraction of the perimeter.
        span_prestrain: ``(n_bays, n_contour)`` the local prestrain of the span
            fibre through each node (dimensionless).
        contour_prestrain: ``(n_bays, n_contour)`` that of the contour edge from
            each node to the next (dimensionless).
        leading_edge: the leading edge's arc fraction, marked (None: not marked).

    Returns:
        A `matplotlib.figure.Figure`.
    """
    arc = np.asarray(arc, np.float64)
    fields = (np.asarray(span_prestrain, np.float64), np.asarray(contour_prestrain, np.float64))
    n_bays = arc.shape[0]
    bays = np.broadcast_to(np.arange(n_bays, dtype=np.float64)[:, None], arc.shape)
    low = min(float(np.min(f)) for f in fields)
    high = max(float(np.max(f)) for f in fields)
    if not high > low:  # (a uniform field: a visible range around it)
        low, high = low - 1e-4, high + 1e-4
    fig = _figure(11.0, 3.0 + 0.06 * min(n_bays, 80))
    axes = fig.subplots(1, 2, sharey=True)
    for ax, field, fibre in zip(axes, fields, ("span", "contour")):
        mesh = ax.pcolormesh(arc, bays, field, cmap="viridis", vmin=low, vmax=high, shading="nearest")
        if leading_edge is not None:
            ax.axvline(leading_edge, color="w", lw=0.8, ls="--")
        ax.set_title(f"{fibre} fibres")
    from matplotlib.ticker import MaxNLocator

    axes[0].yaxis.set_major_locator(MaxNLocator(integer=True))
    axes[0].set_ylabel("bay (root to tip)")
    fig.supxlabel("contour arc / perimeter, from the trailing edge over the upper surface (leading edge dashed)")
    fig.colorbar(mesh, ax=axes, label="local prestrain")
    fig.suptitle(f"cut fields of {n_bays} bays: local prestrain {low:.4f} to {high:.4f}")
    return fig
