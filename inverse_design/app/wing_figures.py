"""Figures of a wing and of its design: the overview of every bay, the cut fields, the optimiser's history,
the aerodynamic comparison and the tolerance analysis.

Built as `bay_figures`' are (`matplotlib.figure.Figure` objects without
pyplot); `folder.write_report` saves them into the output folder.
"""

from __future__ import annotations

import numpy as np

from .bay_figures import RIB_STYLE, SKIN_STYLE, TARGET_STYLE, kpa, new_figure

__all__ = ["plot_aero", "plot_cut_fields", "plot_history", "plot_tolerance", "plot_wing_overview"]


#: Each variable's axis label, its factor from SI and the unit of a value on that axis.
_UNITS = {"pressure": ("pressure, kPa", 1e-3, " kPa"), "prestrain_span": ("span prestrain, %", 100.0, "%"),
          "prestrain_chord": ("chord prestrain, %", 100.0, "%"),
          "rib_thickness_scale": ("rib thickness scale\n(x starting thickness)", 1.0, " x starting thickness"),
          "rib_chord_scale": ("rib chord scale\n(x starting chord)", 1.0, " x starting chord"),
          "rib_shape": ("rib shape coefficients\n(chord)", 1.0, " chord"),
          "cut_pattern": ("cut pattern coefficients, %", 100.0, "%")}
#: A legend beside its axes, outside them: it never covers a curve.
_OUTSIDE = dict(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize="small")


def plot_history(result, bounds: dict | None = None):
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
    fig = new_figure(10.0, 2.4 + 1.9 * len(names))
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
    styles = {"target": dict(label=f"target {comparison.target_name}", **TARGET_STYLE),
              "bay_average": dict(label="bay-average section", ls="--", **RIB_STYLE),
              "mid_bay": dict(label="mid-bay section", **SKIN_STYLE)}
    differences = {"mid_bay": comparison.mid_bay_difference, "bay_average": comparison.bay_average_difference}
    fig = new_figure(12.0, 7.0)
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


def _per_bay(stations, values) -> tuple[np.ndarray, np.ndarray]:
    """``(x, y)`` of a per-bay value as a line level across each bay, from rib to rib (a staircase)."""
    return np.repeat(np.asarray(stations, np.float64), 2)[1:-1], np.repeat(np.asarray(values, np.float64), 2)


def plot_wing_overview(result, deviation: np.ndarray):
    """One figure of every bay of a wing design: the deviation over the whole skin and the per-bay figures.

    Top: the signed normal distance of every node from its row's target
    (fractions of the local chord, ``deviation`` of `measures.wing_deviation`)
    over the span (rows of all bays joined, y from the root rib) and around
    the contour (node index: trailing edge, upper surface, leading edge,
    lower surface), its colour bar beside it. Middle: each bay's RMS and
    largest distance, before and after; bottom: each bay's smallest and
    largest fibre tension at the design, with the tension floor: a bay's value
    is drawn as a level line from its root rib to its tip rib (one bay: one
    line across the bay, not a dot).

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
    fig = new_figure(10.0, 9.0)
    ax_map, ax_err, ax_ten = fig.subplots(3, 1, sharex=True, height_ratios=(1.4, 1.0, 1.0))
    limit = float(np.max(np.abs(joined))) or 1.0
    mesh = ax_map.pcolormesh(y, np.arange(n_contour), joined.T, cmap="RdBu_r", vmin=-limit, vmax=limit,
                             shading="nearest")
    # beside the map, in the column of the other panels' legends (a colour bar given the map's axes
    # went to the figure's far edge, past those legends)
    fig.colorbar(mesh, cax=ax_map.inset_axes([1.01, 0.0, 0.025, 1.0]), label="distance / local chord\n(+ outside)")
    for s in stations:
        ax_map.axvline(s, color="0.4", lw=0.3)
    ax_map.set_ylabel("contour node\n(TE, upper, LE, lower)")
    ax_err.plot(*_per_bay(stations, result.initial_bay_rms_error), "--", color="0.5", label="rms, start")
    ax_err.plot(*_per_bay(stations, result.bay_rms_error), "-", color="C0", lw=1.6, label="rms, design")
    ax_err.plot(*_per_bay(stations, result.bay_max_error), "-.", color="C3", lw=1.6, label="max, design")
    ax_err.set_yscale("log")
    ax_err.set_ylabel("distance / local chord")
    ax_err.grid(alpha=0.3, which="both")
    ax_err.legend(**_OUTSIDE)
    ax_ten.plot(*_per_bay(stations, result.bay_min_tension), "-", color="C2", lw=1.6, label="min fibre tension")
    ax_ten.plot(*_per_bay(stations, result.bay_max_tension), "-.", color="C1", lw=1.6, label="max fibre tension")
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
    fig.suptitle(f"{bays} at {kpa(float(result.parameters.pressure))}: {what}")
    return fig


def _cannot_meet(ax, budget: dict) -> None:
    """The budget's panel where the nominal design already misses the spec: a statement, no bars."""
    ax.set_axis_off()
    ax.set_title(f"budget: 95% of wings within {budget['spec']:g} mm rms", fontsize="medium")
    ax.text(0.5, 0.5, f"The spec cannot be met by any tolerance.\n\nThe design itself, built exactly,\n"
            f"is {budget['nominal_rms']:.3g} mm rms from its target:\nalready above the {budget['spec']:g} mm "
            "spec.\nNo tolerance, however tight, brings\n95% of wings within it.\n\n"
            f"Loosen --shape-spec to more than {budget['nominal_rms']:.3g} mm,\nor improve the design.",
            ha="center", va="center", transform=ax.transAxes, fontsize="medium", wrap=True,
            bbox={"boxstyle": "round", "facecolor": "#fdecea", "edgecolor": "C3"})


