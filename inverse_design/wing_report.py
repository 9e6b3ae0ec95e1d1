"""The output folder of a wing design (`optimise.optimise_wing`), like the single bay's.

`write_wing_report` writes, atomically (`export.staged_folder`)::

    summary.json                 inputs, the design, per-bay errors before/after, result
                                 codes, tensions, constraints, timings, versions, files
    wing.npz                     every bay stacked: nodes (n_bays, n_span, n_contour, 3) m
                                 (each bay in its own frame, root rib at y = 0), tensions,
                                 wrinkled cells, deviation from the row targets, ribs
    skin.obj, skin.stl           the whole wing's skin in one mesh (bays joined at their ribs,
                                 y from the root rib), metres (`export.write_obj` / `write_stl`)
    bay_K_mid_bay_section.png    bay K's mid-bay section against its rib and its target
                                 (`plots.plot_section`)
    rib_K.dat                    rib K's designed section (Selig), when the rib shapes were
                                 optimised (`export.write_selig`)
    history.png                  the optimiser's iterates (`plots.plot_history`)

The single-bay helpers are reused as they are; nothing of the single-bay
report changes.
"""

from __future__ import annotations

import json
import platform
import time

import numpy as np

from .export import check_output_folder, staged_folder, write_obj, write_selig, write_stl
from .plots import plot_history, plot_section
from .summary import _jsonable, _version
from .objectives import bay_distances, local_chords, row_targets
from .optimise import DesignResult as WingDesignResult

__all__ = ["wing_deviation", "wing_nodes", "summarise_wing", "write_wing_report"]

_DPI = 150


def wing_nodes(result: WingDesignResult) -> np.ndarray:
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


def wing_deviation(result: WingDesignResult) -> np.ndarray:
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


def summarise_wing(result: WingDesignResult, *, inputs: dict | None = None, timings: dict | None = None,
                   warnings: list | None = None) -> dict:
    """The JSON-ready summary of a wing design (the keys the command line reads as for one bay:
    ``mode``, ``results.success``, ``results.message``, ``constraints.violated``; ``warnings``:
    lines about the inputs, `plausibility.check_plausibility`)."""
    sol = result.wing_solution
    params = result.parameters.resolved(sol.fabric).as_dict()
    stations = np.asarray(result.wing.stations, np.float64)
    specs = [r.get("section") for r in (inputs or {}).get("wing") or []]  # the case file's section specs
    bays = []
    for k, bay in enumerate(sol.bays):
        solution = sol.bay_solution(k)
        bays.append({
            "bay": k, "ribs": [k, k + 1], "span_m": [stations[k], stations[k + 1]],
            "chords_m": [bay.chord_root, bay.chord_tip], "weight": result.weights[k],
            "targets": [result.targets[k].name, result.targets[k + 1].name],
            "result": result.bay_results[k], "steps": int(np.asarray(sol.steps)[k]),
            "relative_residual": float(np.asarray(sol.residual)[k]),
            "errors_before": {"rms": result.initial_bay_rms_error[k], "max": result.initial_bay_max_error[k]},
            "errors_after": {"rms": result.bay_rms_error[k], "max": result.bay_max_error[k]},
            "min_tension_n_per_m": result.bay_min_tension[k], "max_tension_n_per_m": result.bay_max_tension[k],
            "wrinkled_fraction": solution.wrinkled_fraction,
        })
    fabric = sol.fabric
    summary = {
        "package": {"name": "inflatable-wing", "version": _version("inflatable-wing")},
        "versions": {"python": platform.python_version(), "jax": _version("jax"), "numpy": np.__version__},
        "mode": "wing",
        "inputs": dict(inputs or {}),
        "warnings": list(warnings or []),
        "case": {
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
                       "stiffness_chord_n_per_m": params["stiffness_chord"]},
            "rib_shapes": None if result.rib_shapes is None else np.asarray(result.rib_shapes).tolist(),
            "rib_shape_max_abs": None if result.rib_shapes is None else float(np.max(np.abs(result.rib_shapes))),
            "rib_limits": list(result.rib_limits),
            "variables": list(result.variables), "method": result.method,
            "iterations": len(result.history), "forward_solves": result.solves,
            "wall_time_s": result.wall_time, "bays": bays,
        },
        "errors": {
            "unit": "fraction of the local chord", "objective": result.objective,
            "weighting": "bay planform area",
            "before": {"rms": result.initial_rms_error}, "after": {"rms": result.rms_error},
        },
        "constraints": {
            "active": list(result.active_constraints),
            "violated": _per_place(result.violated_constraints),
            "violated_at_start": _per_place(result.violated_at_start),
            "values": dict(result.constraint_values), "unit": "N/m",
        },
        "timings_s": dict(timings or {}),
        "history": list(result.history),
    }
    return _jsonable(summary)


def _per_place(violated: dict) -> dict:
    """``{name: {"bay K" (tension limits) or "rib K" (rib limits): amount}}``."""
    return {name: {f"{'rib' if name.startswith('rib_') else 'bay'} {k}": v for k, v in per_index.items()}
            for name, per_index in violated.items()}


