"""The one report writer: the summary of a design of N >= 1 bays and its output folder.

`write_report` turns a `DesignResult` (`optimise_pressure`, `optimise_wing`,
`evaluate_design`: one bay or several) into a folder, by one path whatever
the number of bays: a bay given by options and the same bay given as a
two-rib case file write the same files with the same summary keys.
``summary.json`` (`summarise`, `SCHEMA_VERSION`) holds ``schema``, ``mode``
("optimise", or "evaluate" for a single equilibrium), ``inputs``,
``warnings``, ``case`` (``n_bays``, ``ribs``, grid, trailing edges,
fabric), ``results``, ``errors`` (fractions of the local chord, before and
after, and at mid-bay), ``constraints`` (``violated``: the largest amount
per limit; ``violated_where``: the amount per bay or rib;
``violated_at_start``), ``timings_s``, ``history``, ``rib`` (a shaped
rib), ``patterns`` and ``bays``, the bay axis: one entry per bay (ribs,
span, chords, weight, targets, result code, steps, residual, errors before
and after, tensions, wrinkled fraction, cut lengths, and with ``aero`` its
aerodynamic comparison).

The folder, for any number of bays::

    summary.json                 the summary (above), with the files written and those skipped
    wing.npz                     every bay stacked: nodes (n_bays, n_span, n_contour, 3) m
                                 (each bay in its own frame, root rib at y = 0), tensions,
                                 wrinkled cells, deviation from the row targets, ribs, history
    skin.obj, skin.stl           the skin in one mesh (bays joined at their ribs, y from the root
                                 rib), metres
    wing_overview.png            every bay in one figure: the deviation over the whole skin,
                                 each bay's errors and tensions (`plots.plot_wing_overview`)
    cut_pattern_overview.png     a cut field per bay: every bay's local prestrain along the contour,
                                 span and contour fibres (`plots.plot_cut_fields`)
    bay_K_mid_bay_section.png    bay K's mid-bay section against its root rib and its target (for
                                 at most `PER_BAY_PLOTS` bays)
    bay_K_aero.png               with an aerodynamic comparison: bay K's lift, drag and moment
                                 against its target's (`plots.plot_aero`; at most `PER_BAY_PLOTS` bays)
    bay_K_cut_pattern.csv        bay K's cut lengths (`export.write_cut_pattern`)
    history.png                  the optimiser's iterates (not for a single equilibrium)
    pattern_bay_K_upper.dxf/.svg, pattern_bay_K_lower.dxf/.svg
                                 bay K's flat panels, cut-ready (1:1, mm; `app.cut_files`); a
                                 successful design only
    rib_K.dxf                    rib K's template at its chord (a successful design only)
    rib.dat                      the designed rib as a Selig file (one shape for every rib)
    rib_K.dat                    rib K's designed section (a shape per rib)

and for a single bay, on top of these::

    equilibrium.npz              the bay in full: nodes, tensions, wrinkled cells, held nodes,
                                 deviation, target, sections, cut lengths, parameters, history
                                 (`export.write_npz`)
    deviation.png                the deviation from the target over the whole bay (`plot_deviation`)
    tensions.png                 fibre tensions with the wrinkled cells marked (`plot_tensions`)
    rib_design.png               a shaped rib's template offset and thickness kept (`plot_rib_design`)

The folder is written by `export.staged_folder`: only the tool's own files
are replaced, nothing else in the folder is touched. The pattern files are
plain names in the folder (not a ``patterns/`` subfolder): the staging and
ownership rules (`export.written_files`) own plain files only.

Each figure is built in the calling process (where JAX may be called); the
command hands the built figures (pickled `matplotlib.figure.Figure` objects,
in `_SAVE_ORDER`) and then the DXF patterns to its `workers.ReportWorkers`
(worker processes started when it starts, which import matplotlib and ezdxf,
not JAX, while the design runs) to save; what they do not write, and every
file of a library caller's report, is written in the calling process.

A design that failed (``success`` false) gets no pattern files (the panels of
a design that breaks its limits or did not converge are not to be cut);
``skipped`` says so and the command exits 1. ``patterns=False``
(``--no-patterns``) leaves them out of any report.
"""

from __future__ import annotations

import dataclasses
import json
import math
import platform
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from forward_solver import Solution

from .workers import run_task, save_figure, saved_after
from .export import (check_output_folder, save_npz, staged_folder, write_cut_pattern, write_npz, write_obj,
                     write_selig, write_stl)
from .export import file_checksums
from .cut_files import write_bay_patterns
from ..objectives import WingTargets, distance_errors, same_section
from ..optimise import DesignResult
from .plots import (plot_aero, plot_cut_fields, plot_deviation, plot_history, plot_rib_design, plot_section,
                    plot_tensions, plot_tolerance, plot_wing_overview)
from ..rib_design import cut_lengths

__all__ = ["PER_BAY_PLOTS", "SCHEMA_VERSION", "ReportOptions", "mid_bay_targets", "peak_memory_mb", "summarise",
           "wing_deviation", "wing_nodes", "write_report"]

#: Version of the layout of ``summary.json``: 2 added ``schema``, ``case.n_bays``, the bay axis
#: ``bays`` and ``constraints.violated_where``; 3 is one layout for any number of bays: ``case.ribs``
#: and ``case.trailing_edge`` (no ``case.target``, ``rib``, ``chord_m``, ``rib_spacing_m``), errors in
#: fractions of the local chord, each bay's ``cut_lengths`` (and ``aero``) in its ``bays`` entry,
#: ``rib`` with every shaped rib.
SCHEMA_VERSION = 3

