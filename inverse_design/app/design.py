"""The command's calls into the design library and the solver, for a `case.Case`: one module.

A case is a wing of ribs however it was given, and it runs one path: its
design is `inverse_design.optimise_wing` (`optimise`; a bay given by options
laid out as `inverse_design.optimise_pressure` lays out its bay: one rib
shape, one cut field, `layout`), polished by `inverse_design.refine_design`
(`refine`), or one equilibrium measured by `inverse_design.evaluate_design`
(`evaluate`). The library inputs of a case (`fabric`, `wing`, `start`,
`limits`, `layout`, `solver_settings`), the checks that need the solver
(`check_equilibrium_method`, `check_wing`, `check_flat_panels`), the
tolerances (`tolerances`, `analyse_tolerances`), the aerodynamic comparison
(`aero_angles`, `compare_aero`) and the warnings about the inputs
(`warning_lines`) are made here too. No physics lives here.
"""

from __future__ import annotations

import csv
import math
import os
import sys
import tempfile

from forward_solver import ConvergenceError, Fabric, Parameters, Wing
from forward_solver.derivatives.custom_jvp import GRADIENT_RTOL
from forward_solver.solvers.bays import check_rib_gaps, default_strategy

from .. import methods
from ..aero import AeroUnavailable, aerodynamic_cost, alpha_range, require_neuralfoil
from ..constraints import Constraints
from ..flat_panels import bay_panels
from ..marker import nest_panels, panel_label, widest_panel
from ..memory import design_memory, design_tangents
from ..optimise import evaluate_design, optimise_wing, refine_design
from ..plausibility import LIMITS, check_plausibility
from ..rib_design import RibLimits
from ..settings import DesignRequest, Layout, Limits, SolverSettings
from ..tolerance import SOURCE_UNITS, Sampling, connect_scheduler, parse_tolerances, tolerance_analysis
from . import interrupts, resources
from .case_file import read_config
from .measures import mid_bay_targets
from .options import PROG, InputError

__all__ = ["aero_angles", "analyse_tolerances", "check_equilibrium_method", "check_flat_panels", "check_wing",
           "compare_aero", "evaluate", "fabric", "layout", "limits", "marker", "method", "optimise", "refine",
           "solver_settings", "start", "tolerances", "warning_lines", "wing"]


# ------------------------------------------------------------------ the library inputs of a case
def fabric(case) -> Fabric:
    """The case's `forward_solver.Fabric`: eq. (10) with ``--stiffness-span``, ``--stiffness-chord`` and
    ``--poisson``, or the law fitted to ``--fabric-test`` (`case.Case.law`); its warp along ``--warp``, its
    shear stiffness ``--shear-stiffness``."""
    o = case.options
    if case.law is not None:
        return Fabric(law=case.law, warp=o.warp, shear_stiffness=o.shear_stiffness)
    return Fabric(stiffness_span=o.stiffness_span, stiffness_chord=o.stiffness_chord, poisson=o.poisson, warp=o.warp,
                  shear_stiffness=o.shear_stiffness)


def wing(case) -> Wing:
    """The `forward_solver.Wing` of the case's ribs (a bay given by options: its two ribs)."""
    try:
        return Wing(airfoils=tuple(r.section for r in case.ribs), chords=tuple(r.chord for r in case.ribs),
                    stations=tuple(r.station for r in case.ribs), trailing_edge=case.options.trailing_edge)
    except ValueError as exc:
        raise InputError(f"{case.options.config}: {exc}") from None


def start(case) -> Parameters:
    """The starting parameters: a zero rib shape of 2 ``--rib-shape-terms`` coefficients when ``rib_shape``
    is designed, a zero cut pattern of 2 ``--cut-pattern-terms`` when ``cut_pattern`` is."""
    o = case.options
    parameters = Parameters(pressure=o.pressure, prestrain_span=o.prestrain_span, prestrain_chord=o.prestrain_chord,
                            rib_thickness_scale=o.rib_thickness_scale, rib_chord_scale=o.rib_chord_scale)
    if "rib_shape" in case.designed:
        parameters = parameters.replace(rib_shape=[0.0] * (2 * o.rib_shape_terms))
    if "cut_pattern" in case.designed:
        parameters = parameters.replace(cut_pattern=[0.0] * (2 * o.cut_pattern_terms))
    return parameters