class _SharedHistory:
    """The result as `plots.plot_history` reads it, with the shared variables only (per-rib shapes
    are many coefficients; they are in summary.json's history and the rib_K.dat files)."""

    def __init__(self, result: WingDesignResult):
        names = tuple(n for n in result.variables if n != "rib_shape")
        self.variables, self.method, self.objective = names, result.method, result.objective
        self.rms_error, self.success, self.values = result.rms_error, result.success, result.values
        self.history = [{**h, "values": {n: h["values"][n] for n in names}} for h in result.history]


def write_wing_report(out_dir, result: WingDesignResult, *, bounds: dict | None = None,
                      inputs: dict | None = None, timings: dict | None = None,
                      magnification: float | None = None, warnings: list | None = None) -> dict:
    """Write the output folder of a wing design and return its summary (module docstring).

    Args:
        out_dir: the folder to create, or to write into (replacing only an earlier
            report's files: `export.staged_folder`).
        result: the `optimise.DesignResult` of the wing.
        bounds: variable bounds to draw in the history plot.
        inputs: the caller's options (stored as given).
        timings: seconds spent before the report; ``report`` and ``total`` are added.
        magnification: deviation factor of the section plots (default automatic).
        warnings: lines about the inputs, stored as ``summary["warnings"]``.

    Returns:
        The summary, with ``files``, ``skipped`` and ``out``.

    Raises:
        ValueError: if ``out_dir`` cannot be written (`export.check_output_folder`).
    """
    start = time.perf_counter()
    out = check_output_folder(out_dir)
    summary = summarise_wing(result, inputs=inputs, timings=timings, warnings=warnings)
    sol = result.wing_solution
    files, skipped = [], {}
    with staged_folder(out) as staging:
        solutions = [sol.bay_solution(k) for k in range(len(sol.bays))]
        params = result.parameters
        shared = [n for n in result.variables if n != "rib_shape"]
        with open(staging / "wing.npz", "wb") as f:
            np.savez_compressed(
                f, nodes=np.stack([s.nodes for s in solutions]),
                tension_span=np.stack([s.tension_span for s in solutions]),
                tension_chord=np.stack([s.tension_chord for s in solutions]),
                wrinkled=np.stack([np.asarray(s.wrinkled, bool) for s in solutions]),
                deviation=wing_deviation(result), weights=np.asarray(result.weights),
                stations=np.asarray(result.wing.stations, np.float64),
                chords=np.asarray(result.wing.chords, np.float64),
                result=np.asarray(sol.result), residual=np.asarray(sol.residual, np.float64),
                pressure=np.float64(params.pressure), prestrain=np.array(params.prestrain, np.float64),
                rib_thickness_scale=np.float64(params.rib_thickness_scale),
                rib_chord_scale=np.float64(params.rib_chord_scale),
                target_names=np.array([t.name for t in result.targets], dtype=str),
                variables=np.array(list(shared), dtype=str),
                history_objective=np.array([h["objective"] for h in result.history], np.float64),
                history_values=np.array([[h["values"][n] for n in shared] for h in result.history],
                                        np.float64).reshape(-1, len(shared)),
                rib_shapes=np.zeros((0, 0)) if result.rib_shapes is None else np.asarray(result.rib_shapes))
        joined = wing_nodes(result)
        write_obj(staging / "skin.obj", joined, sol.bays[0].periodic, name="wing")
        write_stl(staging / "skin.stl", joined, sol.bays[0].periodic)
        files += ["wing.npz", "skin.obj", "skin.stl"]
        for k, bay in enumerate(sol.bays):
            target = row_targets(result.targets[k], result.targets[k + 1], bay.chord_root, bay.chord_tip,
                                 [0.5])[0]
            name = f"bay_{k}_mid_bay_section.png"
            fig = plot_section(solutions[k], target, sol.scene(k), magnification=magnification)
            fig.suptitle(f"bay {k} (ribs {k}-{k + 1}): {fig.get_suptitle()}")
            fig.savefig(staging / name, dpi=_DPI)
            files.append(name)
        if result.rib_shapes is not None:  # each designed rib as a Selig file, as the single bay's rib.dat
            from forward_solver import rib_section

            for k, (airfoil, row) in enumerate(zip(result.wing.sections, np.asarray(result.rib_shapes))):
                section = rib_section(airfoil, row, float(result.parameters.rib_thickness_scale),
                                      name=f"{airfoil.name} rib {k}")
                write_selig(staging / f"rib_{k}.dat", section, comment=f"chord {result.wing.chords[k]:g} m")
                files.append(f"rib_{k}.dat")
        if result.history:
            plot_history(_SharedHistory(result), bounds).savefig(staging / "history.png", dpi=_DPI)
            files.append("history.png")
        else:
            skipped["history.png"] = "no optimiser history"
        times = dict(summary["timings_s"])
        times["report"] = time.perf_counter() - start
        times.setdefault("total", sum(v for v in times.values() if isinstance(v, (int, float))))
        summary.update(timings_s=times, files=files + ["summary.json"], skipped=skipped, out=str(out))
        (staging / "summary.json").write_text(json.dumps(_jsonable(summary), indent=2, allow_nan=False) + "\n")
    return summary