#: Resolution of the PNG files in the folder, dots per inch.
_DPI = 150
#: zlib level of the PNG figures: 3 writes them 0.07 s faster each than PIL's default 6, 13% larger.
_PNG_COMPRESSION = 3
#: A wing of at most this many bays also gets one mid-bay section plot per bay (more: only
#: ``wing_overview.png``, which shows every bay; a plot per bay took 0.3 s each and 15 s of a 40-bay report).
PER_BAY_PLOTS = 8
#: `matplotlib.figure.Figure.savefig`'s options for the PNG figures.
_SAVE_OPTIONS = {"dpi": _DPI, "pil_kwargs": {"compress_level": _PNG_COMPRESSION}}
#: The order in which the figures are handed to the workers, the slowest first (saving each on the
#: 2-core development machine, 2026-11-25: history 0.35-0.39 s, tensions 0.34 s, mid-bay section
#: 0.28 s, deviation 0.24 s; the wing overview, added later, last). Figures not named keep their place
#: after these.
_SAVE_ORDER = ("history.png", "tensions.png", "bay_0_mid_bay_section.png", "deviation.png", "wing_overview.png",
               "cut_pattern_overview.png")


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


def _checked(result) -> DesignResult:
    if isinstance(result, DesignResult):
        return result
    if isinstance(result, Solution):
        raise TypeError("a single bay's Solution needs its target and scene: write_report(out, solution, target, "
                        "scene=scene), or measure it with inverse_design.evaluate_design")
    raise TypeError(f"expected an inverse_design.DesignResult or a forward_solver.Solution, "
                    f"got {type(result).__name__}")


def _measured(solution: Solution, target, scene, objective: str | None) -> DesignResult:
    """A single bay's equilibrium as a `DesignResult` (`evaluate_design` on the solution as it is)."""
    from forward_solver import Wing

    from ..optimise import evaluate_design

    if target is None or scene is None:
        _checked(solution)
    wing = Wing.from_scene(scene) if getattr(scene.bay, "airfoil", None) is not None else None
    return evaluate_design(scene, target, objective=objective or "mid_bay", wing=wing, solution=solution)


def summarise(result: DesignResult, *, inputs: dict | None = None, timings: dict | None = None, aero=None,
              warnings: list | None = None) -> dict:
    """The summary of a design (or a single equilibrium) of N >= 1 bays, as `write_report` stores it.

    Args:
        result: a `DesignResult` (`optimise_pressure`, `optimise_wing`;
            `evaluate_design` for a single equilibrium).
        inputs: the caller's options (stored as given).
        timings: seconds, e.g. ``{"setup": ..., "optimisation": ...}``.
        aero: one `inverse_design.aero.AeroComparison` per bay (mid-bay and
            bay-average sections against the bay's mid-bay target), stored in
            the bay's entry as ``aero`` (`AeroComparison.as_dict`); None leaves it out.
        warnings: lines about the inputs (`inverse_design.plausibility`),
            stored as ``summary["warnings"]`` (default none).

    Returns:
        A JSON-ready dict (module docstring). Errors are fractions of the
        local chord; ``null`` marks a value that does not exist (no upper
        tension limit, no start for a single equilibrium).
    """
    result = _checked(result)
    design = bool(result.variables)
    sol = result.wing_solution
    fabric = sol.fabric if sol.fabric is not None else result.per_bay.scenes[0].fabric
    params = result.parameters.resolved(fabric).as_dict()
    specs = [r.get("section") for r in (inputs or {}).get("wing") or []]  # the case file's section specs
    solutions = [sol.bay_solution(k) for k in range(result.n_bays)]
    wing = result.wing
    summary = {
        "schema": SCHEMA_VERSION,
        "package": {"name": "inflatable-wing", "version": _version("inflatable-wing")},
        "versions": {"python": platform.python_version(), "jax": _version("jax"), "numpy": np.__version__},
        "mode": "optimise" if design else "evaluate",
        "inputs": dict(inputs or {}),
        "warnings": list(warnings or []),
        "case": {
            "n_bays": result.n_bays,
            "ribs": [{"section": section, "target": t.name, "chord_m": c, "station_m": y}
                     for section, t, c, y in zip(_rib_names(result), result.per_bay.targets,
                                                 *_chords_and_stations(result))],
            "grid": [sol.bays[0].n_span, sol.bays[0].n_contour],
            "trailing_edge": None if wing is None else {
                "option": wing.trailing_edge, "unit": "chord",
                "changed": [{"rib": c["index"], "section": wing.airfoils[c["index"]].name,
                             **({"file": specs[c["index"]]} if c["index"] < len(specs) else {}),
                             "gap_before": c["gap_before"], "gap_after": c["gap_after"], "blend": c["blend"]}
                            for c in wing.trailing_edge_changes]},
            "fabric": {"stiffness_span_n_per_m": fabric.stiffness_span,
                       "stiffness_chord_n_per_m": fabric.stiffness_chord, "poisson": fabric.poisson},
        },
        "results": {
            "success": bool(result.success), "message": result.message,
            "values": {"pressure_pa": params["pressure"], "prestrain_span": params["prestrain_span"],
                       "prestrain_chord": params["prestrain_chord"],
                       "rib_thickness_scale": params["rib_thickness_scale"],
                       "rib_chord_scale": params["rib_chord_scale"],
                       "stiffness_span_n_per_m": params["stiffness_span"],
                       "stiffness_chord_n_per_m": params["stiffness_chord"],
                       "rib_shape": params["rib_shape"], "cut_pattern": params["cut_pattern"]},
            "rib_shapes": None if result.per_bay.rib_shapes is None else np.asarray(result.per_bay.rib_shapes).tolist(),
            "rib_shape_max_abs": _largest_coefficient(result),
            "rib_limits": list(result.per_bay.rib_limits),
            "cut_patterns": (None if result.per_bay.cut_patterns is None
                             else np.asarray(result.per_bay.cut_patterns).tolist()),
            "cut_pattern_local": _local_prestrain_range(result),
            "variables": list(result.variables), "method": result.method if design else None,
            "iterations": len(result.history), "forward_solves": result.solves,
            "wall_time_s": result.wall_time,
            "grid_change": result.grid_change,  # after --refine: both grids and how far the design moved
            "equilibrium": _equilibrium(solutions),
        },
        "errors": {
            "unit": "fraction of the local chord", "objective": result.objective,
            "weighting": "bay planform area",
            "before": {"rms": result.initial_rms_error, "max": result.initial_max_error} if design else None,
            "after": {"rms": result.rms_error, "max": result.max_error},
            "mid_bay_after": _mid_bay_errors(result),
        },
        "constraints": {
            "active": list(result.active_constraints) if design else None,
            "violated": dict(result.violated_constraints) if design else None,
            "violated_where": _labelled(result.violated_where) if design else None,
            "violated_at_start": dict(result.violated_at_start) if design else None,
            "violated_at_start_where": _labelled(result.violated_at_start_where) if design else None,
            "values": dict(result.constraint_values), "unit": "N/m",
        },
        "timings_s": dict(timings or {}),
        "history": list(result.history),
        "bays": _bay_entries(result, solutions, aero),
    }
    if not design:
        summary["constraints"]["note"] = ("a single equilibrium: no limit is judged; the tensions are the "
                                          "fibres' unclamped tensions (below zero a fibre would be in "
                                          "compression: the cell wrinkles)")
    rib = _rib_entry(result)
    if rib is not None:
        summary["rib"] = rib
    return _jsonable(summary)