def limits(case) -> Limits:
    o = case.options
    ribs = (RibLimits(min_thickness=o.min_rib_thickness, min_radius=o.min_rib_radius)
            if "rib_shape" in case.designed and not o.no_rib_limits else None)
    tension = None if o.no_tension_constraints else Constraints(min_tension=o.min_tension, max_tension=o.max_tension)
    return Limits(tension=tension, ribs=ribs)


def layout(case, n_span: int | None = None) -> Layout:
    """The design's `inverse_design.Layout` (on ``n_span`` span nodes, default the case's): a case file's
    ribs with a rib shape per rib and ``--cut-pattern-layout``; a bay given by options with one shape
    and one field for both ribs, as `inverse_design.optimise_pressure`."""
    o = case.options
    n_span = o.n_span if n_span is None else n_span
    if not case.from_ribs:
        return Layout(rib_shape="shared", cut_pattern="shared", n_span=n_span, n_contour=o.n_contour)
    return Layout(cut_pattern=o.cut_pattern_layout, n_span=n_span, n_contour=o.n_contour)


def solver_settings(case, progress: bool = False, callback=None) -> SolverSettings:
    """How the design's optimiser and forward solves run (``--max-iterations``, ``--equilibrium-method``,
    ``--max-steps``)."""
    o = case.options
    return SolverSettings(max_iterations=o.max_iterations, equilibrium_method=o.equilibrium_method,
                          max_steps=o.max_steps, progress=progress, callback=callback)


def method(case):
    """The design method (`inverse_design.methods.named`: ``--method`` with ``--tolerance`` and
    ``--root-condition`` where it has them)."""
    o = case.options
    return methods.named(o.method, objective=o.objective, tolerance=o.tolerance, condition=o.root_condition)


# ------------------------------------------------------------------ checks before the long work
def check_equilibrium_method(case, strategy: str | None = None) -> None:
    """Refuse an ``--equilibrium-method`` the design's forward solves cannot honour.

    On the CPU every method is honoured (each bay solved in turn,
    `forward_solver.solve_bays`'s "loop"). On an accelerator (``strategy``
    "batch", default `forward_solver.solvers.bays.default_strategy`) the
    design relaxes every bay together in one batch: relax alone (auto
    becomes relax). ``--evaluate`` solves one equilibrium with the method
    asked for, anywhere.

    Raises:
        InputError: for newton or relax+newton in a design on the batch.
    """
    o = case.options
    strategy = default_strategy() if strategy is None else strategy
    if strategy == "batch" and not o.evaluate and o.equilibrium_method not in ("auto", "relax"):
        raise InputError(f"--equilibrium-method {o.equilibrium_method}: on this machine's accelerator the "
                         "design relaxes its bays together in one batch, which runs relax alone: give "
                         "--equilibrium-method relax or auto, or run on the CPU (JAX_PLATFORMS=cpu)")


def check_wing(case) -> None:
    """Refuse ribs too close for the grid (`forward_solver.solvers.bays.check_rib_gaps`), for a case file's
    ribs and a bay given by options alike, and a design that would not fit in memory
    (`resources.check_design_memory`; not for one equilibrium)."""
    o = case.options
    try:
        check_rib_gaps(case.wing, case.fabric, case.start, n_span=o.n_span, n_contour=o.n_contour,
                       rtol=GRADIENT_RTOL)
    except ValueError as exc:
        if case.from_ribs:
            raise
        raise InputError(f"--rib-spacing {o.rib_spacing:g}: {exc}") from None
    if not o.evaluate:
        resources.check_design_memory(case.n_bays, o.n_span, o.n_contour, _tangents(case),
                                      allow_large=o.allow_large_grid)


def _tangents(case) -> int:
    """The design's Jacobian tangents per bay (`inverse_design.memory.design_tangents`)."""
    o, grid = case.options, layout(case)
    return design_tangents(case.variables, case.n_bays, cut_pattern_terms=o.cut_pattern_terms,
                           rib_shape_terms=o.rib_shape_terms, cut_pattern=grid.cut_pattern, rib_shape=grid.rib_shape)


def _run_memory(case) -> float:
    """The run's estimated peak memory before its samples, bytes: the grid's (`resources.estimate_cost`) or
    the wing design's (`inverse_design.memory.design_memory`), the larger."""
    o = case.options
    grid = resources.estimate_cost(o.n_span, o.n_contour, evaluate=o.evaluate).memory
    return max(grid, design_memory(case.n_bays, o.n_span, o.n_contour, 0 if o.evaluate else _tangents(case)))


