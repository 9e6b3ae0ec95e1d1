"""The summary of a design of N >= 1 bays: the ``summary.json`` record (`summarise`, `SCHEMA_VERSION`).

One record for any number of bays (a bay given by options and the same bay
as a two-rib case file have the same keys): ``schema``, ``mode``
("optimise", or "evaluate" for a single equilibrium), ``inputs``,
``warnings``, ``case``, ``results``, ``errors`` (fractions of the local
chord), ``constraints``, ``sensitivity`` (`inverse_design.sensitivity`), ``timings_s``, ``history``, ``rib`` (a shaped
rib) and ``bays``, one entry per bay (docs/command.md lists every key). The
folder adds ``patterns``, ``files``, ``skipped``, ``checksums`` and ``out``
(`folder.write_report`); the console prints a few lines of it (`console.describe`).
"""

from __future__ import annotations

import math
import platform
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np

from forward_solver.model.cut_field import field_values

from ..fabric_range import strain_range
from ..objectives import same_section
from ..rib_design import cut_lengths
from .measures import chords_and_stations, le_recessions, mid_bay_errors

__all__ = ["SCHEMA_VERSION", "jsonable", "rib_files", "shared_names", "summarise"]

#: Version of the layout of ``summary.json``: 2 added ``schema``, ``case.n_bays``, the bay axis
#: ``bays`` and ``constraints.violated_where``; 3 is one layout for any number of bays: ``case.ribs``
#: and ``case.trailing_edge`` (no ``case.target``, ``rib``, ``chord_m``, ``rib_spacing_m``), errors in
#: fractions of the local chord, each bay's ``cut_lengths`` (and ``aero``) in its ``bays`` entry,
#: ``rib`` with every shaped rib.
SCHEMA_VERSION = 3


def _version(distribution: str) -> str:
    try:
        return version(distribution)
    except PackageNotFoundError:
        return "unknown"


def jsonable(value):
    """Plain JSON types; non-finite floats become None (JSON has no inf or NaN)."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, Path):
        return str(value)
    return value


def summarise(result, *, inputs: dict | None = None, timings: dict | None = None, aero=None,
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
                     for section, t, c, y in zip([af.name for af in wing.airfoils], result.per_bay.targets,
                                                 *chords_and_stations(result))],
            "grid": [sol.bays[0].n_span, sol.bays[0].n_contour],
            "trailing_edge": {
                "option": wing.trailing_edge, "unit": "chord",
                "changed": [{"rib": c["index"], "section": wing.airfoils[c["index"]].name,
                             **({"file": specs[c["index"]]} if c["index"] < len(specs) else {}),
                             "gap_before": c["gap_before"], "gap_after": c["gap_after"], "blend": c["blend"]}
                            for c in wing.trailing_edge_changes]},
            "fabric": {"stiffness_span_n_per_m": fabric.stiffness_span,
                       "stiffness_chord_n_per_m": fabric.stiffness_chord, "poisson": fabric.poisson,
                       "warp": fabric.warp, "shear_stiffness_n_per_m": fabric.shear_stiffness,
                       "law": _law(fabric)},
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
            # a fitted law's: the strains the design reaches, against the test's range (case.fabric.law)
            "fibre_strains": None if fabric.law is None else strain_range(result),
        },
        "errors": {
            "unit": "fraction of the local chord", "objective": result.objective,
            "weighting": "bay planform area",
            "before": {"rms": result.initial_rms_error, "max": result.initial_max_error} if design else None,
            "after": {"rms": result.rms_error, "max": result.max_error},
            "mid_bay_after": mid_bay_errors(result),
        },
        "constraints": {
            "active": list(result.active_constraints) if design else None,
            "violated": dict(result.violated_constraints) if design else None,
            "violated_where": _labelled(result.violated_where) if design else None,
            "violated_at_start": dict(result.violated_at_start) if design else None,
            "violated_at_start_where": _labelled(result.violated_at_start_where) if design else None,
            "values": dict(result.constraint_values), "unit": "N/m",
        },
        # what held the design where it is: shadow prices and design windows (docs/design_problem.md)
        "sensitivity": result.sensitivity if design else None,
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
    return jsonable(summary)


def _law(fabric) -> dict:
    """``case.fabric.law``: eq. (10), or the fitted law's record (`model.biaxial.FittedLaw.as_dict`: its
    coefficients, fit errors, tested strains) with the tested strains in the wing's directions."""
    if fabric.law is None:
        return {"kind": "linear, eq. 10", "stiffness_span_n_per_m": fabric.stiffness_span,
                "stiffness_chord_n_per_m": fabric.stiffness_chord, "poisson": fabric.poisson}
    return {**fabric.law.as_dict(), "warp": fabric.warp,
            "tested_strain_wing": {k: list(v) for k, v in fabric.strain_range.items()}}


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