def _chords_and_stations(result: DesignResult) -> tuple:
    """The ribs' chords and span stations, m (a flat panel: its width from y = 0)."""
    if result.wing is not None:
        return tuple(result.wing.chords), tuple(result.wing.stations)
    bays = result.wing_solution.bays
    stations = np.concatenate([[0.0], np.cumsum([b.rib_spacing for b in bays])])
    return tuple([b.chord_root for b in bays] + [bays[-1].chord_tip]), tuple(stations)


def _rib_names(result: DesignResult) -> list:
    if result.wing is not None:
        return [af.name for af in result.wing.airfoils]
    return [b.name for b in result.wing_solution.bays] + [result.wing_solution.bays[-1].name]


def _labelled(where: dict) -> dict:
    """``{name: {"bay k" or "rib k": amount}}`` of ``{name: {k: amount}}``."""
    return {name: {f"{'rib' if name.startswith('rib_') else 'bay'} {k}": float(v) for k, v in amounts.items()}
            for name, amounts in where.items()}


def _equilibrium(solutions: list) -> dict:
    """The final solve of every bay in one entry: the worst result, the most steps, the largest residual."""
    failed = [s for s in solutions if not s.converged]
    return {"result": (failed[0] if failed else solutions[0]).result.name, "converged": not failed,
            "steps": max(int(s.steps) for s in solutions),
            "relative_residual": max(float(s.residual) for s in solutions),
            "method": solutions[0].method,
            "wrinkled_fraction": float(np.mean([s.wrinkled_fraction for s in solutions]))}


def _largest_coefficient(result: DesignResult) -> float | None:
    shapes = result.per_bay.rib_shapes if result.per_bay.rib_shapes is not None else result.parameters.rib_shape
    return None if shapes is None else float(np.max(np.abs(np.asarray(shapes))))


def _rib_entry(result: DesignResult) -> dict | None:
    """``summary["rib"]`` of a shaped rib (one shape for every rib, or one per rib), else None."""
    shared = result.parameters.rib_shape
    if result.per_bay.rib_shapes is None and shared is None:
        return None
    coefficients = np.asarray(shared if result.per_bay.rib_shapes is None else result.per_bay.rib_shapes, np.float64)
    return {"layout": "shared" if result.per_bay.rib_shapes is None else "per_rib",
            "coefficients": coefficients.tolist(), "terms_per_surface": int(coefficients.shape[-1]) // 2,
            "parametrisation": "outward z offset sqrt(x)(1-x) sum_k c_k B_k(x), chord-normalised; "
                               "upper-surface coefficients, then lower (forward_solver.model.rib_shape)",
            "limits": list(result.per_bay.rib_limits), "files": _rib_files(result)}


