"""What the command prints when a run ends: a few lines from its summary."""

from __future__ import annotations

import re
from pathlib import Path

__all__ = ["WROTE_NAMES", "describe", "grouped_names", "marker_line", "number_text", "refined_line", "sensitivity_lines",
           "start_violation_line", "tolerance_lines", "wrote_line"]

#: Units of the amounts in ``constraints.violated`` (tension limits: N/m).
_VIOLATION_UNITS = {"rib_min_thickness": " of the starting thickness", "rib_min_radius": " chord"}


def _amount_text(name: str, amount) -> str:
    """``"by 12.3 N/m"``; a per-bay (per-rib) amount ``{where: amount}`` as ``"by 12.3 N/m in bay 0, ..."``."""
    unit = _VIOLATION_UNITS.get(name, " N/m")
    if isinstance(amount, dict):
        return ", ".join(f"by {v:.4g}{unit} in {where}" for where, v in amount.items())
    return f"by {amount:.4g}{unit}"


def start_violation_line(summary: dict) -> str | None:
    """The console line of a design whose start broke a limit (``constraints.violated_at_start``),
    or None when the start met every limit.

    The start's error is then no fair yardstick: a design that meets the
    limit may have a larger error than the infeasible start, and the line
    says so rather than leave a worse error unexplained. A wing's amounts
    are given per bay (``violated_at_start_where``).
    """
    constraints = summary["constraints"]
    at_start = constraints.get("violated_at_start") or {}
    if not at_start:
        return None
    where = constraints.get("violated_at_start_where") or {}
    several = summary.get("case", {}).get("n_bays", 1) > 1
    broke = "; ".join(f"{name} {_amount_text(name, where[name] if several and name in where else amount)}"
                      for name, amount in at_start.items())
    err = summary["errors"]
    if constraints["violated"]:
        verdict = "the design still breaks a limit (above)"
    elif err["after"]["rms"] > err["before"]["rms"]:
        verdict = ("the design is feasible but its error is larger than the infeasible start's "
                   f"({err['after']['rms']:.3e} against {err['before']['rms']:.3e} chord)")
    else:
        verdict = "the design is feasible"
    return f"  note: the start broke {broke}; {verdict}"

#: Below this size a design value is zero to rounding: the optimiser's scaled variables are
#: ``lower + u (upper - lower)``, and a value at a bound of zero comes back as a few 1e-19 to 1e-12 (a
#: prestrain of 6e-13 at its bound of 0 was printed so); no design value means anything at 1e-9 (a
#: prestrain or a rib shape coefficient of a billionth; a pressure in Pa, a rib scale near 1).
_ZERO = 1e-9


def number_text(value: float, digits: int = 6) -> str:
    """``value`` with ``digits`` significant digits; a value that is zero to rounding (below `_ZERO` in
    size, far below any design value's meaning) as ``0``."""
    return "0" if abs(value) < _ZERO else f"{value:.{digits}g}"


def _value_text(name: str, value) -> str:
    """``name value`` for the console (a vector variable as its rounded components)."""
    if isinstance(value, list):
        return f"{name} [{', '.join('0' if abs(v) < _ZERO else f'{v:.4f}' for v in value)}]"
    return f"{name} {number_text(value)}" + (" Pa" if name == "pressure" else "")


def refined_line(results: dict) -> str | None:
    """After ``--refine``: the two grids and how far each variable moved (``results["grid_change"]``)."""
    grid = results.get("grid_change")
    if not grid:
        return None
    moves = ", ".join(f"{n} {c:+.2%}" if n == "pressure" else f"{n} {c:+.4f}"
                      for n, c in grid["change"].items())  # a vector: its largest move
    return (f"  refined {grid['grids'][0][0]}x{grid['grids'][0][1]} -> {grid['grids'][1][0]}x"
            f"{grid['grids'][1][1]}: {moves}; rms {grid['rms_error'][0]:.3e} -> {grid['rms_error'][1]:.3e}")


def _count(n: int, word: str) -> str:
    """``"1 iterate"``, ``"3 iterates"``: ``n`` and ``word``, plural unless one (``word`` names one)."""
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


#: What the errors of each objective are: the rows they are measured over.
_ROWS = {"mid_bay": "the mid-bay section", "average": "every row from rib to rib", "worst": "the worst row",
         "robust": "every row from rib to rib"}