def _largest_coefficient(result) -> float | None:
    shapes = result.per_bay.rib_shapes if result.per_bay.rib_shapes is not None else result.parameters.rib_shape
    return None if shapes is None else float(np.max(np.abs(np.asarray(shapes))))


def _rib_entry(result) -> dict | None:
    """``summary["rib"]`` of a shaped rib (one shape for every rib, or one per rib), else None."""
    shared = result.parameters.rib_shape
    if result.per_bay.rib_shapes is None and shared is None:
        return None
    coefficients = np.asarray(shared if result.per_bay.rib_shapes is None else result.per_bay.rib_shapes, np.float64)
    return {"layout": "shared" if result.per_bay.rib_shapes is None else "per_rib",
            "coefficients": coefficients.tolist(), "terms_per_surface": int(coefficients.shape[-1]) // 2,
            "parametrisation": "outward z offset sqrt(x)(1-x) sum_k c_k B_k(x), chord-normalised; "
                               "upper-surface coefficients, then lower (forward_solver.model.rib_shape)",
            "limits": list(result.per_bay.rib_limits), "files": rib_files(result)}


def rib_files(result) -> list:
    """The designed ribs' Selig files: ``rib.dat`` for one shape on ribs of one section, else ``rib_K.dat``."""
    if result.per_bay.rib_shapes is None and result.parameters.rib_shape is None:
        return []
    if result.per_bay.rib_shapes is None and _same_sections(result):
        return ["rib.dat"]
    return [f"rib_{k}.dat" for k in range(len(result.wing.sections))]


def _same_sections(result) -> bool:
    sections = result.wing.sections
    return all(same_section(sections[0], s) for s in sections[1:])


def _bay_entries(result, solutions: list, aero) -> list:
    """The bay axis of the summary: one entry per bay."""
    sol = result.wing_solution
    stations = chords_and_stations(result)[1]
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


def shared_names(result) -> tuple:
    """The design's variables shared by every bay (not per-rib shapes, not per-bay fields)."""
    return tuple(n for n in result.variables if not (n == "rib_shape" and result.per_bay.rib_shapes is not None)
                 and not (n == "cut_pattern" and result.per_bay.cut_patterns is not None))


def _local_prestrain_range(result) -> dict | None:
    """``{"span": [low, high], "chord": [low, high]}``: the local prestrain of the design's cut field(s)
    over the contour (every bay's for per-bay fields), or None for a uniform cut."""
    p = result.parameters
    rows = [p.cut_pattern] if result.per_bay.cut_patterns is None else list(np.asarray(result.per_bay.cut_patterns))
    if rows[0] is None:
        return None
    s = np.linspace(0.0, 1.0, 401)
    span, chord = zip(*(field_values(s, p.prestrain_span, p.prestrain_chord, row) for row in rows))
    return {"span": [float(np.min(span)), float(np.max(span))],
            "chord": [float(np.min(chord)), float(np.max(chord))]}