def _rib_files(result: DesignResult) -> list:
    """The designed ribs' Selig files: ``rib.dat`` for one shape on ribs of one section, else ``rib_K.dat``."""
    if result.wing is None or (result.per_bay.rib_shapes is None and result.parameters.rib_shape is None):
        return []
    if result.per_bay.rib_shapes is None and _same_sections(result):
        return ["rib.dat"]
    return [f"rib_{k}.dat" for k in range(len(result.wing.sections))]


def _same_sections(result: DesignResult) -> bool:
    sections = result.wing.sections
    return all(same_section(sections[0], s) for s in sections[1:])


def mid_bay_targets(result: DesignResult) -> list:
    """Each bay's target at mid-bay (`objectives.WingTargets.mid_bay_targets`)."""
    return WingTargets(result.wing_solution.bays, result.per_bay.targets, "mid_bay").mid_bay_targets()


def _mid_bay_errors(result: DesignResult) -> dict:
    """RMS (weighted by bay area) and largest distance of the bays' mid-bay sections from their targets."""
    sol = result.wing_solution
    distances = WingTargets(sol.bays, result.per_bay.targets, "mid_bay").deviation(sol.nodes)
    rms, largest = zip(*(distance_errors(d, "mid_bay") for d in distances))
    weights = np.asarray(result.per_bay.weights, np.float64)
    return {"rms": float(np.sqrt(np.sum(weights * np.square(rms)))), "max": float(np.max(largest))}


def le_recessions(result: DesignResult) -> np.ndarray:
    """``(n_bays,)`` how far each bay's mid-bay section's nose lies behind its target's (positive: pulled
    back by the prestressed skin), in fractions of the bay's chord at mid-bay."""
    sol = result.wing_solution
    out = []
    for k, (bay, target) in enumerate(zip(sol.bays, mid_bay_targets(result))):
        nodes = np.asarray(sol.nodes[k])
        s = 0.5 * (nodes.shape[0] - 1)  # (the mid-bay row, interpolated on an even n_span: Solution.section)
        i0 = min(int(np.floor(s)), nodes.shape[0] - 2)
        row = (1.0 - (s - i0)) * nodes[i0] + (s - i0) * nodes[i0 + 1]
        out.append(float(np.min(row[:, 0])) / (0.5 * (bay.chord_root + bay.chord_tip)) - float(np.min(target.x)))
    return np.array(out)


def _bay_entries(result: DesignResult, solutions: list, aero) -> list:
    """The bay axis of the summary: one entry per bay."""
    sol = result.wing_solution
    stations = _chords_and_stations(result)[1]
    design = bool(result.variables)
    recessions = le_recessions(result)
    entries = []
    for k, bay in enumerate(sol.bays):
        cuts = cut_lengths(sol.scene(k) if sol.fabric is not None else result.per_bay.scenes[k],
                           solutions[k].parameters)
        mid_row = bay.n_span // 2
        mid_chord, recession = 0.5 * (bay.chord_root + bay.chord_tip), float(recessions[k])
        entry = {
            "bay": k, "ribs": [k, k + 1], "span_m": [stations[k], stations[k + 1]],
            "chords_m": [bay.chord_root, bay.chord_tip], "weight": result.per_bay.weights[k],
            "targets": [result.per_bay.targets[k].name, result.per_bay.targets[k + 1].name],
            "result": result.bay_results[k], "steps": int(np.asarray(sol.steps)[k]),
            "relative_residual": float(np.asarray(sol.residual)[k]),
            "errors_before": ({"rms": result.per_bay.initial_rms_error[k], "max": result.per_bay.initial_max_error[k]}
                              if design else None),
            "errors_after": {"rms": result.per_bay.rms_error[k], "max": result.per_bay.max_error[k]},
            "min_tension_n_per_m": result.per_bay.min_tension[k], "max_tension_n_per_m": result.per_bay.max_tension[k],
            "wrinkled_fraction": solutions[k].wrinkled_fraction,
            "le_recession": {"chord_fraction": recession, "mm": 1e3 * recession * mid_chord},
            "cut_lengths": {
                "unit": "m", "file": f"bay_{k}_cut_pattern.csv",
                "contour_perimeter": {"root_rib": cuts["contour_cut_m"][0], "mid_bay": cuts["contour_cut_m"][mid_row],
                                      "tip_rib": cuts["contour_cut_m"][-1]},
                "span_fibre": {"min": float(np.min(cuts["span_cut_m"])), "max": float(np.max(cuts["span_cut_m"]))}},
        }
        if aero is not None:
            entry["aero"] = aero[k].as_dict()
        entries.append(entry)
    return entries


def _shared_names(result: DesignResult) -> tuple:
    """The design's variables shared by every bay (not per-rib shapes, not per-bay fields)."""
    return tuple(n for n in result.variables if not (n == "rib_shape" and result.per_bay.rib_shapes is not None)
                 and not (n == "cut_pattern" and result.per_bay.cut_patterns is not None))


def _local_prestrain_range(result: DesignResult) -> dict | None:
    """``{"span": [low, high], "chord": [low, high]}``: the local prestrain of the design's cut field(s)
    over the contour (every bay's for per-bay fields), or None for a uniform cut."""
    from forward_solver.model.cut_field import field_values

    p = result.parameters
    rows = [p.cut_pattern] if result.per_bay.cut_patterns is None else list(np.asarray(result.per_bay.cut_patterns))
    if rows[0] is None:
        return None
    s = np.linspace(0.0, 1.0, 401)
    span, chord = zip(*(field_values(s, p.prestrain_span, p.prestrain_chord, row) for row in rows))
    return {"span": [float(np.min(span)), float(np.max(span))],
            "chord": [float(np.min(chord)), float(np.max(chord))]}