#: Rib spacing over mean chord below which `check_flat_panels` lays a bay's panels out before the
#: design: the lower end of the validated range (`inverse_design.plausibility.RANGES`). The default case
#: and the built-in wing lay flat; a tapered bay whose ribs are 1 mm apart (chords 1 and 0.5 m, 9x32)
#: does not (measured: an edge off by 24% of its length), and its design runs to the end before the
#: report fails.
CLOSE_RIBS = 0.05


def check_flat_panels(case) -> None:
    """Refuse a bay whose flat panels cannot be laid out at the start's cut lengths, before the design.

    The report draws each bay's panels (`inverse_design.flat_panels.bay_panels`)
    after the design; a bay whose panels cannot be laid flat then ends the
    run with no report. Only bays with ribs closer than `CLOSE_RIBS` of their
    mean chord are laid out here (about 0.1-1 s each); the cut lengths are
    the start's (a design moves them by its prestrains, rib scales and
    fields, which the layout follows unless the ribs are this close).

    Raises:
        ValueError: naming the bay (and for a case file's ribs, its ribs) and what to change.
    """
    o = case.options
    for k, scene in enumerate(case.wing.scenes(case.fabric, n_span=o.n_span, n_contour=o.n_contour)):
        bay = scene.bay
        if not bay.periodic or bay.rib_spacing >= CLOSE_RIBS * bay.chord:
            continue
        try:
            bay_panels(scene, case.start, bay=k)
        except ValueError as exc:
            where = (f"bay {k} (ribs {k} and {k + 1}, {bay.rib_spacing:.3g} m apart, chords {bay.chord_root:g} and "
                     f"{bay.chord_tip:g} m)" if case.from_ribs else
                     f"the bay (ribs {bay.rib_spacing:.3g} m apart, chord {bay.chord:g} m)")
            raise ValueError(f"{where}: its flat panels cannot be laid out at its cut lengths ({exc}), so no cut "
                             "pattern could be drawn after the design; place the ribs further apart or make their "
                             "chords closer, or give --no-patterns to design without patterns") from None


def tolerances(case) -> dict | None:
    """The parsed manufacturing tolerances (``{name: Tolerance}``), or None when none are given; bad input
    refused before any solve.

    Raises:
        InputError: one line: an unknown or negative tolerance, a stiffness
            scatter of 100% or more of the fabric's, every tolerance 0 for
            ``--objective robust``, more ``--samples`` than the machine holds or
            runs in reasonable time (`resources.check_samples`), a ``--scheduler``
            that does not answer or without the ``distributed`` package.
    """
    o = case.options
    if not o.tolerances:
        return None
    try:
        parsed = parse_tolerances(o.tolerances)
    except ValueError:
        in_file = (read_config(o.config).get("tolerances") or []) if o.config else []
        for item in o.tolerances:  # the item at fault, named where it was given
            try:
                parse_tolerances([item])
            except ValueError as exc:
                if item in in_file:
                    raise InputError(f"{o.config}: [tolerances] {str(exc).removeprefix('tolerance ')}") from None
                raise InputError(f"--{exc}") from None
        raise
    if o.objective == "robust" and not any(t.value > 0 for t in parsed.values()):
        raise InputError("--objective robust designs for the scatter of the tolerances, and every tolerance given "
                         "is 0: give at least one (e.g. --tolerance pressure=2%), or none for the defaults")
    for name in ("stiffness_span", "stiffness_chord"):
        t, nominal = parsed.get(name), getattr(case.fabric, name)
        if t is not None and not t.relative and t.spread(nominal) >= nominal:
            raise InputError(f"--tolerance {name}={t.text} {SOURCE_UNITS[name]} is a scatter of 100% or more of "
                             f"the fabric's {nominal:g} N/m (zero or negative stiffness): give less")
    if o.samples:
        try:
            resources.check_samples(o.samples, case.n_bays, o.n_span, o.n_contour, base=_run_memory(case),
                                    scheduler=bool(o.scheduler), allow_large=o.allow_large_grid)
        except ValueError as exc:
            raise InputError(str(exc)) from None
    if o.scheduler and o.samples:  # (the samples connect again: no connection is held through the design)
        try:
            connect_scheduler(o.scheduler).close()
        except (ImportError, ValueError) as exc:
            raise InputError(f"--scheduler: {exc}") from None
    return parsed


