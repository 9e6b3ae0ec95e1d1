"""The report of a design: its summary and the output folder (DESIGN section 7).

`write_report` turns a `DesignResult` (or a single equilibrium `Solution`)
into a folder::

    summary.json          inputs, results, errors before and after, constraints,
                          timings, package version, the files written (`summarise`)
    equilibrium.npz       nodes, tensions, wrinkled cells, deviation, target, parameters
                          (`inverse_design.export.write_npz`)
    skin.obj, skin.stl    the equilibrium skin as a mesh (metres)
    mid_bay_section.png   the mid-bay section against the rib and the target,
                          deviations magnified (`inverse_design.plots.plot_section`)
    deviation.png         the deviation from the target over the whole bay (`plot_deviation`)
    tensions.png          fibre tensions with the wrinkled cells marked (`plot_tensions`)
    history.png           the optimiser's iterates (`plot_history`; skipped for a
                          single equilibrium)
    aero.png              lift, drag and moment against the target (`plot_aero`; only
                          with an `inverse_design.aero.AeroComparison`)
    cut_pattern.csv       the fabric's cut lengths along the contour and the span
                          (`inverse_design.export.write_cut_pattern`)
    rib.dat               the designed rib as a Selig file (`export.write_selig`; only
                          for a shaped rib)
    rib_design.png        the rib's template offset and the thickness kept
                          (`plot_rib_design`; only for a shaped rib)

The folder is written atomically (`inverse_design.export.staged_folder`).
"""

from __future__ import annotations

import json
import math
import platform
import time
from pathlib import Path

import numpy as np

from forward_solver import Solution

from .export import (check_output_folder, staged_folder, write_cut_pattern, write_npz, write_obj, write_selig,
                     write_stl)
from .objectives import design_errors, section_errors
from .optimise import DesignResult
from .plots import plot_aero, plot_deviation, plot_history, plot_rib_design, plot_section, plot_tensions
from .rib_design import RibGeometry, RibLimits, cut_lengths

__all__ = ["summarise", "write_report"]

#: Resolution of the PNG files in the folder, dots per inch.
_DPI = 150


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


def summarise(result, target, scene, *, objective: str | None = None,
              inputs: dict | None = None, timings: dict | None = None, aero=None, rib=None,
              rib_limits: RibLimits | None = None, warnings: list | None = None) -> dict:
    """The summary of a design or a single equilibrium, as `write_report` stores it.

    Args:
        result: a `DesignResult`, or a `Solution` (a single equilibrium).
        target: the target `targets.Airfoil`.
        scene: the `forward_solver.Scene`.
        objective: the sections the errors are measured on (default the
            result's objective, or "mid_bay" for a `Solution`).
        inputs: the caller's options (stored as given).
        timings: seconds, e.g. ``{"setup": ..., "optimisation": ...}``.
        aero: an `inverse_design.aero.AeroComparison` of the result, stored as
            ``summary["aero"]`` (`AeroComparison.as_dict`); None leaves the key out.
        rib: the rib's starting section (default the target), for the rib
            entry of a shaped rib.
        rib_limits: the `rib_design.RibLimits` the design used (default the defaults).
        warnings: lines about the inputs (`plausibility.check_plausibility`),
            stored as ``summary["warnings"]`` (default none).

    Returns:
        A JSON-ready dict. Errors are fractions of chord; ``null`` marks a
        value that does not exist (no upper tension limit, a gradient not
        computed).
    """
    solution, design = _unpack(result)
    objective = objective or (design.objective if design is not None else "mid_bay")
    params = solution.parameters.as_dict()
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
        "warnings": list(warnings or []),
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
                       "rib_chord_scale": params["rib_chord_scale"],
                       "stiffness_span_n_per_m": params["stiffness_span"],
                       "stiffness_chord_n_per_m": params["stiffness_chord"],
                       "rib_shape": params["rib_shape"]},
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
            "violated": dict(design.violated_constraints) if design is not None else None,
            "violated_at_start": dict(design.violated_at_start) if design is not None else None,
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


# ------------------------------------------------------------------ the folder
def write_report(out_dir, result, target, *, scene, objective: str | None = None,
                 bounds: dict | None = None, inputs: dict | None = None,
                 timings: dict | None = None, magnification: float | None = None, aero=None,
                 rib=None, rib_limits: RibLimits | None = None, warnings: list | None = None) -> dict:
    """Write the output folder of a design (or of a single equilibrium) and return its summary.

    Args:
        out_dir: the folder to create, or to write into (replacing only an earlier
            report's files: `staged_folder`).
        result: a `DesignResult` from `optimise_pressure`, or a `Solution`.
        target: the target `targets.Airfoil` (chord-normalised).
        scene: the `forward_solver.Scene` it was solved on.
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
    summary = summarise(result, target, scene, objective=objective, inputs=inputs, timings=timings, aero=aero,
                        rib=rib, rib_limits=rib_limits, warnings=warnings)
    files, skipped = [], {}
    start_rib = target if rib is None else rib
    shaped = solution.parameters.rib_shape is not None
    with staged_folder(out) as staging:
        write_npz(staging / "equilibrium.npz", solution, target, scene, design)
        write_obj(staging / "skin.obj", solution.nodes, scene.bay.periodic, name=scene.bay.name)
        write_stl(staging / "skin.stl", solution.nodes, scene.bay.periodic)
        write_cut_pattern(staging / "cut_pattern.csv", scene, solution.parameters)
        files += ["equilibrium.npz", "skin.obj", "skin.stl", "cut_pattern.csv"]
        if shaped:
            from forward_solver import rib_section

            section = rib_section(start_rib, solution.parameters.rib_shape,
                                  float(solution.parameters.rib_thickness_scale),
                                  name=f"{start_rib.name} designed rib")
            chord = scene.bay.chord * float(solution.parameters.rib_chord_scale)
            write_selig(staging / "rib.dat", section, comment=f"chord {chord:g} m")
            files.append("rib.dat")
        figures = [("mid_bay_section.png", lambda: plot_section(solution, target, scene,
                                                                magnification=magnification,
                                                                start_rib=start_rib if shaped else None)),
                   ("deviation.png", lambda: plot_deviation(solution, target, scene)),
                   ("tensions.png", lambda: plot_tensions(solution, scene))]
        if design is not None and design.history:
            figures.append(("history.png", lambda: plot_history(design, bounds)))
        else:
            skipped["history.png"] = "a single equilibrium has no optimiser history"
        if aero is not None:
            figures.append(("aero.png", lambda: plot_aero(aero)))
        if shaped:
            figures.append(("rib_design.png", lambda: plot_rib_design(
                solution.parameters, start_rib, scene.bay.chord * float(solution.parameters.rib_chord_scale),
                rib_limits)))
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