class _Overview:
    """What `plots.plot_wing_overview` reads of a result, as plain values: it pickles for the report's
    workers (a `DesignResult` carries its scenes, solutions and targets)."""

    def __init__(self, result: DesignResult):
        self.wing = SimpleNamespace(stations=tuple(float(y) for y in _chords_and_stations(result)[1]))
        self.parameters = SimpleNamespace(pressure=float(result.parameters.pressure))
        for name in ("initial_rms_error", "rms_error", "max_error", "min_tension", "max_tension"):  # per bay
            setattr(self, name.replace("initial_", "initial_bay_") if "initial" in name else f"bay_{name}",
                    np.asarray(getattr(result.per_bay, name), np.float64))
        self.constraint_values = dict(result.constraint_values)
        self.success, self.variables, self.method, self.solves = (bool(result.success), tuple(result.variables),
                                                                  result.method, int(result.solves))
        self.initial_rms_error, self.rms_error = float(result.initial_rms_error), float(result.rms_error)


class _SharedHistory:
    """The result as `plots.plot_history` reads it, with the shared variables only (per-rib shapes and
    per-bay cut fields are many coefficients; they are in summary.json's history, the rib_K.dat and
    bay_K_cut_pattern.csv files). Plain values: it pickles for the report's workers."""

    def __init__(self, result: DesignResult):
        names = _shared_names(result)
        self.variables, self.method, self.objective = names, result.method, result.objective
        self.rms_error, self.success = result.rms_error, result.success
        self.values = {n: v for n, v in result.values.items() if n in names}
        self.history = [{**h, "values": {n: h["values"][n] for n in names}} for h in result.history]


# ------------------------------------------------------------------ a wing of several bays
def wing_nodes(result: DesignResult) -> np.ndarray:
    """``(n_bays (n_span - 1) + 1, n_contour, 3)`` m: the bays joined at their shared ribs, y the
    span station (`Wing.stations`)."""
    sol = result.wing_solution
    stations = np.asarray(_chords_and_stations(result)[1], np.float64)
    parts = []
    for k in range(len(sol.bays)):
        nodes = np.array(sol.nodes[k], dtype=np.float64)
        nodes[..., 1] += stations[k]
        parts.append(nodes if k == 0 else nodes[1:])  # the first row is the previous bay's tip rib
    return np.concatenate(parts)


def wing_deviation(result: DesignResult) -> np.ndarray:
    """``(n_bays, n_span, n_contour)`` signed normal distance of every node from its row's target,
    fractions of the local chord (positive outside; `objectives.WingTargets.deviation` of every row)."""
    sol = result.wing_solution
    return np.stack(WingTargets(sol.bays, result.per_bay.targets, "average").deviation(sol.nodes))


# ------------------------------------------------------------------ the folder
def _save(fig, path) -> None:
    save_figure(path, fig, **_SAVE_OPTIONS)


@dataclasses.dataclass(frozen=True, eq=False)
class ReportOptions:
    """What a report holds beside the design, and how it is drawn (`write_report`).

    Args:
        bounds: ``{name: (lower, upper)}`` variable bounds drawn in the
            history plot (None: none drawn).
        magnification: deviation factor of the section plots (None: automatic).
        rib_limits: the `rib_design.RibLimits` a shaped rib was designed
            with, drawn in ``rib_design.png`` (None: the defaults).
        patterns: write the flat panels and the rib templates (DXF, SVG) of a
            successful design (module docstring).
        seam_allowance_mm: the patterns' seam allowance, mm (>= 0).
        inputs, warnings, aero: the run's inputs, its warning lines and each
            bay's aerodynamic polar, recorded as `summarise` does (``aero``
            also draws ``bay_K_aero.png``).
        timings: seconds spent before the report (e.g. ``setup``,
            ``optimisation``); ``report`` and, unless given, ``total`` (their
            sum) are added.
        tolerance: an `inverse_design.tolerance.ToleranceAnalysis` of the
            result (None: none): ``summary["tolerance"]``, ``tolerance.png``
            and, with samples, ``tolerance_samples.csv`` (docs/tolerances.md).

    Raises:
        ValueError: if ``seam_allowance_mm`` is negative or not finite.
    """

    bounds: dict | None = None
    magnification: float | None = None
    rib_limits: object = None
    patterns: bool = True
    seam_allowance_mm: float = 10.0
    inputs: dict | None = None
    timings: dict | None = None
    aero: object = None
    warnings: list | None = None
    tolerance: object = None

    def __post_init__(self):
        check_seam_allowance(self.seam_allowance_mm)


