"""The output folder of a design of N >= 1 bays: every file of the report, by one path (`write_report`).

A bay given by options and the same bay given as a two-rib case file write
the same files (docs/command.md lists them): ``summary.json``
(`summary.summarise`), ``wing.npz`` (every bay stacked, `formats.wing_arrays`),
``skin.obj`` and ``skin.stl`` (one mesh), ``wing_overview.png``,
``cut_pattern_overview.png`` (a cut field per bay), ``history.png``,
``tolerance.png`` and ``tolerance_samples.csv`` (`wing_figures`), each bay's
``bay_K_mid_bay_section.png`` (at most `PER_BAY_PLOTS` bays),
``bay_K_aero.png`` and ``bay_K_cut_pattern.csv``, a designed rib's
``rib.dat`` or ``rib_K.dat``, and the cut-ready ``pattern_bay_K_*.dxf/.svg``
and ``rib_K.dxf`` (`cut_files`; a successful design only, not with
``patterns=False``: ``skipped`` says why). A single bay adds
``equilibrium.npz`` (`formats.bay_arrays`), ``deviation.png``,
``tensions.png`` and ``rib_design.png`` (`bay_figures`). The deviation in
the files and figures is `measures.wing_deviation`'s.

The folder is written by `output_folder.staged_folder`: only the tool's own
files are replaced, nothing else in the folder is touched; the files are
plain names in the folder (the staging and ownership rules own plain files
only). Each figure is built in the calling process (where JAX may be called);
the command hands the built figures (pickled `matplotlib.figure.Figure`
objects, in `_SAVE_ORDER`) and then the DXF patterns to its
`workers.ReportWorkers` (processes started with the command, which import
matplotlib and ezdxf, not JAX, while the design runs) to save; what they do
not write, and every file of a library caller's report, is written here.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import platform
import shutil
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from forward_solver import rib_section

from ..optimise import DesignResult
from ..rib_design import cut_lengths
from .bay_figures import plot_deviation, plot_rib_design, plot_section, plot_tensions
from .marker_files import write_marker_files
from .patterns import write_bay_patterns
from .formats import bay_arrays, wing_arrays, write_cut_pattern, write_npz, write_obj, write_selig, write_stl
from .measures import chords_and_stations, mid_bay_targets, wing_deviation, wing_nodes
from .output_folder import file_checksums, staged_folder
from .summary import jsonable, rib_files, shared_names, summarise
from .wing_figures import plot_aero, plot_cut_fields, plot_history, plot_tolerance, plot_wing_overview
from .workers import run_task, save_figure, saved_after

__all__ = ["PER_BAY_PLOTS", "ReportOptions", "peak_memory_mb", "write_report"]

#: zlib level of the PNG figures: 3 writes them 0.07 s faster each than PIL's default 6, 13% larger.
_PNG_COMPRESSION = 3
#: `matplotlib.figure.Figure.savefig`'s options for the PNG figures: 150 dots per inch.
_SAVE_OPTIONS = {"dpi": 150, "pil_kwargs": {"compress_level": _PNG_COMPRESSION}}
#: A wing of at most this many bays also gets one mid-bay section plot per bay (more: only
#: ``wing_overview.png``, which shows every bay; a plot per bay took 0.3 s each and 15 s of a 40-bay report).
PER_BAY_PLOTS = 8
#: The order in which the figures are handed to the workers, the slowest first (saving each on the
#: 2-core development machine, 2026-11-25: history 0.35-0.39 s, tensions 0.34 s, mid-bay section
#: 0.28 s, deviation 0.24 s; the wing overview, added later, last). Figures not named keep their place
#: after these.
_SAVE_ORDER = ("history.png", "tensions.png", "bay_0_mid_bay_section.png", "deviation.png", "wing_overview.png",
               "cut_pattern_overview.png")


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
        figures: draw the figures (every ``.png``, the marker's too); without
            them each is in ``skipped``, with why.
        inputs, warnings, aero: the run's inputs, its warning lines and each
            bay's aerodynamic polar, recorded as `summary.summarise` does (``aero``
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
    figures: bool = True
    inputs: dict | None = None
    timings: dict | None = None
    aero: object = None
    warnings: list | None = None
    tolerance: object = None

    def __post_init__(self):
        value = float(self.seam_allowance_mm)
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"the seam allowance must be 0 mm or more (the cut line lies outside the sewing "
                             f"line), got {self.seam_allowance_mm!r} mm: give --seam-allowance 0 or a positive number")


def write_report(out, result: DesignResult, *, options: ReportOptions | None = None, workers=None,
                 marker=None) -> dict:
    """Write the output folder of a design (or of a single equilibrium) of N >= 1 bays; return its summary.

    Args:
        out: the folder to create, or to write into (replacing only an earlier
            report's files: `output_folder.staged_folder`), as
            `output_folder.check_output_folder` checked it (the command checks
            it before the long work).
        result: a `DesignResult` of airfoil bays (`optimise_pressure`, `optimise_wing`,
            `evaluate_design`): it carries its wing, bays and targets.
        options: what the report holds beside the design and how it is drawn
            (`ReportOptions`; None: the defaults).
        workers: `workers.ReportWorkers` started before the design (the
            command's), to save the figures built here and to
            write the DXF patterns while this process writes the other
            files; what they do not write is written here. Default none:
            every file is written here.
        marker: the design's marker (`inverse_design.marker.Marker`, the command's ``--roll-width``) or
            None: ``marker.dxf``, ``.svg``, ``.png`` (`marker_files`) and ``summary["marker"]``; its
            panels are the pattern files' (laid out once).

    Returns:
        The summary (as written to ``summary.json``), with ``files`` (names in
        the folder), ``skipped`` (files not written and why) and ``out`` (the
        folder's absolute path).

    Raises:
        TypeError: if ``result`` is not a `DesignResult` of a wing, or ``options`` not a `ReportOptions`.
    """
    options = ReportOptions() if options is None else options
    if not isinstance(options, ReportOptions):
        raise TypeError(f"options must be a ReportOptions, got {type(options).__name__}")
    if not (isinstance(result, DesignResult) and result.wing is not None):
        raise TypeError(f"expected an inverse_design.DesignResult of airfoil bays (a single equilibrium: measure "
                        f"it with inverse_design.evaluate_design), got {type(result).__name__}")
    start = time.perf_counter()
    out = Path(os.path.abspath(os.fspath(out)))
    bays = _Bays(result)
    files, skipped = [], {}
    with staged_folder(out) as staging:
        # Each figure is a plotting function and its arguments, built here; the report's workers, if
        # there are any, save them, else they are saved after the other files are written
        # (`workers.saved_after`).
        specs = _figures(bays, options, skipped)
        if not options.figures:
            skipped.update((name, "not asked for (--no-figures)") for name, *_ in specs)
            specs = []
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
            summary = summarise(result, inputs=options.inputs, timings=options.timings, aero=options.aero,
                                warnings=options.warnings)
            if options.tolerance is not None:
                summary["tolerance"] = options.tolerance.summary()
                if options.tolerance.samples_file:  # (the rows the run streamed)
                    shutil.copyfile(options.tolerance.samples_file, staging / "tolerance_samples.csv")
                    files.append("tolerance_samples.csv")
            with saved_after(built, _save):
                _write_data(staging, bays, files, skipped)
                if marker is not None:
                    files += write_marker_files(staging, marker, picture=options.figures)
                    if not options.figures:
                        skipped["marker.png"] = "not asked for (--no-figures)"
                    summary["marker"] = marker.summary()
                if _patterns_wanted(options.patterns, summary, skipped):
                    laid = {} if marker is None else {(p.bay, p.name): p.panel for p in marker.pieces}
                    names, panels = _write_patterns(staging, bays, options.seam_allowance_mm, workers, sent, laid)
                    files += names
                    summary["patterns"] = _pattern_entry(names, panels, options.seam_allowance_mm)
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
        summary["checksums"] = file_checksums(staging, files)  # (`output_folder.changed_files` compares them)
        text = json.dumps(jsonable(summary), indent=2, allow_nan=False)
        (staging / "summary.json").write_text(text + "\n")
    return summary


class _Bays:
    """The design and what the report draws of each bay: its solution (without LU factors, which do not
    pickle for the workers), scene and mid-bay target, the ribs' stations and the deviation of every node
    from its row's target (`measures.wing_deviation`)."""

    def __init__(self, result: DesignResult):
        sol = result.wing_solution
        self.result, self.n = result, result.n_bays
        self.solutions = [sol.bay_solution(k).without_factor() for k in range(self.n)]
        self.scenes = [sol.scene(k) if sol.fabric is not None else result.per_bay.scenes[k] for k in range(self.n)]
        self.targets = mid_bay_targets(result)
        self.stations = chords_and_stations(result)[1]
        self.deviation = wing_deviation(result)


def _figures(bays: _Bays, options: ReportOptions, skipped: dict) -> list:
    """``[(name, plotting function, args, kwargs)]`` of the report's figures (module docstring); a figure
    not drawn, with why, goes to ``skipped``."""
    result, n_bays, solutions, scenes, targets = bays.result, bays.n, bays.solutions, bays.scenes, bays.targets
    shaped = rib_files(result)
    specs = [("wing_overview.png", plot_wing_overview, (_Overview(result), bays.deviation), {})]
    for k in range(n_bays if n_bays <= PER_BAY_PLOTS else 0):
        start_rib = result.wing.sections[k] if shaped else None
        specs.append((f"bay_{k}_mid_bay_section.png", plot_section, (solutions[k], targets[k], scenes[k]),
                      dict(magnification=options.magnification, start_rib=start_rib, bay=k,
                           rib_stations=(bays.stations[k], bays.stations[k + 1]))))
        if options.aero is not None:
            specs.append((f"bay_{k}_aero.png", plot_aero, (options.aero[k],), {}))
    if result.per_bay.cut_patterns is not None:  # a cut field per bay: every bay's in one image
        specs.append(("cut_pattern_overview.png", plot_cut_fields, _cut_fields(scenes, solutions), {}))
    if n_bays > PER_BAY_PLOTS:
        skipped["bay_K_mid_bay_section.png"] = (f"{n_bays} bays: more than {PER_BAY_PLOTS}, so "
                                                "wing_overview.png shows every bay in one figure")
    if result.history:
        specs.append(("history.png", plot_history, (_SharedHistory(result), options.bounds), {}))
    else:
        skipped["history.png"] = "a single equilibrium has no optimiser history"
    if n_bays == 1:  # the one-bay extras
        specs += [("deviation.png", plot_deviation, (solutions[0], targets[0], scenes[0], bays.deviation[0]), {}),
                  ("tensions.png", plot_tensions, (solutions[0], scenes[0]), {})]
        if result.parameters.rib_shape is not None:
            chord = scenes[0].bay.chord * float(result.parameters.rib_chord_scale)
            specs.append(("rib_design.png", plot_rib_design, (
                result.parameters, result.wing.sections[0], chord, options.rib_limits), {}))
    tolerance = options.tolerance
    if tolerance is not None:
        sampled = tolerance.sampled_rms if tolerance.sampled_rms is not None and tolerance.sampled_rms.size else None
        specs.append(("tolerance.png", plot_tolerance, (tolerance.summary(), tolerance.linear_rms, sampled), {}))
    return specs


def _write_data(staging: Path, bays: _Bays, files: list, skipped: dict) -> None:
    """The data files of the folder (module docstring): npz, meshes, cut lengths, designed ribs (each
    name written is appended to ``files``; a rib not drawn, with why, goes to ``skipped``)."""
    result, solutions, scenes = bays.result, bays.solutions, bays.scenes
    sol, params = result.wing_solution, result.parameters
    write_npz(staging / "wing.npz", wing_arrays(result, solutions, bays.deviation))
    joined = wing_nodes(result)
    periodic = sol.bays[0].periodic
    write_obj(staging / "skin.obj", joined, periodic, name="wing" if result.n_bays > 1 else sol.bays[0].name)
    write_stl(staging / "skin.stl", joined, periodic)
    files += ["wing.npz", "skin.obj", "skin.stl"]
    if result.n_bays == 1:  # the one-bay extra: the bay in full (a single equilibrium: no variables, no history)
        write_npz(staging / "equilibrium.npz", bay_arrays(solutions[0], bays.targets[0], scenes[0],
                                                          bays.deviation[0], result if result.variables else None))
        files.append("equilibrium.npz")
    for k in range(result.n_bays):
        name = f"bay_{k}_cut_pattern.csv"
        write_cut_pattern(staging / name, scenes[k], solutions[k].parameters)
        files.append(name)
    names = rib_files(result)
    if not names:
        return
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


def _write_patterns(staging: Path, bays: _Bays, seam_allowance_mm: float, workers, sent: list, laid: dict) -> tuple:
    """Every bay's flat panels and rib templates (`patterns.write_bay_patterns`): ``(names, panels)``; the
    panels already laid out for the marker (``laid``: ``{(bay, name): Panel}``) are not laid out again.
    With workers that took every task so far (``sent``, the figures', extended here; none with
    ``--no-figures``), each bay's DXF and SVG files are handed to them at once: they draw and write them
    while this process lays out the next bays' panels."""
    tasks = []  # (the files go to the workers, which have ezdxf imported)
    handed = workers is not None and workers.submitted == len(sent)
    writer = (lambda path, function, *args: tasks.append((path, function, args, {}))) if handed else None
    names, panels = [], []
    for k in range(bays.n):
        known = [panel for (bay, _), panel in laid.items() if bay == k] or None
        more, bay_panels = write_bay_patterns(staging, bays.scenes[k], bays.solutions[k].parameters, bay=k,
                                              ribs=(k if k == 0 else None, k + 1),
                                              seam_allowance_m=seam_allowance_mm / 1000.0, writer=writer,
                                              panels=known)
        names += more
        panels += bay_panels
        if tasks and workers.submit(tasks):
            sent += tasks
        else:
            for task in tasks:
                run_task(task)
        tasks.clear()
    return names, panels


def _save(fig, path) -> None:
    save_figure(path, fig, **_SAVE_OPTIONS)


def _cut_fields(scenes: list, solutions: list) -> tuple:
    """`wing_figures.plot_cut_fields`'s arguments: every bay's contour arc (fraction of its root rib's cut
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

class _Overview:
    """What `wing_figures.plot_wing_overview` reads of a result, as plain values: it pickles for the report's
    workers (a `DesignResult` carries its scenes, solutions and targets)."""

    def __init__(self, result: DesignResult):
        self.wing = SimpleNamespace(stations=tuple(float(y) for y in chords_and_stations(result)[1]))
        self.parameters = SimpleNamespace(pressure=float(result.parameters.pressure))
        for name in ("initial_rms_error", "rms_error", "max_error", "min_tension", "max_tension"):  # per bay
            setattr(self, name.replace("initial_", "initial_bay_") if "initial" in name else f"bay_{name}",
                    np.asarray(getattr(result.per_bay, name), np.float64))
        self.constraint_values = dict(result.constraint_values)
        self.success, self.variables, self.method, self.solves = (bool(result.success), tuple(result.variables),
                                                                  result.method, int(result.solves))
        self.initial_rms_error, self.rms_error = float(result.initial_rms_error), float(result.rms_error)


class _SharedHistory:
    """The result as `wing_figures.plot_history` reads it, with the shared variables only (per-rib shapes and
    per-bay cut fields are many coefficients; they are in summary.json's history, the rib_K.dat and
    bay_K_cut_pattern.csv files). Plain values: it pickles for the report's workers."""

    def __init__(self, result: DesignResult):
        names = shared_names(result)
        self.variables, self.method, self.objective = names, result.method, result.objective
        self.rms_error, self.success = result.rms_error, result.success
        self.values = {n: v for n, v in result.values.items() if n in names}
        self.history = [{**h, "values": {n: h["values"][n] for n in names}} for h in result.history]