def _case_line(summary: dict) -> str:
    """The first line: the targets, the bays, the grid and the objective (one equilibrium: the rows measured)."""
    case, err = summary["case"], summary["errors"]
    ribs, n = case["ribs"], case["n_bays"]
    targets = list(dict.fromkeys(r["target"] for r in ribs))
    chords = ribs[0]["chord_m"], ribs[-1]["chord_m"]
    chord = f"{chords[0]:g} m chord" if chords[0] == chords[1] else f"{chords[0]:g} to {chords[1]:g} m chord"
    span = ribs[-1]["station_m"] - ribs[0]["station_m"]
    bays = "one bay" if n == 1 else f"a wing of {n} bays"
    per_bay = "" if n == 1 else " per bay"
    objective = (f"errors over {_ROWS[err['objective']]}" if summary["mode"] == "evaluate"
                 else f"{err['objective']} objective")
    return (f"{' to '.join(targets)}, {bays} ({chord}, {span:g} m span), {case['grid'][0]}x{case['grid'][1]} "
            f"grid{per_bay}, {objective}")


def describe(summary: dict) -> list[str]:
    """The console lines of a finished run, of one bay or several."""
    case, res, err = summary["case"], summary["results"], summary["errors"]
    v = res["values"]
    several = case["n_bays"] > 1
    lines = [_case_line(summary)]
    trailing = case.get("trailing_edge") or {}
    for change in trailing.get("changed", []):
        source = change.get("file") or change["section"]
        lines.append(f"  rib {change['rib']} ({source}): trailing edge {'closed' if change['gap_after'] == 0 else 'opened'}"
                     f", gap {change['gap_before']:.3g} -> {change['gap_after']:.3g} chord over the last "
                     f"{change['blend']:.0%} of chord (--trailing-edge {trailing['option']})")
    law = (case.get("fabric") or {}).get("law") or {}
    if "fit_error_n_per_m" in law:  # (a fitted law: which, how well it fits, and the strains it was tested over)
        rms, tested, strains = law["fit_error_n_per_m"]["rms"], law["tested_strain"], res.get("fibre_strains") or {}
        reached = "".join(f", {d} {100 * strains[d][0]:.3g}% to {100 * strains[d][1]:.3g}%" for d in ("span", "chord")
                          if d in strains)
        lines.append(f"  fabric: law fitted to {Path(law['source']).name} (degree {law['degree']}, warp along the "
                     f"{law['warp']}; fit rms warp {rms['warp']:.3g}, weft {rms['weft']:.3g} N/m; tested warp "
                     f"{100 * tested['warp'][0]:.3g}% to {100 * tested['warp'][1]:.3g}%, weft {100 * tested['weft'][0]:.3g}%"
                     f" to {100 * tested['weft'][1]:.3g}%); strains reached{reached or ' (not measured)'}")
    unit = "of the local chord" + (" (area-weighted)" if several else "")
    rows = _ROWS[err["objective"]]
    if summary["mode"] == "evaluate":
        eq = res["equilibrium"]
        lines.append(f"  equilibrium at {number_text(v['pressure_pa'])} Pa: {eq['result']} in {_count(eq['steps'], 'step')}")
        lines.append(f"  error over {rows}: rms {err['after']['rms']:.3e}, max {err['after']['max']:.3e} {unit} "
                     f"(mid-bay rms {err['mid_bay_after']['rms']:.3e}, max {err['mid_bay_after']['max']:.3e})")
    else:
        per_bay = res.get("cut_patterns") is not None
        per_rib = res.get("rib_shapes") is not None
        chosen = ", ".join(_value_text(n, v['pressure_pa' if n == 'pressure' else n]) for n in res["variables"]
                           if not (n == "rib_shape" and per_rib) and not (n == "cut_pattern" and per_bay))
        if per_rib:
            chosen += f", a rib shape per rib (rib_K.dat; largest coefficient {res['rib_shape_max_abs']:.3g})"
        if per_bay:
            local = res["cut_pattern_local"]
            chosen += (f", a cut field per bay (bay_K_cut_pattern.csv; local prestrain span {local['span'][0]:.4f}.."
                       f"{local['span'][1]:.4f}, contour {local['chord'][0]:.4f}..{local['chord'][1]:.4f})")
        lines.append(f"  {res['method']}: {chosen.lstrip(', ')}")
        lines.append(f"  error over {rows}: rms {err['before']['rms']:.3e} -> {err['after']['rms']:.3e}, "
                     f"max {err['before']['max']:.3e} -> {err['after']['max']:.3e} {unit}")
    if several:
        for bay in summary["bays"]:
            before = f"{bay['errors_before']['rms']:.3e} -> " if bay.get("errors_before") else ""
            lines.append(f"  bay {bay['bay']}: {bay['result']}, rms {before}{bay['errors_after']['rms']:.3e}, "
                         f"max {bay['errors_after']['max']:.3e}, tension {bay['min_tension_n_per_m']:.4g} to "
                         f"{bay['max_tension_n_per_m']:.4g} N/m")
    if summary["mode"] != "evaluate":
        constraints = summary["constraints"]
        violated = (constraints["violated_where"] if several else constraints["violated"]) or {}
        shown = ", ".join(f"{name} {_amount_text(name, amount)}" for name, amount in violated.items())
        solves = _count(res["forward_solves"], "wing solve" if several else "forward solve")
        lines.append(f"  active constraints: {', '.join(grouped_names(constraints['active'])) or 'none'}; violated: "
                     f"{shown or 'none'}; {_count(res['iterations'], 'iterate')}, {solves}")
        values = constraints.get("values") or {}
        if values.get("min_tension_p5") is not None:  # (a robust design: the limit held at each cell's quantile)
            lines.append(f"  robust tension limit: each cell's tension at its own 5th percentile, least "
                         f"{values['min_tension_p5']:.4g} N/m (a cell's scatter, not the whole wing's)")
        start_line = start_violation_line(summary)
        if start_line:
            lines.append(start_line)
        refined = refined_line(res)
        if refined:
            lines.append(refined)
        if res.get("success"):  # (a failed design's multipliers price nothing it reached)
            lines += sensitivity_lines(summary.get("sensitivity"))
    for bay in summary["bays"]:
        aero = bay.get("aero")
        if aero:
            worst, alphas = aero["max_abs_difference"]["mid_bay"], aero["alphas_deg"]
            where = f" of bay {bay['bay']}" if several else ""
            lines.append(f"  aerodynamics{where} at Re {aero['reynolds']:.3g}, {alphas[0]:g} to {alphas[-1]:g} deg: "
                         f"mid-bay max |dCL| {worst['cl']:.3g}, |dCD| {worst['cd']:.3g}, |dCM| {worst['cm']:.3g} "
                         f"(confidence >= {aero['min_confidence']['mid_bay']:.2f})")
    if summary.get("tolerance"):
        lines += tolerance_lines(summary["tolerance"])
    if summary.get("marker"):
        lines.append(marker_line(summary["marker"]))
    wrinkled = res["equilibrium"]["wrinkled_fraction"]
    if wrinkled:
        lines.append(f"  wrinkled cells: {100 * wrinkled:.1f}% of the skin")
    timings = summary["timings_s"]
    memory = timings.get("peak_memory_mb")
    memory = f", peak memory {memory:.0f} MB" if isinstance(memory, (int, float)) and memory == memory else ""
    lines.append(f"  {timings['total']:.1f} s (report {timings['report']:.1f} s{memory})")
    lines.append(wrote_line(summary))
    return lines