def write_report(out_dir, result: DesignResult | Solution, target=None, *, scene=None, objective: str | None = None,
                 options: ReportOptions | None = None, workers=None) -> dict:
    """Write the output folder of a design (or of a single equilibrium) of N >= 1 bays; return its summary.

    Args:
        out_dir: the folder to create, or to write into (replacing only an earlier
            report's files: `staged_folder`).
        result: a `DesignResult` (`optimise_pressure`, `optimise_wing`,
            `evaluate_design`): it carries its bays, targets and ribs; or a
            single bay's equilibrium `Solution` (measured by `evaluate_design`).
        target, scene: a single bay's target and scene: needed with a
            `Solution`; with a `DesignResult` they must be its own (ValueError if not).
        objective: the rows a `Solution`'s errors are measured on (default "mid_bay").
        options: what the report holds beside the design and how it is drawn
            (`ReportOptions`: bounds, magnification, rib limits, patterns and
            their seam allowance, the run's inputs, timings, aero and warnings;
            None: the defaults).
        workers: `workers.ReportWorkers` started before the design (the
            command's), to save the figures built here and to
            write the DXF patterns while this process writes the other
            files; what they do not write is written here. Default none:
            every file is written here.

    Returns:
        The summary (as written to ``summary.json``), with ``files`` (names in
        the folder), ``skipped`` (files not written and why) and ``out`` (the
        folder's absolute path).

    Raises:
        ValueError: if ``out_dir`` cannot be written (`check_output_folder`),
            or ``target``/``scene`` are not the result's.
        TypeError: if ``result`` is neither a `DesignResult` nor a `Solution` (or a
            `Solution` comes without its target and scene).
    """
    options = ReportOptions() if options is None else options
    if not isinstance(options, ReportOptions):
        raise TypeError(f"options must be a ReportOptions, got {type(options).__name__}")
    magnification, aero, bounds, rib_limits = options.magnification, options.aero, options.bounds, options.rib_limits
    seam_allowance_mm, tolerance = options.seam_allowance_mm, options.tolerance
    if isinstance(result, Solution):
        result = _measured(result, target, scene, objective)
    result = _checked(result)
    if target is not None and not all(same_section(target, t) for t in result.per_bay.targets):
        raise ValueError(f"target {target.name} is not the design's ({result.per_bay.targets[0].name})")
    if scene is not None and (result.n_bays != 1 or scene.bay.n_span != result.wing_solution.bays[0].n_span):
        raise ValueError("scene is not the design's bay (give the result alone: it carries its bays)")
    start = time.perf_counter()
    out = check_output_folder(out_dir)
    sol = result.wing_solution
    n_bays = result.n_bays
    solutions = [_without_factors(sol.bay_solution(k)) for k in range(n_bays)]
    scenes = [sol.scene(k) if sol.fabric is not None else result.per_bay.scenes[k] for k in range(n_bays)]
    targets = mid_bay_targets(result)
    stations = _chords_and_stations(result)[1]
    deviation = wing_deviation(result)
    files, skipped = [], {}
    rib_files = _rib_files(result)
    with staged_folder(out) as staging:
        # Each figure is a plotting function and its arguments, built here; the report's workers, if
        # there are any, save them, else they are saved after the other files are written
        # (`workers.saved_after`).
        specs = [("wing_overview.png", plot_wing_overview, (_Overview(result), deviation), {})]
        for k in range(n_bays if n_bays <= PER_BAY_PLOTS else 0):
            start_rib = (result.wing.sections[k] if result.wing is not None and rib_files else None)
            specs.append((f"bay_{k}_mid_bay_section.png", plot_section, (solutions[k], targets[k], scenes[k]),
                          dict(magnification=magnification, start_rib=start_rib, bay=k,
                               rib_stations=(stations[k], stations[k + 1]))))
            if aero is not None:
                specs.append((f"bay_{k}_aero.png", plot_aero, (aero[k],), {}))
        if result.per_bay.cut_patterns is not None:  # a cut field per bay: every bay's in one image
            specs.append(("cut_pattern_overview.png", plot_cut_fields, _cut_fields(scenes, solutions), {}))
        if n_bays > PER_BAY_PLOTS:
            skipped["bay_K_mid_bay_section.png"] = (f"{n_bays} bays: more than {PER_BAY_PLOTS}, so "
                                                    "wing_overview.png shows every bay in one figure")
        if result.history:
            specs.append(("history.png", plot_history, (_SharedHistory(result), bounds), {}))
        else:
            skipped["history.png"] = "a single equilibrium has no optimiser history"
        if n_bays == 1:  # the one-bay extras
            specs += [("deviation.png", plot_deviation, (solutions[0], targets[0], scenes[0]), {}),
                      ("tensions.png", plot_tensions, (solutions[0], scenes[0]), {})]
            if result.parameters.rib_shape is not None and result.wing is not None:
                chord = scenes[0].bay.chord * float(result.parameters.rib_chord_scale)
                specs.append(("rib_design.png", plot_rib_design, (
                    result.parameters, result.wing.sections[0], chord, rib_limits), {}))
        if tolerance is not None:
            sampled = [r["rms"] for r in tolerance.samples] if tolerance.samples else None
            specs.append(("tolerance.png", plot_tolerance, (tolerance.summary(), tolerance.linear_rms, sampled), {}))
        to_save = sorted(specs, key=lambda spec: _SAVE_ORDER.index(spec[0]) if spec[0] in _SAVE_ORDER
                         else len(_SAVE_ORDER))
        sent, built = [], []  # the tasks handed to the workers, in order; the figures saved here
        try:
            for name, function, args, kwargs in to_save:  # (a worker saves one while the next is built)
                path, figure = staging / name, function(*args, **kwargs)
                task = (path, save_figure, (figure,), _SAVE_OPTIONS)
                if workers is not None and workers.submitted == len(sent) and workers.submit([task]):
                    sent.append(task)
                else:
                    built.append((path, figure))
            summary = summarise(result, inputs=options.inputs, timings=options.timings, aero=aero,
                                warnings=options.warnings)
            if tolerance is not None:
                summary["tolerance"] = tolerance.summary()
                if tolerance.samples:
                    _write_samples(staging / "tolerance_samples.csv", tolerance)
                    files.append("tolerance_samples.csv")
            with saved_after(built, _save):
                _write_data(staging, result, solutions, scenes, targets, deviation, files, skipped)
                if _patterns_wanted(options.patterns, summary, skipped):
                    dxf = []  # (the DXF files go to the workers, which have ezdxf imported, if they took the figures)
                    writer = (lambda path, function, *args: dxf.append((path, function, args, {}))) if sent else None
                    names, panels = [], []
                    for k in range(n_bays):
                        more, bay_panels = write_bay_patterns(staging, scenes[k], solutions[k].parameters, bay=k,
                                                              ribs=(k if k == 0 else None, k + 1),
                                                              seam_allowance_m=seam_allowance_mm / 1000.0,
                                                              writer=writer)
                        names += more
                        panels += bay_panels
                        # each bay's DXF files handed over at once: the workers write them while this
                        # process lays out the next bays' panels
                        if dxf and workers.submit(dxf):
                            sent += dxf
                        else:
                            for task in dxf:
                                run_task(task)
                        dxf.clear()
                    files += names
                    summary["patterns"] = _pattern_entry(names, panels, seam_allowance_mm)
            if sent:  # the workers' files; any they did not write is written here
                done = workers.finish()
                for k, task in enumerate(sent):
                    if k not in done:
                        run_task(task)
            files += [name for name, *_ in specs]
        except BaseException:
            if sent:  # (no worker writes into the staging folder once it is removed)
                workers.close()
            raise
        times = dict(summary["timings_s"])
        times["report"] = time.perf_counter() - start
        times.setdefault("total", sum(v for v in times.values() if isinstance(v, (int, float))))
        times["peak_memory_mb"] = peak_memory_mb()  # (not a time: after the total)
        summary.update(timings_s=times, files=files + ["summary.json"], skipped=skipped, out=str(out))
        summary["checksums"] = file_checksums(staging, files)  # (`export.changed_files` compares them)
        text = json.dumps(_jsonable(summary), indent=2, allow_nan=False)
        (staging / "summary.json").write_text(text + "\n")
    return summary