def aero_angles(case):
    """The angles of ``--aero``, after checking that NeuralFoil is installed (`InputError` if not)."""
    try:
        require_neuralfoil()
    except AeroUnavailable as exc:
        raise InputError(f"--aero: {exc}") from None
    try:
        return alpha_range(*case.options.alpha_range)
    except ValueError as exc:
        raise InputError(f"--alpha-range: {exc}") from None


def warning_lines(case) -> list[str]:
    """The lines about the inputs (`inverse_design.plausibility.check_plausibility`: the ranges the model
    is validated for, the seam allowance, the Reynolds number), with the command's own about its grid and
    its fields' terms, which name the options to change."""
    o = case.options
    physical = check_plausibility(case.fabric, case.start, case.bays, None if o.evaluate else case.bounds, warn=False)

    def library(**only) -> list[str]:
        return check_plausibility(case.fabric, case.start, case.bays, None if o.evaluate else case.bounds,
                                  warn=False, **only)[len(physical):]

    least = LIMITS["n_span"]
    lines = list(physical)
    if case.law is not None and case.law.fit_warning() is not None:
        lines.append(case.law.fit_warning())
    if o.min_tension < 0 and not o.no_tension_constraints:
        lines.append(f"--min-tension {o.min_tension:g} N/m lets the skin wrinkle: the fabric carries no compression, "
                     "so a negative fibre tension is a wrinkle, and a wrinkled skin cures wrinkled; give 0 (the "
                     "default) for a wrinkle-free skin")
    if not (o.evaluate or o.refine and 2 * o.n_span - 1 >= least) and o.n_span < least:
        lines.append(f"the design grid has {o.n_span} span nodes, fewer than the {least} that the grid study found "
                     "enough (on 9 the default design lands at 6.4 kPa and rib scale 0.945 against 1 kPa and 1.0 on "
                     f"17 or more; docs/design_studies.md): give --n-span {least} or more, or --refine")
    if not o.no_patterns:
        lines += library(seam_allowance_mm=o.seam_allowance)
    most = LIMITS["terms_per_contour_node"] * o.n_contour
    for name in ("cut_pattern", "rib_shape"):
        count = getattr(o, f"{name}_terms")
        if name in case.designed and count > most:
            lines.append(f"{name.replace('_', ' ')} of {count} terms on {o.n_contour} contour nodes: more than a "
                         f"quarter of the nodes ({most:g}), so each term spans fewer than 4 nodes and the grid "
                         f"cannot resolve it; give --{name.replace('_', '-')}-terms {int(most)} or fewer, or more "
                         "--n-contour")
    if o.aero:
        lines += library(reynolds=o.reynolds)
    return lines


# ------------------------------------------------------------------ the runs
def optimise(case, tolerances: dict | None = None, *, progress: bool = False, callback=None, **changes):
    """The case's design: `inverse_design.optimise_wing` on its wing, targets, variables, start, bounds,
    limits and layout (``tolerances``: those of ``--objective robust``; ``changes``: keyword arguments of
    `optimise_wing` in place of the case's)."""
    o = case.options
    arguments = dict(variables=case.variables, initial=case.start, bounds=case.bounds, objective=o.objective,
                     method=method(case), limits=case.limits, solver=solver_settings(case, progress, callback),
                     layout=case.layout)
    if o.objective == "robust":  # (designed for the tolerances the analysis then reports)
        arguments["tolerances"] = tolerances
    arguments.update(changes)
    return optimise_wing(case.wing, case.fabric, case.targets, DesignRequest(**arguments))


def refine(case, result):
    """``result`` confirmed and polished on twice the span resolution (`inverse_design.refine_design` on
    2 ``--n-span`` - 1 span nodes; what was asked is the result's request)."""
    return refine_design(result, layout(case, 2 * case.options.n_span - 1))


def evaluate(case):
    """One equilibrium of the case at its given values, measured as a design is (`evaluate_design`; solved
    to `forward_solver.solve_equilibrium`'s default residual, not the gradients')."""
    o = case.options
    return evaluate_design(case.wing.scenes(case.fabric, o.n_span, o.n_contour), case.targets, case.start,
                           objective=o.objective, wing=case.wing,
                           solver=SolverSettings(rtol=1e-8, equilibrium_method=o.equilibrium_method,
                                                 max_steps=o.max_steps))