def marker_line(marker: dict) -> str:
    """The marker's line (``summary["marker"]``): the roll, the length used, the utilisation, the nesting."""
    return (f"  marker: {marker['panels']} panels on a {marker['roll_width_mm']:g} mm roll (warp along the "
            f"{marker['warp']}), {marker['length_mm'] / 1000:.3f} m used, utilisation {marker['utilisation']:.1%}, "
            f"nested by {marker['nester']} in {marker['seconds']:.0f} s ({marker['ended']}; marker.dxf)")


#: Most file names the "wrote" line lists; beyond, it gives their count (summary.json lists them all).
WROTE_NAMES = 20


def wrote_line(summary: dict) -> str:
    """``wrote OUT (the files)``, or for many files (a wing's patterns) how many, with summary.json's list."""
    files = summary["files"]
    if len(files) <= WROTE_NAMES:
        return f"wrote {summary['out']} ({', '.join(files)})"
    return f"wrote {summary['out']} ({len(files)} files; summary.json lists them under \"files\")"


#: An active bound's name: a variable, its component (a rib's or a bay's row and a coefficient), its side.
_BOUND = re.compile(r"^(?P<name>\w+)(?P<index>(\[\d+\])+)(?P<side><=upper|>=lower)$")


def grouped_names(active: list) -> list:
    """The active constraints, the components of a vector variable at one side of their bounds grouped:
    ``cut_pattern<=upper (20 coefficients)`` in place of twenty ``cut_pattern[i][j]<=upper``."""
    groups, out = {}, []
    for name in active:
        match = _BOUND.match(name)
        key = (match["name"], match["side"]) if match else name
        if key not in groups:
            groups[key] = []
            out.append(key)
        groups[key].append(name)
    return [key if isinstance(key, str) else
            (groups[key][0] if len(groups[key]) == 1 else f"{key[0]}{key[1]} ({len(groups[key])} coefficients)")
            for key in out]


#: Fewer Monte Carlo samples than this place their 95th percentile too roughly to quote without saying so
#: (its standard error is about sqrt(0.05 * 0.95 / n) of the probability: 0.02 at 100).
FEW_SAMPLES = 100