def _cut_fields(scenes: list, solutions: list) -> tuple:
    """`plots.plot_cut_fields`'s arguments: every bay's contour arc (fraction of its root rib's cut
    perimeter, from the trailing edge), the local prestrain of its span fibres and of its contour edges
    at each contour node, ``(n_bays, n_contour)`` each, and the leading edge's mean arc fraction."""
    arcs, spans, contours, leading = [], [], [], []
    for scene, solution in zip(scenes, solutions):
        cuts = cut_lengths(scene, solution.parameters)
        n = scene.bay.n_contour
        edges = cuts["contour_edge_cut_m"][0]
        arc = np.concatenate([[0.0], np.cumsum(edges)])[:n] / np.sum(edges)
        arcs.append(arc)
        spans.append(np.broadcast_to(cuts["span_prestrain"], (n,)))
        contour = np.asarray(cuts["contour_prestrain"])
        contours.append(np.concatenate([contour, contour[-1:]])[:n])  # (a flat panel: its last edge's)
        leading.append(arc[int(np.argmin(np.asarray(scene.bay.contour_root)[:, 0]))])
    return np.stack(arcs), np.stack(spans), np.stack(contours), float(np.mean(leading))


def peak_memory_mb() -> float:
    """The largest resident memory of this process so far, or of its largest child process that has
    ended (the report's workers), whichever is larger, in MB (10**6 bytes): ``resource.getrusage``'s
    ``ru_maxrss`` (kB on Linux, bytes on macOS); NaN where it is not available (Windows)."""
    try:
        import resource
    except ImportError:
        return math.nan
    unit = 1.0 if platform.system() == "Darwin" else 1024.0
    largest = max(resource.getrusage(who).ru_maxrss for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))
    return round(largest * unit / 1e6, 1)