def compare_aero(case, result, alphas) -> list:
    """The `inverse_design.aero.AeroComparison` of each bay: its mid-bay and bay-average sections against
    its mid-bay target, at its mean chord."""
    sol = result.wing_solution
    return [aerodynamic_cost(sol.bay_solution(k), target, float(sol.bays[k].chord), reynolds=case.options.reynolds,
                             alphas=alphas) for k, target in enumerate(mid_bay_targets(result))]


def analyse_tolerances(case, result, parsed: dict, notes: list):
    """`inverse_design.tolerance.tolerance_analysis` of ``result`` with the options' spec, samples and
    seed; the samples stream to a temporary CSV file (its path in the analysis' ``samples_file``, for the
    report to copy), and are not kept in memory (`inverse_design.tolerance.Sampling`'s ``keep_rows``). A
    stop is raised after each sample (`interrupts.check`); the file is removed on a stop, also when the
    stop abandons the work (`interrupts.undo_if_abandoned`).

    A design that does not solve again at its own values (the analysis' nominal solve) is not lost: the
    analysis is skipped with a warning line, kept in ``notes`` (the summary's warnings), and None returned.
    """
    o = case.options
    stream = {"file": None, "writer": None}

    def remove() -> None:
        if stream["file"] is not None:
            stream["file"].close()
            os.unlink(stream["path"])
            stream["file"] = None

    def on_sample(row: dict) -> None:
        if stream["writer"] is None:
            handle, path = tempfile.mkstemp(prefix="tolerance-samples-", suffix=".csv")
            stream["path"] = path
            stream["file"] = os.fdopen(handle, "w", newline="")
            stream["writer"] = csv.DictWriter(stream["file"], fieldnames=list(row))
            stream["writer"].writeheader()
        stream["writer"].writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in row.items()})
        stream["file"].flush()
        interrupts.check()  # (the samples' safe point)

    try:
        with interrupts.undo_if_abandoned(remove):
            analysis = tolerance_analysis(result, parsed, spec=o.shape_spec, sampling=Sampling(
                samples=o.samples, seed=o.seed, on_sample=on_sample, scheduler=o.scheduler or None, keep_rows=False))
    except BaseException as exc:
        remove()
        if not isinstance(exc, ConvergenceError):
            raise
        line = (f"the tolerance analysis is skipped: the design did not solve again at its own values, which the "
                f"analysis linearises about ({exc}); the design's report is written without it")
        notes.append(line)
        if not o.quiet:
            print(f"{PROG}: warning: {line}", file=sys.stderr)
        return None
    if stream["file"] is not None:
        stream["file"].close()
    analysis.samples_file = stream.get("path")
    return analysis



def marker(case, result, *, progress: bool = False, callback=None):
    """The shop's marker of a design (``--roll-width``, `case.Case.marker`): every bay's panels
    (`inverse_design.flat_panels.bay_panels` at the designed cut lengths) nested on the roll
    (`inverse_design.marker.nest_panels`).

    Raises:
        InputError: the roll is narrower than the widest panel (named, with the width it needs): checked
            here, after the design and before the nesting, since a panel's width follows its designed
            cut lengths.
    """
    sol, request, allowance = result.wing_solution, case.marker, case.options.seam_allowance
    panels = []
    for k in range(result.n_bays):
        scene = sol.scene(k) if sol.fabric is not None else result.per_bay.scenes[k]
        panels += bay_panels(scene, sol.bay_solution(k).parameters, bay=k)
    widest, needs = widest_panel(panels, request, allowance)
    if needs > request.roll_width_mm:
        given = "roll-width (case file)" if case.sources.get("roll_width") == "config" else "--roll-width"
        raise InputError(f"{given} {request.roll_width_mm:g} mm is narrower than the {panel_label(widest)}, which "
                         f"needs {needs:.1f} mm across the roll (its cut outline, warp along the {request.warp}, with "
                         f"the {request.gap_mm:g} mm gap): give {given} {math.ceil(needs)} or more (checked after the "
                         "design, whose cut lengths set the panels' widths; nothing was written)")
    return nest_panels(panels, request, seam_allowance_mm=allowance, progress=progress, callback=callback)