def tolerance_lines(section: dict) -> list[str]:
    """Two lines of the tolerance analysis (`inverse_design.tolerance.ToleranceAnalysis.summary`): the
    rms distance and least tension to first order (and sampled), then the budget or the main sources."""
    lin = section["linear"]
    text = (f"  tolerances: rms distance {lin['rms']['mean']:.3g} +- {lin['rms']['std']:.2g} mm, p95 "
            f"{lin['rms']['p95']:.3g} mm (first order)")
    sampled = section.get("sampled")
    if sampled:
        failed = f", {sampled['failed']} failed" if sampled["failed"] else ""
        few = (f"; too few to place a 95th percentile, which needs about {FEW_SAMPLES}"
               if sampled["count"] < FEW_SAMPLES else "")
        text += f", {sampled['rms']['p95']:.3g} mm ({sampled['count']} samples{failed}{few})"
    text += f"; the wing's least tension, 5th percentile {lin['min_tension']['p5']:.4g} N/m"
    budget = section.get("budget")
    if budget is None:
        shares = sorted(section["shares"]["rms"].items(), key=lambda item: -item[1])
        second = "  scatter of the rms from: " + ", ".join(f"{name} {100 * v:.0f}%" for name, v in shares[:3])
    elif not budget["met_at_nominal"]:
        second = (f"  budget: the nominal design's rms {budget['nominal_rms']:.3g} mm already misses the spec "
                  f"{budget['spec']:g} mm; no tolerance meets it")
    else:
        common = budget["common_scale"]
        scale = "any scale" if common is None else f"x{common:.3g}"
        alone = ", ".join(f"{name} {entry['text'] or 'any'}" for name, entry in budget["sources"].items())
        second = (f"  budget for 95% within {budget['spec']:g} mm rms: all tolerances {scale}; each alone up to "
                  f"{alone}")
    return [text, second]


#: How the console shows a value of each variable: ``(unit shown, factor from the record's unit)``.
_SHOWN = {"pressure": (" kPa", 1e-3), "prestrain_span": ("%", 100.0), "prestrain_chord": ("%", 100.0),
          "cut_pattern": ("%", 100.0), "rib_shape": (" chord", 1.0),
          "min_tension": (" N/m", 1.0), "max_tension": (" N/m", 1.0), "rib_min_radius": (" chord", 1.0)}


def _shown(name: str, value: float) -> str:
    """``value`` of ``name`` as the console shows it (``1 kPa``, ``2%``, ``0.8``)."""
    unit, factor = _SHOWN.get(name, ("", 1.0))
    return f"{number_text(value * factor, 3)}{unit}"


def sensitivity_lines(section: dict | None) -> list[str]:
    """What held the design where it is (`inverse_design.sensitivity`, the summary's ``sensitivity``): one
    line per active bound or limit with its shadow price, then one per scalar variable at a bound or with
    a wide window, in words."""
    if not section:
        return []
    lines = []
    for price in section["prices"]:
        name = price.get("variable") or price["limit"]
        relation = ">=" if price["side"] == "lower" else "<="
        count = f" ({price['components']} coefficients)" if price.get("components", 1) > 1 else ""
        move = "lowering" if price["side"] == "lower" else "raising"
        lines.append(f"  {name} {relation} {_shown(name, price['value'])}{count}: shadow price "
                     f"{price['relaxed_gain']:.3g} chord of rms per {price['per']} ({price['percent']:.2g}% of it): "
                     f"{move} it lowers the rms at that rate at first")
    for window in section["windows"]:
        name, side = window["name"], window["at_bound"]
        if window["variable"] != name or not (side or window["wide"]):
            continue  # (a vector's components: the record has them)
        span = (f"any value from {_shown(name, window['low'])} to {_shown(name, window['high'])} keeps the rms "
                f"within {section['window']:.0%}")
        limits = [f"{end} ends it {where}" for end, where in ((window["low_end"], "below"), (window["high_end"], "above"))
                  if end not in ("rms", "lower bound", "upper bound")]  # a linearised limit row
        if limits:
            span += f" ({', '.join(limits)})"
        freed = f"freed from it, the rms would fall by {'only ' if window['decided_by_bound'] else ''}" \
                f"{100 * window['free_gain']:.2g}%"
        if side and window["decided_by_bound"]:
            verdict = f"the {side} bound decides it ({freed})"
        elif side:
            verdict = f"the {side} bound holds it back ({freed})"
        else:
            verdict = "the optimum is flat"
        lines.append(f"  {name}: {span}; {verdict}" if window["wide"] else f"  {name}: {verdict}; {span}")
    return lines