def _write_data(staging: Path, result: DesignResult, solutions: list, scenes: list, targets: list,
                deviation: np.ndarray, files: list, skipped: dict) -> None:
    """The data files of the folder (module docstring): npz, meshes, cut lengths, designed ribs (each
    name written is appended to ``files``; a rib not drawn, with why, goes to ``skipped``)."""
    sol = result.wing_solution
    params = result.parameters
    shared = _shared_names(result)
    save_npz(
        staging / "wing.npz", dict(
            nodes=np.stack([s.nodes for s in solutions]),
            tension_span=np.stack([s.tension_span for s in solutions]),
            tension_chord=np.stack([s.tension_chord for s in solutions]),
            wrinkled=np.stack([np.asarray(s.wrinkled, bool) for s in solutions]),
            deviation=deviation, weights=np.asarray(result.per_bay.weights),
            stations=np.asarray(_chords_and_stations(result)[1], np.float64),
            chords=np.asarray(_chords_and_stations(result)[0], np.float64),
            result=np.asarray(sol.result), residual=np.asarray(sol.residual, np.float64),
            pressure=np.float64(params.pressure), prestrain=np.array(params.prestrain, np.float64),
            rib_thickness_scale=np.float64(params.rib_thickness_scale),
            rib_chord_scale=np.float64(params.rib_chord_scale),
            target_names=np.array([t.name for t in result.per_bay.targets], dtype=str),
            variables=np.array(list(shared), dtype=str),
            history_objective=np.array([h["objective"] for h in result.history], np.float64),
            history_values=(np.array([np.concatenate([np.ravel(h["values"][n]) for n in shared])
                                      for h in result.history], np.float64) if result.history else np.zeros((0, 0))),
            rib_shapes=np.zeros((0, 0)) if result.per_bay.rib_shapes is None else np.asarray(result.per_bay.rib_shapes),
            cut_patterns=(np.zeros((0, 0)) if result.per_bay.cut_patterns is None
                          else np.asarray(result.per_bay.cut_patterns))))
    joined = wing_nodes(result)
    periodic = sol.bays[0].periodic
    write_obj(staging / "skin.obj", joined, periodic, name="wing" if result.n_bays > 1 else sol.bays[0].name)
    write_stl(staging / "skin.stl", joined, periodic)
    files += ["wing.npz", "skin.obj", "skin.stl"]
    if result.n_bays == 1:  # the one-bay extra: the bay in full
        write_npz(staging / "equilibrium.npz", solutions[0], targets[0], scenes[0],
                  result if result.variables else None)  # (a single equilibrium: no variables, no history)
        files.append("equilibrium.npz")
    for k in range(result.n_bays):
        name = f"bay_{k}_cut_pattern.csv"
        write_cut_pattern(staging / name, scenes[k], solutions[k].parameters)
        files.append(name)
    names = _rib_files(result)
    if names:
        from forward_solver import rib_section

        rows = (np.asarray(result.per_bay.rib_shapes) if result.per_bay.rib_shapes is not None
                else [params.rib_shape] * len(names))
        crossed = result.violated_where.get("rib_crossing", {})  # (a rib that cannot be made is not drawn)
        if crossed:
            skipped["rib.dat" if names == ["rib.dat"] else "rib_K.dat"] = (
                f"the designed rib{'s' if len(crossed) > 1 else ''} {', '.join(map(str, sorted(crossed)))} "
                "cross themselves (constraints.violated: rib_crossing)")
        for k, (name, airfoil, row, chord) in enumerate(zip(names, result.wing.sections, rows, result.wing.chords)):
            if crossed and (name == "rib.dat" or k in crossed):
                continue
            label = "designed rib" if name == "rib.dat" else f"rib {name[4:-4]}"
            write_selig(staging / name, rib_section(airfoil, row, float(params.rib_thickness_scale),
                                                    name=f"{airfoil.name} {label}"),
                        comment=f"chord {chord * float(params.rib_chord_scale):g} m")
            files.append(name)


def _write_samples(path: Path, tolerance) -> None:
    """``tolerance_samples.csv``: the rows the run streamed (copied), or written from the analysis."""
    import csv
    import shutil

    if tolerance.samples_file:
        shutil.copyfile(tolerance.samples_file, path)
        return
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(tolerance.samples[0]))
        writer.writeheader()
        for row in tolerance.samples:
            writer.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in row.items()})


def _without_factors(value):
    """``value`` without LU factors (host objects that do not pickle) if it is a `Solution` or a
    `DesignResult`, for the figure workers; anything else as it is."""
    if isinstance(value, Solution):
        return value if value.factor is None else dataclasses.replace(value, factor=None)
    if isinstance(value, DesignResult) and getattr(value.wing_solution, "solutions", None):
        solutions = [dataclasses.replace(s, factor=None) for s in value.wing_solution.solutions]
        return dataclasses.replace(value, wing_solution=dataclasses.replace(value.wing_solution, solutions=solutions))
    return value


def check_seam_allowance(seam_allowance_mm) -> float:
    """The seam allowance (mm) as a float; a ValueError saying what to change if it is negative or not finite."""
    value = float(seam_allowance_mm)
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"the seam allowance must be 0 mm or more (the cut line lies outside the sewing "
                         f"line), got {seam_allowance_mm!r} mm: give --seam-allowance 0 or a positive number")
    return value


def _patterns_wanted(patterns: bool, summary: dict, skipped: dict) -> bool:
    """Whether to write the pattern files; if not, why, in ``skipped`` (module docstring)."""
    if not patterns:
        skipped["patterns"] = "not asked for (--no-patterns)"
        return False
    if not summary["results"]["success"]:
        skipped["patterns"] = ("a failed design is not to be cut: no panel or rib template (DXF, SVG) was "
                               "written")
        return False
    return True


def _pattern_entry(names: list, panels: list, seam_allowance_mm: float) -> dict:
    """``summary["patterns"]``: the files, the layers, the allowance and the layout's largest edge error."""
    return {"files": list(names), "unit": "mm", "scale": "1:1", "layers": ["CUT", "SEW", "MARK", "GRID"],
            "seam_allowance_mm": float(seam_allowance_mm),
            "panels": [{"bay": p.bay, "panel": p.name, "contour_nodes": [int(p.columns[0]), int(p.columns[-1])],
                        "length_error_m": p.length_error} for p in panels],
            "largest_length_error_m": max((p.length_error for p in panels), default=0.0)}
