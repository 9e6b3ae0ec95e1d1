"""``optimise-pressure --config wing.toml``: a case file that describes a whole wing.

A case file with ``[[rib]]`` tables (two or more, root to tip) describes a
wing; `cli.read_config` hands them to `read_ribs` and `cli.run` to
`run_wing`, which calls `optimise.optimise_wing` (one pressure, and the
other ``variables``, for every bay) and `wing_report.write_wing_report`::

    variables = ["pressure"]
    pressure-bounds = [1e3, 1e5]
    n-span = 17
    n-contour = 64

    [[rib]]
    section = "naca2412"   # a NACA code or a Selig/Lednicer .dat path (relative to the case file's folder)
    chord = 1.0            # m
    station = 0.0          # m, span position
    [[rib]]
    section = "naca2412"
    chord = 0.8
    station = 0.3
    # target = "naca2412"  # optional: this rib's target section (default: the section itself,
    #                      # or the case's --target when one is given)

The other keys are the single-bay options that apply to a wing (grid,
fabric, prestrain, pressure, variables and bounds, tension limits,
objective, ``max-iterations``, ``tolerance``, output; with ``rib_shape``
among the variables every rib gets its own shape, ``rib-shape-terms``
coefficients per surface within ``rib-shape-bounds``, each rib held to the
rib limits ``min-rib-thickness`` and ``min-rib-radius`` against its own
section unless ``no-rib-limits``); those that do not
(``chord``, ``rib-spacing``, ``rib``, ``method`` other than slsqp,
``refine``, ``evaluate``, ``aero``) are refused with what to change.
``trailing-edge`` (close, open, as-given) says how ribs with closed and
open trailing edges are brought to one form (`forward_solver.wing.Wing`);
a changed rib is noted in the summary and on the console. Bad
wing input exits 2 with one line naming the file and the rib. An example:
``inverse_design/cases/wing_taper.toml``.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

from .resources import check_grid

__all__ = ["RIB_KEYS", "EXAMPLE_CASE", "describe_wing", "read_ribs", "run_wing"]

#: Keys of a ``[[rib]]`` table: required, then optional.
RIB_KEYS = (("section", "chord", "station"), ("target",))
#: The built-in example: a 3-bay tapered NACA 2412 wing.
EXAMPLE_CASE = Path(__file__).parent / "cases" / "wing_taper.toml"

#: Options that mean nothing for a wing, and what to do instead.
_NOT_FOR_A_WING = {
    "chord": "give each rib's chord in its [[rib]] table",
    "rib_spacing": "give each rib's station in its [[rib]] table",
    "rib": "give each rib's section in its [[rib]] table",
    "refine": "run the wing again on a finer grid (n-span, n-contour)",
    "evaluate": "optimise the wing, or solve it with forward_solver.solve_wing",
    "aero": "compare the sections of a single bay",
}


def _error(message: str):
    from .cli import InputError

    return InputError(message)


def read_ribs(path: str, tables) -> list[dict]:
    """Check the ``[[rib]]`` tables of a case file; return them as ``[{section, chord, station, target}]``.

    Each section (and target) is loaded once here, so that an unknown one is
    refused before any work.

    Raises:
        cli.InputError: one line naming the file, the rib (0 is the root) and what to change.
    """
    from .cli import _airfoil, case_path

    required, optional = RIB_KEYS
    if not isinstance(tables, list) or len(tables) < 2:
        n = len(tables) if isinstance(tables, list) else 0
        raise _error(f"{path}: a wing needs at least two [[rib]] tables (root and tip), got {n}; add ribs")
    ribs = []
    for k, table in enumerate(tables):
        where = f"{path}: rib {k}"
        unknown = sorted(set(table) - set(required) - set(optional))
        if unknown:
            raise _error(f"{where}: unknown key(s) {unknown}; a [[rib]] table has {', '.join(required)} "
                         f"and optionally {', '.join(optional)}")
        missing = [key for key in required if key not in table]
        if missing:
            raise _error(f"{where}: missing {', '.join(missing)}; every [[rib]] needs section (a NACA code "
                         "or a .dat file), chord (m) and station (m, span position)")
        rib = {}
        for key in ("chord", "station"):
            value = table[key]
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise _error(f"{where}: {key} must be a finite number in m, got {value!r}")
            rib[key] = float(value)
        if not rib["chord"] > 0:
            raise _error(f"{where}: chord must be a positive length in m, got {rib['chord']!r}")
        if k and not rib["station"] > ribs[-1]["station"]:
            raise _error(f"{where}: station {rib['station']:g} m does not lie beyond rib {k - 1}'s "
                         f"({ribs[-1]['station']:g} m); list the ribs root to tip with increasing stations")
        for key in ("section", "target"):
            if key not in table:
                continue
            if not isinstance(table[key], str):
                raise _error(f"{where}: {key} must be a NACA code such as \"naca2412\" or a .dat path, "
                             f"got {table[key]!r}")
            rib[key] = case_path(path, table[key])  # a relative .dat path: beside the case file
            _airfoil(rib[key], f"{where}: {key}")  # refuses an unknown section now
        ribs.append(rib)
    return ribs


def run_wing(args, sources: dict | None = None, progress: bool = False, started: float | None = None) -> dict:
    """Optimise the wing of ``args.wing`` (from `read_ribs`), write the folder, return its summary.

    Raises:
        ValueError: bad input (`cli.InputError` among them).
        forward_solver.ConvergenceError: a bay's solve at the start failed (nothing written).
    """
    from .cli import _airfoil, _safe_point, design_inputs, plausibility

    start = time.perf_counter() if started is None else started
    sources = dict(sources or {})
    for option, instead in _NOT_FOR_A_WING.items():
        if option in sources:
            raise _error(f"{option.replace('_', '-')} does not apply to a wing ([[rib]] tables in "
                         f"{args.config}): {instead}")
    if args.method != "slsqp":
        raise _error(f"method {args.method} is not available for a wing ([[rib]] tables in {args.config}); "
                     "use slsqp (the default)")
    if args.equilibrium_method not in ("auto", "relax"):
        raise _error(f"equilibrium-method {args.equilibrium_method} is not available for a wing ([[rib]] tables "
                     f"in {args.config}): its bays are relaxed together; use auto or relax")
    if args.max_steps < 1:
        raise _error(f"max-steps must be a positive integer, got {args.max_steps}")
    check_grid(args.n_span, args.n_contour, allow_large=args.allow_large_grid)  # (per bay)
    where = args.config
    common = _airfoil(args.target, "--target") if "target" in sources else None
    sections = [_airfoil(r["section"], f"{where}: rib {k}: section") for k, r in enumerate(args.wing)]
    targets = [(_airfoil(r["target"], f"{where}: rib {k}: target") if "target" in r else
                common if common is not None else sections[k]) for k, r in enumerate(args.wing)]
    from forward_solver import Fabric
    from forward_solver.wing import Wing

    from .export import check_output_folder
    from .optimise import optimise_wing
    from .wing_report import write_wing_report

    out = check_output_folder(args.out)
    try:
        wing = Wing(airfoils=tuple(sections), chords=tuple(r["chord"] for r in args.wing),
                    stations=tuple(r["station"] for r in args.wing), trailing_edge=args.trailing_edge)
    except ValueError as exc:
        raise _error(f"{where}: {exc}") from None
    fabric = Fabric(stiffness_span=args.stiffness_span, stiffness_chord=args.stiffness_chord,
                    poisson=args.poisson)
    initial, variables, rib_limits, bounds, constraints = design_inputs(args)  # (one shape per rib)
    chords, stations = wing.chords, wing.stations
    notes = plausibility(args, fabric, initial, [(stations[k + 1] - stations[k], 0.5 * (chords[k] + chords[k + 1]))
                                                 for k in range(len(chords) - 1)], bounds)
    timings = {"setup": time.perf_counter() - start}
    t = time.perf_counter()
    result = optimise_wing(wing, fabric, targets, variables, initial=initial, bounds=bounds,
                           objective=args.objective, constraints=constraints, rib_limits=rib_limits,
                           n_span=args.n_span, max_steps=args.max_steps,
                           n_contour=args.n_contour, max_iterations=args.max_iterations,
                           **({} if args.tolerance is None else {"tolerance": args.tolerance}),
                           progress=progress, callback=_safe_point)
    timings["optimisation"] = time.perf_counter() - t
    inputs = {**vars(args), "sources": sources}
    _safe_point()
    return write_wing_report(out, result, bounds=bounds, inputs=inputs, timings=timings,
                             magnification=args.magnification, warnings=notes)


def describe_wing(summary: dict) -> list[str]:
    """The console lines of a finished wing run."""
    from .cli import start_violation_line

    res, err = summary["results"], summary["errors"]
    v = res["values"]
    ribs = summary["case"]["ribs"]
    lines = [f"wing of {len(ribs) - 1} bays ({ribs[0]['chord_m']:g} to {ribs[-1]['chord_m']:g} m chord, "
             f"{ribs[-1]['station_m'] - ribs[0]['station_m']:g} m span), {summary['case']['grid'][0]}x"
             f"{summary['case']['grid'][1]} grid per bay, {err['objective']} objective"]
    chosen = ", ".join(f"{n} {v['pressure_pa' if n == 'pressure' else n]:.6g}" + (" Pa" if n == "pressure" else "")
                       for n in res["variables"] if n != "rib_shape")
    if "rib_shape" in res["variables"]:
        chosen += f", a rib shape per rib (rib_K.dat; largest coefficient {res['rib_shape_max_abs']:.3g})"
    trailing = summary["case"].get("trailing_edge") or {}
    for change in trailing.get("changed", []):
        source = change.get("file") or change["section"]
        lines.append(f"  rib {change['rib']} ({source}): trailing edge {'closed' if change['gap_after'] == 0 else 'opened'}"
                     f", gap {change['gap_before']:.3g} -> {change['gap_after']:.3g} chord over the last "
                     f"{change['blend']:.0%} of chord (--trailing-edge {trailing['option']})")
    lines.append(f"  {res['method']}: {chosen}")
    lines.append(f"  wing error rms {err['before']['rms']:.3e} -> {err['after']['rms']:.3e} (area-weighted)")
    for bay in res["bays"]:
        lines.append(f"  bay {bay['bay']}: {bay['result']}, rms {bay['errors_before']['rms']:.3e} -> "
                     f"{bay['errors_after']['rms']:.3e}, max {bay['errors_after']['max']:.3e} chord, "
                     f"tension {bay['min_tension_n_per_m']:.4g} to {bay['max_tension_n_per_m']:.4g} N/m")
    violated = summary["constraints"]["violated"] or {}
    shown = ", ".join(f"{name} in {bay} by {amount:.4g} N/m" for name, per_bay in violated.items()
                      for bay, amount in per_bay.items())
    lines.append(f"  active constraints: {', '.join(summary['constraints']['active']) or 'none'}; violated: "
                 f"{shown or 'none'}; {res['iterations']} iterates, {res['forward_solves']} wing solves")
    start_line = start_violation_line(summary)
    if start_line:
        lines.append(start_line)
    lines.append(f"  {summary['timings_s']['total']:.1f} s (report {summary['timings_s']['report']:.1f} s)")
    lines.append(f"wrote {summary['out']} ({', '.join(summary['files'])})")
    return lines
