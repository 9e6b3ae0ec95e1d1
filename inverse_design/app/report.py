"""The one report writer: the summary of a design and its output folder, for one bay or a wing.

`write_report` turns a `DesignResult` (or a single equilibrium `Solution`)
into a folder. ``summary.json`` has the same layout for a single bay and a
wing (`SCHEMA_VERSION`): ``schema``, ``mode``, ``inputs``, ``case`` (with
``n_bays``), ``results``, ``errors``, ``constraints`` (``violated``: the
largest amount per limit; ``violated_where``: the amount per bay or rib;
``violated_at_start``), ``timings_s``, ``history`` and ``bays``, the bay
axis: one entry per bay (ribs, span, chords, weight, targets, result code,
steps, residual, errors before and after, tensions, wrinkled fraction).

A single bay's folder::

    summary.json          inputs, results, errors before and after, constraints,
                          timings, package version, the files written (`summarise`)
    equilibrium.npz       nodes, tensions, wrinkled cells, deviation, target, parameters
                          (`export.write_npz`)
    skin.obj, skin.stl    the equilibrium skin as a mesh (metres)
    mid_bay_section.png   the mid-bay section against the rib and the target,
                          deviations magnified (`plots.plot_section`)
    deviation.png         the deviation from the target over the whole bay (`plot_deviation`)
    tensions.png          fibre tensions with the wrinkled cells marked (`plot_tensions`)
    history.png           the optimiser's iterates (`plot_history`; skipped for a
                          single equilibrium)
    aero.png              lift, drag and moment against the target (`plot_aero`; only
                          with an `inverse_design.aero.AeroComparison`)
    cut_pattern.csv       the fabric's cut lengths along the contour and the span
                          (`export.write_cut_pattern`)
    pattern_bay_0_upper.dxf, pattern_bay_0_lower.dxf
                          the flat panels, cut-ready: sewing line, cut line at the seam
                          allowance, alignment marks, warp, label (1:1, mm; `app.pattern`);
                          only for a successful design
    pattern_bay_0_upper.svg, pattern_bay_0_lower.svg   the same for a quick look
    rib_0.dxf, rib_1.dxf  the two ribs' templates at their chords with the attachment marks
    rib.dat               the designed rib as a Selig file (`export.write_selig`; only
                          for a shaped rib)
    rib_design.png        the rib's template offset and the thickness kept
                          (`plot_rib_design`; only for a shaped rib)

A wing's folder::

    summary.json                 as above, with a bay entry per bay
    wing.npz                     every bay stacked: nodes (n_bays, n_span, n_contour, 3) m
                                 (each bay in its own frame, root rib at y = 0), tensions,
                                 wrinkled cells, deviation from the row targets, ribs
    skin.obj, skin.stl           the whole wing's skin in one mesh (bays joined at their ribs,
                                 y from the root rib), metres
    wing_overview.png            every bay in one figure: the deviation over the whole skin,
                                 each bay's errors and tensions (`plots.plot_wing_overview`)
    bay_K_mid_bay_section.png    bay K's mid-bay section against its rib and its target (only
                                 for a wing of at most `PER_BAY_PLOTS` bays)
    rib_K.dat                    rib K's designed section (Selig), when the rib shapes were
                                 optimised
    bay_K_cut_pattern.csv        bay K's cut lengths (`export.write_cut_pattern`)
    pattern_bay_K_upper.dxf/.svg, pattern_bay_K_lower.dxf/.svg
                                 bay K's flat panels (as a single bay's; a successful design only)
    rib_K.dxf                    rib K's template at its chord (a successful design only)
    history.png                  the optimiser's iterates

The folder is written by `export.staged_folder`: only the tool's own files
are replaced, nothing else in the folder is touched. The pattern files are
plain names in the folder (not a ``patterns/`` subfolder): the staging and
ownership rules (`export.written_files`) own plain files only.

The command hands a single bay's four figures and DXF patterns to its
`drawing.ReportWorkers` (worker processes started when it starts, which
import matplotlib and ezdxf while the design runs), so its own process
imports neither; what they do not write, and every file of a library
caller's report, is written in the calling process.

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

import numpy as np

from forward_solver import Solution

from .drawing import run_task, save_figure, saved_after
from .export import (check_output_folder, save_npz, staged_folder, write_cut_pattern, write_npz, write_obj,
                     write_selig, write_stl)
from .export import file_checksums
from .pattern import write_bay_patterns
from ..objectives import bay_distances, design_errors, local_chords, row_targets, section_errors
from ..optimise import DesignResult
from .plots import (plot_aero, plot_deviation, plot_history, plot_rib_design, plot_section, plot_tensions,
                    plot_wing_overview)
from ..rib_design import RibGeometry, RibLimits, cut_lengths

__all__ = ["SCHEMA_VERSION", "summarise", "wing_deviation", "wing_nodes", "write_report"]

#: Version of the layout of ``summary.json``: 2 added ``schema``, ``case.n_bays``, the bay axis
#: ``bays`` (one entry per bay, also for a single bay) and ``constraints.violated_where``; a wing's
#: ``mode`` is "optimise" like a bay's.
SCHEMA_VERSION = 2

#: Resolution of the PNG files in the folder, dots per inch.
_DPI = 150
#: zlib level of the PNG figures: 3 writes them 0.07 s faster each than PIL's default 6, 13% larger.
_PNG_COMPRESSION = 3
#: A wing of at most this many bays also gets one mid-bay section plot per bay (more: only
#: ``wing_overview.png``, which shows every bay; a plot per bay took 0.3 s each and 15 s of a 40-bay report).
PER_BAY_PLOTS = 8
#: The order in which a single bay's figures are handed to the workers, the slowest first (saving each
#: on the 2-core development machine, 2026-11-25: history 0.35-0.39 s, tensions 0.34 s, mid-bay
#: section 0.28 s, deviation 0.24 s). Figures not named keep their place after these.
_SAVE_ORDER = ("history.png", "tensions.png", "mid_bay_section.png", "deviation.png")
#: The figures a `drawing.ReportWorkers` may build: their plotting functions call no JAX and take
#: picklable NumPy-only arguments.
_PORTABLE = frozenset(_SAVE_ORDER)


# ------------------------------------------------------------------ inputs
def _unpack(result) -> tuple[Solution, DesignResult | None]:
    if isinstance(result, DesignResult):
        return result.solution, result
    if isinstance(result, Solution):
        return result, None
    raise TypeError(f"expected an inverse_design.DesignResult or a forward_solver.Solution, "
                    f"got {type(result).__name__}")


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


def summarise(result, target=None, scene=None, *, objective: str | None = None,
              inputs: dict | None = None, timings: dict | None = None, aero=None, rib=None,
              rib_limits: RibLimits | None = None, warnings: list | None = None) -> dict:
    """The summary of a design or a single equilibrium, as `write_report` stores it.

    Args:
        result: a `DesignResult`, or a `Solution` (a single equilibrium).
        target: a single bay's target `targets.Airfoil`; None for a wing's
            summary (any number of bays, the result's own targets).
        scene: a single bay's `forward_solver.Scene`.
        objective: the sections the errors are measured on (default the
            result's objective, or "mid_bay" for a `Solution`).
        inputs: the caller's options (stored as given).
        timings: seconds, e.g. ``{"setup": ..., "optimisation": ...}``.
        aero: an `inverse_design.aero.AeroComparison` of the result, stored as
            ``summary["aero"]`` (`AeroComparison.as_dict`); None leaves the key out.
        rib: the rib's starting section (default the target), for the rib
            entry of a shaped rib.
        rib_limits: the `rib_design.RibLimits` the design used (default the defaults).
        warnings: lines about the inputs (`inverse_design.plausibility`),
            stored as ``summary["warnings"]`` (default none).

    Returns:
        A JSON-ready dict. Errors are fractions of chord; ``null`` marks a
        value that does not exist (no upper tension limit, a gradient not
        computed).
    """
    if isinstance(result, DesignResult) and (result.n_bays > 1 or target is None):
        return _summarise_wing(result, inputs=inputs, timings=timings, warnings=warnings)
    solution, design = _unpack(result)
    objective = objective or (design.objective if design is not None else "mid_bay")
    params = solution.parameters.as_dict()
    chord = scene.bay.chord
    rms, largest = design_errors(solution.nodes, target, chord, objective)
    mid = section_errors(solution, target, chord)
    bay, fabric = scene.bay, scene.fabric
    summary = {
        "schema": SCHEMA_VERSION,
        "package": {"name": "inflatable-wing", "version": _version("inflatable-wing")},
        "versions": {"python": platform.python_version(), "jax": _version("jax"),
                     "numpy": np.__version__},
        "mode": "optimise" if design is not None else "evaluate",
        "inputs": dict(inputs or {}),
        "warnings": list(warnings or []),
        "case": {
            "n_bays": 1, "target": str(target.name), "rib": bay.name, "chord_m": chord,
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
                       "rib_chord_scale": params["rib_chord_scale"],
                       "stiffness_span_n_per_m": params["stiffness_span"],
                       "stiffness_chord_n_per_m": params["stiffness_chord"],
                       "rib_shape": params["rib_shape"], "cut_pattern": params["cut_pattern"]},
            "variables": list(design.variables) if design is not None else [],
            "method": design.method if design is not None else None,
            "iterations": len(design.history) if design is not None else 0,
            "forward_solves": design.solves if design is not None else 1,
            "grid_change": design.grid_change if design is not None else None,
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
            "violated": ({name: float(v) for name, v in design.violated_constraints.items()}
                         if design is not None else None),
            "violated_where": _violated_where(design.violated_constraints) if design is not None else None,
            "violated_at_start": ({name: float(v) for name, v in design.violated_at_start.items()}
                                  if design is not None else None),
            "violated_at_start_where": (_violated_where(design.violated_at_start) if design is not None
                                        else None),
            "values": (dict(design.constraint_values) if design is not None else
                       {"min_tension": float(min(np.min(solution.tension_span), np.min(solution.tension_chord))),
                        "max_tension": float(max(np.max(solution.tension_span), np.max(solution.tension_chord)))}),
            "unit": "N/m",
        },
        "timings_s": dict(timings or {}),
        "history": list(design.history) if design is not None else [],
        "bays": (_bay_entries(design) if design is not None else
                 [_equilibrium_entry(solution, scene, target, rms, largest)]),
    }
    if design is None:
        summary["constraints"]["note"] = ("a single equilibrium: constraints are not enforced; "
                                          "tensions are the solver's (compression clamped to zero)")
    if aero is not None:
        summary["aero"] = aero.as_dict()
    cuts = cut_lengths(scene, solution.parameters)
    mid_row = bay.n_span // 2
    summary["cut_lengths"] = {
        "unit": "m", "file": "cut_pattern.csv",
        "contour_perimeter": {"root_rib": cuts["contour_cut_m"][0], "mid_bay": cuts["contour_cut_m"][mid_row],
                              "tip_rib": cuts["contour_cut_m"][-1]},
        "span_fibre": {"min": float(np.min(cuts["span_cut_m"])), "max": float(np.max(cuts["span_cut_m"]))},
    }
    if solution.parameters.rib_shape is not None:
        geometry = RibGeometry(target if rib is None else rib, rib_limits or RibLimits())
        summary["rib"] = {"coefficients": solution.parameters.rib_shape,
                          "terms_per_surface": int(np.size(solution.parameters.rib_shape)) // 2,
                          "parametrisation": "outward z offset sqrt(x)(1-x) sum_k c_k B_k(x), chord-normalised; "
                                             "upper-surface coefficients, then lower (forward_solver.rib_shape)",
                          "limits": geometry.measure(solution.parameters), "file": "rib.dat"}
    return _jsonable(summary)


def _violated_where(violated: dict) -> dict:
    """``{name: {"bay k" or "rib k": amount}}`` of a design's `constraints.Violation`s."""
    where = {}
    for name, violation in violated.items():
        label = "rib" if name.startswith("rib_") else "bay"
        where[name] = {f"{label} {k}": float(v) for k, v in violation.items()}
    return where


def _bay_entries(result: DesignResult) -> list:
    """The bay axis of the summary: one entry per bay of a design (also of a single bay)."""
    sol = result.wing_solution
    if result.wing is not None:
        stations = np.asarray(result.wing.stations, np.float64)
    else:  # a flat panel: one bay from y = 0
        stations = np.asarray([0.0, sol.bays[0].rib_spacing])
    entries = []
    for k, bay in enumerate(sol.bays):
        entries.append({
            "bay": k, "ribs": [k, k + 1], "span_m": [stations[k], stations[k + 1]],
            "chords_m": [bay.chord_root, bay.chord_tip], "weight": result.weights[k],
            "targets": [result.targets[k].name, result.targets[k + 1].name],
            "result": result.bay_results[k], "steps": int(np.asarray(sol.steps)[k]),
            "relative_residual": float(np.asarray(sol.residual)[k]),
            "errors_before": {"rms": result.initial_bay_rms_error[k], "max": result.initial_bay_max_error[k]},
            "errors_after": {"rms": result.bay_rms_error[k], "max": result.bay_max_error[k]},
            "min_tension_n_per_m": result.bay_min_tension[k], "max_tension_n_per_m": result.bay_max_tension[k],
            "wrinkled_fraction": sol.bay_solution(k).wrinkled_fraction,
        })
    return entries


def _equilibrium_entry(solution: Solution, scene, target, rms: float, largest: float) -> dict:
    """The one bay entry of a single equilibrium (``--evaluate``): no start, solver tensions."""
    bay = scene.bay
    return {"bay": 0, "ribs": [0, 1], "span_m": [0.0, bay.rib_spacing], "chords_m": [bay.chord_root, bay.chord_tip],
            "weight": 1.0, "targets": [target.name, target.name], "result": solution.result.name,
            "steps": int(solution.steps), "relative_residual": solution.residual, "errors_before": None,
            "errors_after": {"rms": rms, "max": largest},
            "min_tension_n_per_m": float(min(np.min(solution.tension_span), np.min(solution.tension_chord))),
            "max_tension_n_per_m": float(max(np.max(solution.tension_span), np.max(solution.tension_chord))),
            "wrinkled_fraction": solution.wrinkled_fraction}


# ------------------------------------------------------------------ the folder
def _save(fig, path) -> None:
    fig.savefig(path, dpi=_DPI, pil_kwargs={"compress_level": _PNG_COMPRESSION})


def write_report(out_dir, result, target=None, *, scene=None, objective: str | None = None,
                 bounds: dict | None = None, inputs: dict | None = None,
                 timings: dict | None = None, magnification: float | None = None, aero=None,
                 rib=None, rib_limits: RibLimits | None = None, warnings: list | None = None,
                 patterns: bool = True, seam_allowance_mm: float = 10.0, workers=None) -> dict:
    """Write the output folder of a design (or of a single equilibrium) and return its summary.

    Args:
        out_dir: the folder to create, or to write into (replacing only an earlier
            report's files: `staged_folder`).
        result: a `DesignResult` (`optimise_pressure`, `optimise_wing`: one
            bay or several), or a single bay's `Solution`.
        target: a single bay's target `targets.Airfoil` (chord-normalised);
            None for a wing's folder (any number of bays; its targets are the
            result's own, one per rib).
        scene: a single bay's `forward_solver.Scene` it was solved on.
        objective, inputs, warnings: as `summarise`.
        bounds: variable bounds to draw in the history plot.
        timings: seconds spent before the report (e.g. ``setup``,
            ``optimisation``); ``report`` and, unless given, ``total`` (their
            sum) are added.
        magnification: deviation factor of the section plot (default automatic).
        aero: an `inverse_design.aero.AeroComparison`: stored in the summary
            and drawn as ``aero.png`` (default none).
        rib, rib_limits: the rib's starting section (default the target)
            and its `rib_design.RibLimits`: a shaped rib is written as
            ``rib.dat`` and drawn against it in ``rib_design.png``.
        patterns: write the flat panels and the rib templates (DXF, SVG) of a
            successful design (module docstring).
        seam_allowance_mm: the patterns' seam allowance, mm (>= 0).
        workers: `drawing.ReportWorkers` started before the design (the
            command's), to build and save a single bay's section, deviation,
            tensions and history figures and to write its DXF patterns while
            this process writes the other files; what they do not write is
            written here. Default none: every file is written here.

    Returns:
        The summary (as written to ``summary.json``), with ``files`` (names in
        the folder), ``skipped`` (files not written and why) and ``out`` (the
        folder's absolute path).

    Raises:
        ValueError: if ``out_dir`` cannot be written (`check_output_folder`), or
            ``seam_allowance_mm`` is negative.
        TypeError: if ``result`` is neither a `DesignResult` nor a `Solution`.
    """
    check_seam_allowance(seam_allowance_mm)
    if isinstance(result, DesignResult) and (result.n_bays > 1 or target is None):  # a wing's folder
        if aero is not None:
            raise ValueError("the aerodynamic comparison is of one bay's sections; a wing's report has none")
        return _write_wing_folder(out_dir, result, bounds=bounds, inputs=inputs, timings=timings,
                                  magnification=magnification, warnings=warnings, patterns=patterns,
                                  seam_allowance_mm=seam_allowance_mm)
    if target is None or scene is None:
        raise TypeError("a single bay's report needs its target and scene")
    start = time.perf_counter()
    out = check_output_folder(out_dir)
    solution, design = _unpack(result)
    files, skipped = [], {}
    start_rib = target if rib is None else rib
    shaped = solution.parameters.rib_shape is not None
    has_history = design is not None and bool(design.history)
    with staged_folder(out) as staging:
        # Each figure is a plotting function and its arguments. Those of `_PORTABLE` go to the report's
        # workers if there are any; every other is built here (where JAX may be called), then saved
        # after the other files are written (`drawing.saved_after`).
        specs = [("mid_bay_section.png", plot_section, (solution, target, scene),
                  dict(magnification=magnification, start_rib=start_rib if shaped else None)),
                 ("deviation.png", plot_deviation, (solution, target, scene), {}),
                 ("tensions.png", plot_tensions, (solution, scene), {})]
        if has_history:
            specs.append(("history.png", plot_history, (design, bounds), {}))
        if aero is not None:
            specs.append(("aero.png", plot_aero, (aero,), {}))
        if shaped:
            specs.append(("rib_design.png", plot_rib_design, (
                solution.parameters, start_rib, scene.bay.chord * float(solution.parameters.rib_chord_scale),
                rib_limits), {}))
        to_save = sorted(specs, key=lambda spec: _SAVE_ORDER.index(spec[0]) if spec[0] in _SAVE_ORDER
                         else len(_SAVE_ORDER))
        sent, portable = [], []  # the tasks handed to the workers, in order; the figures among them
        if workers is not None and workers.submitted == 0:
            portable = [(staging / name, save_figure, (_save, function, tuple(_without_factors(a) for a in args),
                                                        kwargs), {})
                        for name, function, args, kwargs in to_save if name in _PORTABLE]
            if workers.submit(portable):
                sent += portable
            else:
                portable = []
        try:
            summary = summarise(result, target, scene, objective=objective, inputs=inputs, timings=timings,
                                aero=aero, rib=rib, rib_limits=rib_limits, warnings=warnings)
            handed = {path.name for path, *_ in portable}
            built = [(staging / name, function(*args, **kwargs)) for name, function, args, kwargs in to_save
                     if name not in handed]
            with saved_after(built, _save):
                write_npz(staging / "equilibrium.npz", solution, target, scene, design)
                write_obj(staging / "skin.obj", solution.nodes, scene.bay.periodic, name=scene.bay.name)
                write_stl(staging / "skin.stl", solution.nodes, scene.bay.periodic)
                write_cut_pattern(staging / "cut_pattern.csv", scene, solution.parameters)
                files += ["equilibrium.npz", "skin.obj", "skin.stl", "cut_pattern.csv"]
                if _patterns_wanted(patterns, summary, skipped):
                    dxf = []  # (the DXF files go to the workers, which have ezdxf imported, if they took the figures)
                    names, panels = write_bay_patterns(
                        staging, scene, solution.parameters, seam_allowance_m=seam_allowance_mm / 1000.0,
                        writer=(lambda path, function, *args: dxf.append((path, function, args, {}))) if sent else None)
                    if dxf and workers.submit(dxf):
                        sent += dxf
                    else:
                        for task in dxf:
                            run_task(task)
                    files += names
                    summary["patterns"] = _pattern_entry(names, panels, seam_allowance_mm)
                if shaped and "rib_crossing" in (design.violated_constraints if design is not None else {}):
                    skipped["rib.dat"] = "the designed rib crosses itself (constraints.violated: rib_crossing)"
                elif shaped:
                    from forward_solver import rib_section

                    section = rib_section(start_rib, solution.parameters.rib_shape,
                                          float(solution.parameters.rib_thickness_scale),
                                          name=f"{start_rib.name} designed rib")
                    chord = scene.bay.chord * float(solution.parameters.rib_chord_scale)
                    write_selig(staging / "rib.dat", section, comment=f"chord {chord:g} m")
                    files.append("rib.dat")
                if not has_history:
                    skipped["history.png"] = "a single equilibrium has no optimiser history"
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
        summary.update(timings_s=times, files=files + ["summary.json"], skipped=skipped, out=str(out))
        summary["checksums"] = file_checksums(staging, files)  # (`export.changed_files` compares them)
        text = json.dumps(_jsonable(summary), indent=2, allow_nan=False)
        (staging / "summary.json").write_text(text + "\n")
    return summary


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
        skipped["patterns"] = "a failed design is not to be cut: no pattern or rib template was written"
        return False
    return True


def _pattern_entry(names: list, panels: list, seam_allowance_mm: float) -> dict:
    """``summary["patterns"]``: the files, the layers, the allowance and the layout's largest edge error."""
    return {"files": list(names), "unit": "mm", "scale": "1:1", "layers": ["CUT", "SEW", "MARK", "GRID"],
            "seam_allowance_mm": float(seam_allowance_mm),
            "panels": [{"bay": p.bay, "panel": p.name, "contour_nodes": [int(p.columns[0]), int(p.columns[-1])],
                        "length_error_m": p.length_error} for p in panels],
            "largest_length_error_m": max((p.length_error for p in panels), default=0.0)}


# ------------------------------------------------------------------ a wing of several bays
def wing_nodes(result: DesignResult) -> np.ndarray:
    """``(n_bays (n_span - 1) + 1, n_contour, 3)`` m: the bays joined at their shared ribs, y the
    span station (`Wing.stations`)."""
    sol = result.wing_solution
    stations = np.asarray(result.wing.stations, np.float64)
    parts = []
    for k in range(len(sol.bays)):
        nodes = np.array(sol.nodes[k], dtype=np.float64)
        nodes[..., 1] += stations[k]
        parts.append(nodes if k == 0 else nodes[1:])  # the first row is the previous bay's tip rib
    return np.concatenate(parts)


def wing_deviation(result: DesignResult) -> np.ndarray:
    """``(n_bays, n_span, n_contour)`` signed normal distance of every node from its row's target,
    fractions of the local chord (positive outside; `objectives` module docstring)."""
    import jax

    sol, targets = result.wing_solution, result.targets
    out = []
    with jax.enable_x64(True):
        for k, bay in enumerate(sol.bays):
            etas = np.linspace(0.0, 1.0, bay.n_span)
            rows = row_targets(targets[k], targets[k + 1], bay.chord_root, bay.chord_tip, etas)
            out.append(np.asarray(bay_distances(np.asarray(sol.nodes[k]), rows, etas, local_chords(bay, etas))))
    return np.stack(out)


def _summarise_wing(result: DesignResult, *, inputs: dict | None = None, timings: dict | None = None,
                    warnings: list | None = None) -> dict:
    """The summary of a design of several bays (`summarise` for a single bay; module docstring)."""
    sol = result.wing_solution
    params = result.parameters.resolved(sol.fabric).as_dict()
    specs = [r.get("section") for r in (inputs or {}).get("wing") or []]  # the case file's section specs
    bays = _bay_entries(result)
    fabric = sol.fabric
    summary = {
        "package": {"name": "inflatable-wing", "version": _version("inflatable-wing")},
        "versions": {"python": platform.python_version(), "jax": _version("jax"), "numpy": np.__version__},
        "schema": SCHEMA_VERSION,
        "mode": "optimise",
        "inputs": dict(inputs or {}),
        "warnings": list(warnings or []),
        "case": {
            "n_bays": result.n_bays,
            "ribs": [{"section": af.name, "target": t.name, "chord_m": c, "station_m": y}
                     for af, t, c, y in zip(result.wing.airfoils, result.targets, result.wing.chords,
                                            result.wing.stations)],
            "grid": [sol.bays[0].n_span, sol.bays[0].n_contour],
            "trailing_edge": {"option": result.wing.trailing_edge, "unit": "chord",
                              "changed": [{"rib": c["index"], "section": result.wing.airfoils[c["index"]].name,
                                           **({"file": specs[c["index"]]} if c["index"] < len(specs) else {}),
                                           "gap_before": c["gap_before"], "gap_after": c["gap_after"],
                                           "blend": c["blend"]} for c in result.wing.trailing_edge_changes]},
            "fabric": {"stiffness_span_n_per_m": fabric.stiffness_span,
                       "stiffness_chord_n_per_m": fabric.stiffness_chord, "poisson": fabric.poisson},
        },
        "results": {
            "success": result.success, "message": result.message,
            "values": {"pressure_pa": params["pressure"], "prestrain_span": params["prestrain_span"],
                       "prestrain_chord": params["prestrain_chord"],
                       "rib_thickness_scale": params["rib_thickness_scale"],
                       "rib_chord_scale": params["rib_chord_scale"],
                       "stiffness_span_n_per_m": params["stiffness_span"],
                       "stiffness_chord_n_per_m": params["stiffness_chord"],
                       "cut_pattern": params["cut_pattern"]},
            "rib_shapes": None if result.rib_shapes is None else np.asarray(result.rib_shapes).tolist(),
            "rib_shape_max_abs": None if result.rib_shapes is None else float(np.max(np.abs(result.rib_shapes))),
            "rib_limits": list(result.rib_limits),
            "cut_patterns": None if result.cut_patterns is None else np.asarray(result.cut_patterns).tolist(),
            "cut_pattern_local": _local_prestrain_range(result),
            "variables": list(result.variables), "method": result.method,
            "iterations": len(result.history), "forward_solves": result.solves,
            "wall_time_s": result.wall_time,
            "grid_change": result.grid_change,  # after --refine: both grids and how far the design moved
        },
        "errors": {
            "unit": "fraction of the local chord", "objective": result.objective,
            "weighting": "bay planform area",
            "before": {"rms": result.initial_rms_error}, "after": {"rms": result.rms_error},
        },
        "constraints": {
            "active": list(result.active_constraints),
            "violated": {name: float(v) for name, v in result.violated_constraints.items()},
            "violated_where": _violated_where(result.violated_constraints),
            "violated_at_start": {name: float(v) for name, v in result.violated_at_start.items()},
            "violated_at_start_where": _violated_where(result.violated_at_start),
            "values": dict(result.constraint_values), "unit": "N/m",
        },
        "timings_s": dict(timings or {}),
        "history": list(result.history),
        "bays": bays,
    }
    return _jsonable(summary)


def _shared_names(result: DesignResult) -> tuple:
    """The design's variables shared by every bay of a wing (not per-rib shapes, not per-bay fields)."""
    return tuple(n for n in result.variables if n != "rib_shape"
                 and not (n == "cut_pattern" and result.cut_patterns is not None))


def _local_prestrain_range(result: DesignResult) -> dict | None:
    """``{"span": [low, high], "chord": [low, high]}``: the local prestrain of the design's cut field(s)
    over the contour (every bay's for per-bay fields), or None for a uniform cut."""
    from forward_solver.cut_field import field_values

    p = result.parameters
    rows = [p.cut_pattern] if result.cut_patterns is None else list(np.asarray(result.cut_patterns))
    if rows[0] is None:
        return None
    s = np.linspace(0.0, 1.0, 401)
    span, chord = zip(*(field_values(s, p.prestrain_span, p.prestrain_chord, row) for row in rows))
    return {"span": [float(np.min(span)), float(np.max(span))],
            "chord": [float(np.min(chord)), float(np.max(chord))]}


class _SharedHistory:
    """The result as `plots.plot_history` reads it, with the shared variables only (per-rib shapes and
    per-bay cut fields are many coefficients; they are in summary.json's history, the rib_K.dat and
    bay_K_cut_pattern.csv files)."""

    def __init__(self, result: DesignResult):
        names = _shared_names(result)
        self.variables, self.method, self.objective = names, result.method, result.objective
        self.rms_error, self.success, self.values = result.rms_error, result.success, result.values
        self.history = [{**h, "values": {n: h["values"][n] for n in names}} for h in result.history]


def _write_wing_folder(out_dir, result: DesignResult, *, bounds: dict | None = None,
                      inputs: dict | None = None, timings: dict | None = None,
                      magnification: float | None = None, warnings: list | None = None,
                      patterns: bool = True, seam_allowance_mm: float = 10.0) -> dict:
    """Write the output folder of a wing design and return its summary (module docstring).

    Args:
        out_dir: the folder to create, or to write into (replacing only an earlier
            report's files: `export.staged_folder`).
        result: the `optimise.DesignResult` of the wing.
        bounds: variable bounds to draw in the history plot.
        inputs: the caller's options (stored as given).
        timings: seconds spent before the report; ``report`` and ``total`` are added.
        magnification: deviation factor of the section plots (default automatic).
        patterns, seam_allowance_mm: as `write_report`.

    Returns:
        The summary, with ``files``, ``skipped`` and ``out``.

    Raises:
        ValueError: if ``out_dir`` cannot be written (`export.check_output_folder`).
    """
    start = time.perf_counter()
    out = check_output_folder(out_dir)
    summary = _summarise_wing(result, inputs=inputs, timings=timings, warnings=warnings)
    sol = result.wing_solution
    files, skipped = [], {}
    with staged_folder(out) as staging:
        solutions = [sol.bay_solution(k) for k in range(len(sol.bays))]
        params = result.parameters
        shared = _shared_names(result)
        deviation = wing_deviation(result)
        # Every figure is built first (here, where JAX may be called), then saved after the other
        # files are written (`drawing.saved_after`).
        figures = [("wing_overview.png", plot_wing_overview(result, deviation))]
        for k, bay in enumerate(sol.bays if len(sol.bays) <= PER_BAY_PLOTS else ()):
            target = row_targets(result.targets[k], result.targets[k + 1], bay.chord_root, bay.chord_tip,
                                 [0.5])[0]
            fig = plot_section(solutions[k], target, sol.scene(k), magnification=magnification)
            fig.suptitle(f"bay {k} (ribs {k}-{k + 1}): {fig.get_suptitle()}")
            figures.append((f"bay_{k}_mid_bay_section.png", fig))
        bay_figures = [name for name, _ in figures]  # (the overview and the sections, listed before the ribs)
        if result.history:
            figures.append(("history.png", plot_history(_SharedHistory(result), bounds)))
        with saved_after([(staging / name, fig) for name, fig in figures], _save):
            save_npz(
                staging / "wing.npz", dict(
                    nodes=np.stack([s.nodes for s in solutions]),
                    tension_span=np.stack([s.tension_span for s in solutions]),
                    tension_chord=np.stack([s.tension_chord for s in solutions]),
                    wrinkled=np.stack([np.asarray(s.wrinkled, bool) for s in solutions]),
                    deviation=deviation, weights=np.asarray(result.weights),
                    stations=np.asarray(result.wing.stations, np.float64),
                    chords=np.asarray(result.wing.chords, np.float64),
                    result=np.asarray(sol.result), residual=np.asarray(sol.residual, np.float64),
                    pressure=np.float64(params.pressure), prestrain=np.array(params.prestrain, np.float64),
                    rib_thickness_scale=np.float64(params.rib_thickness_scale),
                    rib_chord_scale=np.float64(params.rib_chord_scale),
                    target_names=np.array([t.name for t in result.targets], dtype=str),
                    variables=np.array(list(shared), dtype=str),
                    history_objective=np.array([h["objective"] for h in result.history], np.float64),
                    history_values=np.array([np.concatenate([np.ravel(h["values"][n]) for n in shared])
                                             for h in result.history],
                                            np.float64).reshape(len(result.history), -1),
                    rib_shapes=np.zeros((0, 0)) if result.rib_shapes is None else np.asarray(result.rib_shapes),
                    cut_patterns=(np.zeros((0, 0)) if result.cut_patterns is None
                                  else np.asarray(result.cut_patterns))))
            joined = wing_nodes(result)
            write_obj(staging / "skin.obj", joined, sol.bays[0].periodic, name="wing")
            write_stl(staging / "skin.stl", joined, sol.bays[0].periodic)
            files += ["wing.npz", "skin.obj", "skin.stl"]
            files += bay_figures
            if len(sol.bays) > PER_BAY_PLOTS:
                skipped["bay_K_mid_bay_section.png"] = (f"{len(sol.bays)} bays: more than {PER_BAY_PLOTS}, so "
                                                        "wing_overview.png shows every bay in one figure")
            crossed = result.violated_constraints.get("rib_crossing", {})
            if crossed:
                skipped["rib_K.dat"] = f"designed ribs {sorted(crossed)} cross themselves (rib_crossing)"
            if result.rib_shapes is not None:  # each designed rib as a Selig file, as the single bay's rib.dat
                from forward_solver import rib_section

                for k, (airfoil, row) in enumerate(zip(result.wing.sections, np.asarray(result.rib_shapes))):
                    if k in crossed:
                        continue
                    section = rib_section(airfoil, row, float(result.parameters.rib_thickness_scale),
                                          name=f"{airfoil.name} rib {k}")
                    write_selig(staging / f"rib_{k}.dat", section,
                                comment=f"chord {result.wing.chords[k]:g} m")
                    files.append(f"rib_{k}.dat")
            for k in range(len(sol.bays)):
                name = f"bay_{k}_cut_pattern.csv"
                write_cut_pattern(staging / name, sol.scene(k), solutions[k].parameters)
                files.append(name)
            if _patterns_wanted(patterns, summary, skipped):
                names, panels = [], []
                for k in range(len(sol.bays)):
                    more, bay_panels = write_bay_patterns(staging, sol.scene(k), solutions[k].parameters, bay=k,
                                                          ribs=(k if k == 0 else None, k + 1),
                                                          seam_allowance_m=seam_allowance_mm / 1000.0)
                    names += more
                    panels += bay_panels
                files += names
                summary["patterns"] = _pattern_entry(names, panels, seam_allowance_mm)
            if result.history:
                files.append("history.png")
            else:
                skipped["history.png"] = "no optimiser history"
        times = dict(summary["timings_s"])
        times["report"] = time.perf_counter() - start
        times.setdefault("total", sum(v for v in times.values() if isinstance(v, (int, float))))
        summary.update(timings_s=times, files=files + ["summary.json"], skipped=skipped, out=str(out))
        summary["checksums"] = file_checksums(staging, files)  # (`export.changed_files` compares them)
        (staging / "summary.json").write_text(json.dumps(_jsonable(summary), indent=2, allow_nan=False) + "\n")
    return summary