def _budget_bars(ax, budget: dict) -> None:
    """The budget's bars: for each source alone, and all together, how far the given tolerance may be
    scaled with 95% of wings within the spec (a log axis), each bar with the scatter it allows."""
    from matplotlib.ticker import FuncFormatter, NullFormatter

    sources = budget["sources"]
    names = list(sources) + ["all together"]
    scales = [sources[n]["scale"] for n in sources] + [budget["common_scale"]]
    known = [v for v in scales if v is not None and v > 0] + [1.0]
    cap, base = max(known) * 2.0, min(known) / 3.0  # (a log axis: the bars start at base)
    shown = [cap if v is None else max(v, base) for v in scales]
    colours = ["C2" if v is None or v >= 1 else "C3" for v in scales]
    bars = ax.barh(names, [v - base for v in shown], left=base, color=colours)
    ax.set_xscale("log")
    for bar, name, scale in zip(bars, names, scales):
        if scale is None:
            text = "no limit: x1000 still meets the spec"
        elif name in sources:
            entry = sources[name]
            unit = "" if entry["unit"] == "%" else f" {entry['unit']}"
            text = f"x{scale:.3g}: {entry['text']}{unit} allowed (given {entry['given']}{unit})"
        else:
            text = f"x{scale:.3g} of every tolerance at once"
        ax.text(bar.get_x() + bar.get_width(), bar.get_y() + bar.get_height() / 2, f" {text}", va="center",
                fontsize="small")
    ax.axvline(1.0, color="black", lw=1.0, ls="--", label="x1: as given")
    ax.set_xlim(base, cap * 30.0)  # (room for the bars' words)
    ax.xaxis.set_major_formatter(FuncFormatter(lambda value, _: f"x{value:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("allowed scatter, times the given tolerance (green: room to spare; red: tighten to it)")
    ax.set_title(f"budget: 95% of wings within {budget['spec']:g} mm rms", fontsize="medium")
    ax.legend(fontsize="small", loc="lower right")
    ax.invert_yaxis()


def plot_tolerance(section: dict, linear_rms, sampled_rms=None):
    """The tolerance analysis: the budget (or each source's share) and the distribution of the rms.

    Left: with a shape spec, how far each given tolerance may be scaled,
    alone, with 95% of wings still within the spec, and all of them together
    (x1: as given; above 1 there is room to spare, below 1 the tolerance must
    be tightened to that multiple; each bar says the allowed scatter in the
    tolerance's unit). Where the nominal design already misses the spec, no
    tolerance meets it however tight: the panel says so instead of drawing
    bars. Without a spec: each source's share of the rms's variance. Right:
    the linearised model's distribution of the wing's rms distance (mm), the
    Monte Carlo samples' histogram beside it, the spec and the nominal.

    Args:
        section: ``summary["tolerance"]`` (`inverse_design.tolerance.ToleranceAnalysis.summary`).
        linear_rms: draws of the rms from the linearised model, mm.
        sampled_rms: the Monte Carlo samples' rms, mm (None: none).

    Returns:
        A `matplotlib.figure.Figure`.
    """
    fig = new_figure(11.0, 4.2)
    left, right = fig.subplots(1, 2)
    budget = section.get("budget")
    if budget is not None and not budget["met_at_nominal"]:
        _cannot_meet(left, budget)
    elif budget is not None:
        _budget_bars(left, budget)
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
    fig = new_figure(11.0, 3.0 + 0.06 * min(n_bays, 80))
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
