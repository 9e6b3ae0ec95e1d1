"""``optimise-pressure``: the command line, a thin layer over the public API.

It parses the options (and a TOML case file, ``--config``), builds the
`forward_solver.Scene`, calls `inverse_design.optimise_pressure` (or, with
``--evaluate``, `forward_solver.solve_equilibrium` once) and hands the result
to `inverse_design.summary.write_report`, which writes the output folder. No
physics lives here.

Exit codes: 0 success; 1 the run failed (a forward solve did not converge:
nothing written; or the optimiser stopped without converging: the folder is
written and says so); 2 bad input (one line on stderr), a grid too large
for the machine among it (`inverse_design.resources.check_grid`); 130
interrupted (Ctrl-C); 143 terminated (SIGTERM: `main` makes it unwind like
Ctrl-C, so the staging folder is removed). A stop that Python loses (raised
inside a garbage-collection callback) is recorded and raised again at the
next safe point (`inverse_design.interrupts`), at the latest before the
folder's files are put in place.

The solvers run in their own thread-local float64 scope. Unlike the
library, the command turns on JAX's persistent compilation cache for its own
process (`compilation_cache_dir`: ``$INFLATABLE_WING_CACHE``, else JAX's own
``$JAX_COMPILATION_CACHE_DIR``, else ``$XDG_CACHE_HOME/inflatable-wing/jax``,
else ``~/.cache/inflatable-wing/jax``;
``--no-compilation-cache`` turns it off; deleting the folder clears it), so a
second run of a grid compiles nothing.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import time
from pathlib import Path

from . import interrupts
from .interrupts import Terminated
from .resources import MAX_NODES, check_grid

__all__ = ["InputError", "Terminated", "build_parser", "main", "parse_arguments", "read_config", "run"]

PROG = "optimise-pressure"
#: ``--variables`` of the default case.
DEFAULT_VARIABLES = "pressure,rib_thickness_scale"
#: Exit codes of a run stopped by Ctrl-C (SIGINT) or SIGTERM: 128 + the signal number, as a shell reports it.
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143


class InputError(ValueError):
    """Bad command-line or case-file input (exit code 2)."""


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # Anything that reads as a negative number (-2e5, -.5, -inf, not only argparse's -4 and -0.5) is a
        # value, so that it reaches the option's own check ("must be a positive number") instead of
        # argparse's "expected one argument"; no option of ours looks like a number.
        self._negative_number_matcher = _NEGATIVE_NUMBER

    def error(self, message):  # one line, no usage block: the caller prints it and exits 2
        raise InputError(f"{message} (see {PROG} --help)")


_NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|infinity|nan)$", re.IGNORECASE)


# ------------------------------------------------------------------ option types
def _number(unit: str = "", positive: bool = False):
    """A type function for a finite (optionally positive) float; ``unit`` goes into the message."""
    where = f" ({unit})" if unit else ""

    def number(text):
        try:
            value = float(text)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(f"expected a number{where}, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"expected a finite number{where}, got {text!r}")
        if positive and not value > 0:
            raise argparse.ArgumentTypeError(f"must be a positive number{where}, got {text!r}")
        return value

    return number


def _whole(text):
    try:
        return int(text)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None


# One entry per option: (group, flag, argparse keyword arguments). The TOML
# reader converts a case file's values with the same types and choices.
_GROUPS = {
    "target": "target and ribs",
    "bay": "bay and grid",
    "fabric": "fabric",
    "design": "design variables and bounds",
    "constraints": "tension constraints",
    "rib": "rib shape (--variables ...,rib_shape)",
    "optimiser": "optimiser",
    "aero": "aerodynamics",
    "output": "input and output",
}
OPTIONS = (
    ("target", "--target", dict(default="naca2412", metavar="SPEC",
                                help="target profile: a NACA 4- or 5-digit code (naca2412, naca23012) or a "
                                "Selig/Lednicer .dat file (default naca2412)")),
    ("target", "--rib", dict(default=None, metavar="SPEC",
                             help="rib profile, same forms as --target (default: the target)")),
    ("target", "--rib-thickness-scale", dict(type=_number(positive=True), default=1.0, metavar="X",
                                             help="rib thickness over the rib profile's, about its camber "
                                             "line: the start if optimised, else fixed (default 1.0)")),
    ("target", "--rib-chord-scale", dict(type=_number(positive=True), default=1.0, metavar="X",
                                         help="rib chord over --chord: the start if optimised, else fixed "
                                         "(default 1.0)")),
    ("target", "--trailing-edge", dict(default="close", choices=("close", "open", "as-given"),
                                       help="a wing ([[rib]] tables) whose ribs mix closed and open trailing "
                                       "edges: close the open ones over the last 5%% of chord (a fabric "
                                       "seam), open the closed ones to the largest gap, or refuse the mix "
                                       "(default close; a single bay has one rib section)")),
    ("bay", "--chord", dict(type=_number("m", positive=True), default=1.0, metavar="M",
                            help="chord of the ribs, m (default 1.0)")),
    ("bay", "--rib-spacing", dict(type=_number("m", positive=True), default=0.25, metavar="M",
                                  help="distance between the two ribs, m (default 0.25)")),
    ("bay", "--n-span", dict(type=_whole, default=17, metavar="N",
                             help="grid nodes along the span, ribs included (default 17: with fewer, "
                             "the skin's contour strain next to the ribs is under-resolved and shows "
                             "spurious compression, which the wrinkle constraint then obeys)")),
    ("bay", "--n-contour", dict(type=_whole, default=64, metavar="N",
                                help="grid nodes around the contour (default 64)")),
    ("bay", "--allow-large-grid", dict(action="store_true",
                                       help="run a grid that is refused otherwise: one whose estimated peak "
                                       "memory exceeds half of the available memory, or with more than "
                                       f"{MAX_NODES:,} nodes (hours per design)")),
    ("fabric", "--stiffness-span", dict(type=_number("N/m", positive=True), default=2e5, metavar="N/M",
                                        help="tensile stiffness E11 of the span fibres per unit width, N/m "
                                        "(default 2e5)")),
    ("fabric", "--stiffness-chord", dict(type=_number("N/m", positive=True), default=2e5, metavar="N/M",
                                         help="tensile stiffness E22 of the contour fibres, N/m (default 2e5)")),
    ("fabric", "--poisson", dict(type=_number(), default=0.25, metavar="NU",
                                 help="Poisson coupling nu12 = nu21, in [0, 1) (default 0.25)")),
    ("fabric", "--prestrain-span", dict(type=_number("fraction"), default=0.02, metavar="E",
                                        help="span prestrain, fraction: the fabric is cut 1 + E times "
                                        "shorter (start if optimised, default 0.02)")),
    ("fabric", "--prestrain-chord", dict(type=_number("fraction"), default=0.02, metavar="E",
                                         help="contour prestrain, fraction (start if optimised, default 0.02)")),
    ("design", "--pressure", dict(type=_number("Pa", positive=True), default=1e4, metavar="PA",
                                  help="internal overpressure, Pa: the start of the optimisation, or the "
                                  "value evaluated with --evaluate (default 1e4)")),
    ("design", "--variables", dict(default=DEFAULT_VARIABLES, metavar="NAMES",
                                   help="comma-separated design variables among pressure, prestrain_span, "
                                   "prestrain_chord, rib_thickness_scale, rib_chord_scale, rib_shape "
                                   f"(default {DEFAULT_VARIABLES})")),
    ("design", "--pressure-bounds", dict(type=_number("Pa", positive=True), nargs=2, default=(1e3, 1e5),
                                         metavar=("LOW", "HIGH"), help="pressure bounds, Pa (default 1e3 1e5)")),
    ("design", "--prestrain-bounds", dict(type=_number("fraction"), nargs=2, default=(0.0, 0.05),
                                          metavar=("LOW", "HIGH"),
                                          help="bounds of both prestrains, fraction (default 0 0.05)")),
    ("design", "--rib-thickness-bounds", dict(type=_number(positive=True), nargs=2, default=(0.7, 1.0),
                                              metavar=("LOW", "HIGH"),
                                              help="bounds of the rib thickness scale (default 0.7 1.0)")),
    ("design", "--rib-chord-bounds", dict(type=_number(positive=True), nargs=2, default=(0.5, 1.5),
                                          metavar=("LOW", "HIGH"),
                                          help="bounds of the rib chord scale (default 0.5 1.5)")),
    ("constraints", "--min-tension", dict(type=_number("N/m"), default=0.0, metavar="N/M",
                                          help="floor of every fibre tension, N/m: 0 keeps the skin free "
                                          "of wrinkles (default 0)")),
    ("constraints", "--max-tension", dict(type=_number("N/m", positive=True), default=None, metavar="N/M",
                                          help="ceiling of every fibre tension (the fabric's allowable), "
                                          "N/m (default none)")),
    ("constraints", "--no-tension-constraints", dict(action="store_true",
                                                     help="drop both tension constraints (keep the bounds)")),
    ("rib", "--rib-shape-terms", dict(type=_whole, default=4, metavar="K",
                                      help="Bernstein terms per surface of the rib's outward offset (2 K "
                                      "coefficients, started at zero; default 4)")),
    ("rib", "--rib-shape-bounds", dict(type=_number("chord"), nargs=2, default=(-0.05, 0.05),
                                       metavar=("LOW", "HIGH"),
                                       help="bounds of every rib-shape coefficient, fraction of chord "
                                       "(default -0.05 0.05: offsets up to about 1%% of chord)")),
    ("rib", "--min-rib-thickness", dict(type=_number("fraction", positive=True), default=0.8, metavar="F",
                                        help="least local thickness of the shaped rib, as a fraction of the "
                                        "starting rib's at the same x (default 0.8)")),
    ("rib", "--min-rib-radius", dict(type=_number("chord", positive=True), default=None, metavar="R",
                                     help="least radius of curvature of the shaped rib, fraction of chord "
                                     "(default: half the starting rib's nose radius)")),
    ("rib", "--no-rib-limits", dict(action="store_true",
                                    help="drop both rib limits (keep the coefficient bounds)")),
    ("optimiser", "--objective", dict(default="average", choices=("mid_bay", "average", "worst"),
                                      help="sections that must match the target: the mid-bay one, every "
                                      "row from rib to rib, or the worst row (default average)")),
    ("optimiser", "--method", dict(default="slsqp", choices=("slsqp", "least_squares", "root", "optax"),
                                   help="optimiser: slsqp (the tension limits as constraints), "
                                   "least_squares or optax (as penalties), root (brentq; takes "
                                   "--variables pressure) (default slsqp)")),
    ("optimiser", "--root-condition", dict(default="thickness", choices=("thickness", "mean_offset"),
                                           help="scalar condition of --method root at mid-bay "
                                           "(default thickness)")),
    ("optimiser", "--max-iterations", dict(type=_whole, default=50, metavar="N",
                                           help="cap on the optimiser's iterations (default 50)")),
    ("optimiser", "--tolerance", dict(type=_number(positive=True), default=None, metavar="TOL",
                                      help="convergence tolerance of the optimiser (default: slsqp 1e-6 "
                                      "of the starting objective, the others 1e-8)")),
    ("optimiser", "--refine", dict(action="store_true",
                                   help="confirm and polish the design on a grid with twice the span "
                                   "resolution (2 n-span - 1 nodes) and report how far it moved")),
    ("optimiser", "--evaluate", dict(action="store_true",
                                     help="only solve the equilibrium at the given values and report it "
                                     "(no optimisation, no history plot)")),
    ("optimiser", "--max-steps", dict(type=_whole, default=200_000, metavar="N",
                                      help="step cap of each relaxation of every equilibrium solve, in every "
                                      "mode (default 200000)")),
    ("optimiser", "--equilibrium-method", dict(default="auto", choices=("auto", "relax", "newton", "relax+newton"),
                                               help="equilibrium solver: auto tries relax+newton, then Newton from "
                                               "where it stopped, then Newton with load continuation, before "
                                               "failing; or one method alone (default auto; a wing: auto or "
                                               "relax, its bays relaxed together)")),
    ("aero", "--aero", dict(action="store_true",
                            help="compare lift, drag and moment of the cured mid-bay and bay-average sections "
                            "with the target's (NeuralFoil: pip install \"inflatable-wing[aero]\"); "
                            "writes aero.png and summary.json's aero entry")),
    ("aero", "--reynolds", dict(type=_number(positive=True), default=1e6, metavar="RE",
                                help="chord Reynolds number of --aero (default 1e6)")),
    ("aero", "--alpha-range", dict(type=_number("deg"), nargs=3, default=(-4.0, 10.0, 1.0),
                                   metavar=("START", "STOP", "STEP"),
                                   help="angles of attack of --aero, deg, stop included, within +-20 "
                                   "(default -4 10 1)")),
    ("output", "--config", dict(default=None, metavar="CASE.TOML",
                                help="read options from a TOML file (keys: the long option names); "
                                "command-line options override it")),
    ("output", "--out", dict(default="optimise-pressure-out", metavar="DIR",
                             help="output folder (may be . or hold other files, which are never touched): "
                             "an earlier report's files in it are replaced (or removed) when the new "
                             "report is complete (default optimise-pressure-out)")),
    ("output", "--magnification", dict(type=_number(positive=True), default=None, metavar="X",
                                       help="deviation factor of the section plot (default: automatic, "
                                       "1, 2, 5, 10, ...)")),
    ("output", "--json", dict(action="store_true", help="print the summary as JSON on stdout, nothing else")),
    ("output", "--quiet", dict(action="store_true", help="print nothing but errors")),
    ("output", "--no-compilation-cache", dict(action="store_true",
                                              help="do not keep JAX's compiled functions between runs "
                                              "(default: kept in $INFLATABLE_WING_CACHE, else "
                                              "~/.cache/inflatable-wing/jax)")),
)
_SPECS = {flag[2:].replace("-", "_"): kwargs for _, flag, kwargs in OPTIONS}

_DESCRIPTION = """\
Inflatable wing bay: choose the internal pressure (and prestrain or rib geometry)
so that the pressurised skin matches a target profile, and write a report folder.

With no arguments it runs the built-in default case: NACA 2412 target and ribs,
chord 1 m, ribs 0.25 m apart, fabric 2e5 N/m both ways, 2% prestrain, 17x64 grid;
the pressure (1-100 kPa) and the rib thickness scale (0.7-1) are chosen so that
every section from rib to rib matches the target, with a wrinkle-free skin.
"""

_EPILOG = """\
output folder (--out DIR): the report is written to a temporary folder (beside a new
DIR, inside an existing one) and put in place when complete. DIR may be . or hold
other files: only the report's files are written, each replacing only a file of an
earlier report (one its summary.json lists); the earlier report's files this run
does not write (e.g. rib.dat) are removed; nothing else is touched. A DIR holding a
file of a report's name that no report wrote is refused (exit 2). Temporary folders
left by a killed run are removed by the next run to DIR:
  summary.json          inputs, results, errors before/after, active constraints,
                        timings, package version, the files written
  equilibrium.npz       nodes (n_span, n_contour, 3) m, tensions N/m, wrinkled
                        cells, deviation from the target, parameters
  skin.obj, skin.stl    the equilibrium skin as a mesh, metres
  mid_bay_section.png   mid-bay section against the rib and the target (magnified)
  deviation.png         deviation from the target over the whole bay
  tensions.png          fibre tensions with the wrinkled cells marked
  history.png           the optimiser's iterates (not with --evaluate)
  aero.png              lift, drag and moment against the target (with --aero)
  cut_pattern.csv       the fabric's cut lengths along the contour and the span
  rib.dat, rib_design.png   the designed rib (Selig) and its offset and thickness
                        (with --variables ...,rib_shape)

case file (--config case.toml; keys are the long option names, with - or _; .dat paths in
it are relative to the case file's folder; options on the command line override it):
  target = "naca4415"
  chord = 0.8                      # m
  variables = ["pressure", "prestrain_span", "prestrain_chord"]
  pressure-bounds = [2e3, 5e4]     # Pa
  n-span = 17
  n-contour = 128

grid size: a grid whose estimated peak memory exceeds half of the available memory,
or with more than {max_nodes:,} nodes, is refused before the run (exit 2, with the
estimate); --allow-large-grid runs it anyway.

exit codes: 0 done; 1 the run failed (the reason on stderr); 2 bad input; 130 interrupted
(Ctrl-C); 143 terminated (SIGTERM). Interrupted or terminated, nothing is written.
""".format(max_nodes=MAX_NODES)


def build_parser(suppress_defaults: bool = False) -> argparse.ArgumentParser:
    """The argument parser; with ``suppress_defaults`` only the options given appear in the namespace."""
    parser = _Parser(prog=PROG, description=_DESCRIPTION, epilog=_EPILOG,
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    groups = {key: parser.add_argument_group(title) for key, title in _GROUPS.items()}
    for group, flag, kwargs in OPTIONS:
        kwargs = dict(kwargs)
        if suppress_defaults:
            kwargs["default"] = argparse.SUPPRESS
        groups[group].add_argument(flag, **kwargs)
    return parser


# ------------------------------------------------------------------ case files
def _toml_value(path: str, key: str, value):
    """A case-file value converted and validated as the command line would."""
    dest = key.replace("-", "_")
    spec = _SPECS.get(dest)
    if spec is None or dest == "config":
        raise InputError(f"{path}: unknown key {key!r}; keys are the long option names of "
                         f"{PROG} --help (e.g. n-span, pressure-bounds)")
    if spec.get("action") == "store_true":
        if not isinstance(value, bool):
            raise InputError(f"{path}: {key} must be true or false, got {value!r}")
        return value
    convert = spec.get("type", str)

    def one(item):
        if isinstance(item, (bool, dict, list)) or not isinstance(item, (int, float, str)):
            raise InputError(f"{path}: {key} must be a single value, got {item!r}")
        try:
            converted = convert(str(item))
        except argparse.ArgumentTypeError as exc:
            raise InputError(f"{path}: {key}: {exc}") from None
        if spec.get("choices") and converted not in spec["choices"]:
            raise InputError(f"{path}: {key} must be one of {', '.join(spec['choices'])}, got {item!r}")
        return converted

    if spec.get("nargs") == 2:
        if not (isinstance(value, list) and len(value) == 2):
            raise InputError(f"{path}: {key} must be a pair [low, high], got {value!r}")
        return tuple(one(v) for v in value)
    if spec.get("nargs") == 3:
        if not (isinstance(value, list) and len(value) == 3):
            raise InputError(f"{path}: {key} must be a list [start, stop, step], got {value!r}")
        return tuple(one(v) for v in value)
    if dest == "variables" and isinstance(value, list):
        if not all(isinstance(v, str) for v in value):
            raise InputError(f"{path}: variables must be a list of names, got {value!r}")
        value = ",".join(value)
    return one(value)


def read_config(path) -> dict:
    """Options of a TOML case file, converted and checked like the command line.

    Raises:
        InputError: for an unreadable file, invalid TOML, an unknown key or a
            bad value (the message names the file and the key).
    """
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover - exercised on Python 3.10 only
        import tomli as tomllib
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise InputError(f"cannot read the case file {path}: {reason}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path} is not valid TOML: {exc}") from None
    values = {}
    for key, value in data.items():
        dest = key.replace("-", "_")
        if key == "rib" and isinstance(value, list) and all(isinstance(v, dict) for v in value):
            from .wing_cli import read_ribs  # [[rib]] tables: a whole wing

            values["wing"] = read_ribs(str(path), value)
            continue
        if dest in values:
            raise InputError(f"{path}: {key!r} is given twice (with - and _)")
        values[dest] = _toml_value(str(path), key, value)
        if dest in ("target", "rib"):
            values[dest] = case_path(path, values[dest])
    return values


def case_path(case_file, spec: str) -> str:
    """A section of a case file (a NACA code or a .dat path) with a relative path made relative to the
    case file's folder (not the current one); NACA codes and absolute paths are returned as they are.

    A spec is a path when it ends in ``.dat`` or names a file in the case file's folder.
    """
    path = Path(spec)
    if path.is_absolute():
        return spec
    beside = Path(case_file).parent / path
    if path.suffix.lower() == ".dat" or beside.exists():
        return str(beside)
    return spec


def parse_arguments(argv: list[str] | None = None) -> tuple[argparse.Namespace, dict]:
    """Resolve the options: defaults, then the case file, then the command line.

    Returns:
        ``(args, sources)``: the namespace and, for every option not at its
        default, where it came from ("config" or "command line").

    Raises:
        InputError: for a bad option or case file.
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    build_parser().parse_args(argv)  # --help, and every check with the full messages
    given = vars(build_parser(suppress_defaults=True).parse_args(argv))
    defaults = vars(build_parser().parse_args([]))
    config = read_config(given["config"]) if given.get("config") else {}
    merged = {**defaults, **config, **given}
    sources = {**{k: "config" for k in config}, **{k: "command line" for k in given}}
    return argparse.Namespace(**merged), sources


# ------------------------------------------------------------------ the run
def _airfoil(spec: str, option: str):
    from targets import load_airfoil, naca

    path = Path(spec)
    if path.is_dir():
        raise InputError(f"{option}: {spec} is a directory; give a NACA code such as naca2412 or a .dat file")
    if path.suffix.lower() == ".dat" or path.exists():
        if not path.is_file():
            raise InputError(f"{option}: no such file {spec!r}; give a NACA code such as naca2412 or the "
                             "path of a Selig/Lednicer .dat file")
        try:
            return load_airfoil(path)
        except OSError as exc:
            raise InputError(f"{option}: cannot read {spec}: {exc.strerror or exc}") from None
    try:
        return naca(spec)
    except ValueError as exc:
        raise InputError(f"{option} {spec!r} is neither a NACA code nor a .dat file: {exc}") from None


def _variables(text: str) -> tuple[str, ...]:
    return tuple(v.strip() for v in text.split(",") if v.strip())


def run(args: argparse.Namespace, sources: dict | None = None, progress: bool = False,
        started: float | None = None) -> dict:
    """Run the case described by ``args``, write the output folder and return its summary.

    ``started`` (a `time.perf_counter` value) dates the ``setup`` timing back, e.g. to the
    start of `main`, so that it includes importing JAX.

    Raises:
        ValueError: bad input (`InputError` among them).
        forward_solver.ConvergenceError: a forward solve failed (nothing written).
    """
    start = time.perf_counter() if started is None else started
    if getattr(args, "wing", None) is not None:  # a case file with [[rib]] tables
        from .wing_cli import run_wing

        return run_wing(args, sources, progress=progress, started=start)
    check_grid(args.n_span, args.n_contour, evaluate=args.evaluate, allow_large=args.allow_large_grid)
    if args.max_steps < 1:
        raise InputError(f"--max-steps must be a positive integer, got {args.max_steps}")
    alphas = _aero_angles(args) if args.aero else None  # (before any solve: a missing package fails fast)
    target = _airfoil(args.target, "--target")  # (before importing JAX: bad input fails fast)
    rib = target if args.rib is None else _airfoil(args.rib, "--rib")
    from forward_solver import Bay, ConvergenceError, Fabric, Scene, solve_equilibrium

    from .optimise import optimise_pressure, refine_design
    from .export import check_output_folder
    from .summary import write_report

    out = check_output_folder(args.out)  # before the long work, not after it
    def scene_on(n_span: int) -> Scene:
        bay = Bay.from_airfoil(rib, chord=args.chord, rib_spacing=args.rib_spacing, n_span=n_span,
                               n_contour=args.n_contour)
        return Scene(bay, Fabric(stiffness_span=args.stiffness_span, stiffness_chord=args.stiffness_chord,
                                 poisson=args.poisson))

    scene = scene_on(args.n_span)
    parameters, variables, rib_limits, bounds, constraints = design_inputs(args)
    notes = plausibility(args, scene.fabric, parameters, [(args.rib_spacing, args.chord)],
                         None if args.evaluate else bounds)
    inputs = {**vars(args), "target_name": target.name, "rib_name": rib.name, "sources": dict(sources or {})}
    report = dict(target=target, objective=args.objective, inputs=inputs, magnification=args.magnification,
                  rib=rib, rib_limits=rib_limits, warnings=notes)
    timings = {"setup": time.perf_counter() - start}
    if args.evaluate:
        t = time.perf_counter()
        result = solve_equilibrium(scene, parameters, max_steps=args.max_steps, method=args.equilibrium_method,
                                   throw=False)
        timings["equilibrium"] = time.perf_counter() - t
        if not result.converged:
            raise ConvergenceError(result)
        aero = _aero(args, result, target, alphas, timings)
        interrupts.check()
        return write_report(out, result, scene=scene, timings=timings, aero=aero, **report)
    options = dict(bounds=bounds, constraints=constraints, root_condition=args.root_condition,
                   max_iterations=args.max_iterations, tolerance=args.tolerance, progress=progress,
                   rib=rib, rib_limits=rib_limits, callback=_safe_point,
                   solver_options={"method": args.equilibrium_method, "max_steps": args.max_steps})
    t = time.perf_counter()
    result = optimise_pressure(scene, target, variables=variables, initial=parameters,
                               objective=args.objective, method=args.method, **options)
    if args.refine:
        scene = scene_on(2 * args.n_span - 1)
        result = refine_design(result, scene, target, **options)
    timings["optimisation"] = time.perf_counter() - t
    aero = _aero(args, result.solution, target, alphas, timings)
    interrupts.check()
    return write_report(out, result, scene=scene, bounds=bounds, timings=timings, aero=aero, **report)


def design_inputs(args: argparse.Namespace) -> tuple:
    """What the options say of the design, for one bay and for a wing alike.

    Returns:
        ``(initial, variables, rib_limits, bounds, constraints)``: the
        starting `forward_solver.Parameters` (a zero rib shape of 2
        ``--rib-shape-terms`` coefficients when ``rib_shape`` is optimised),
        the variable names, the `rib_design.RibLimits` (None without a rib
        shape or with ``--no-rib-limits``), ``{name: (low, high)}`` of the
        variables and the tension `constraints.Constraints` (None with
        ``--no-tension-constraints``).

    Raises:
        InputError: for rib-shape options that make no sense.
    """
    from forward_solver import Parameters

    from .constraints import Constraints
    from .rib_design import RibLimits

    initial = Parameters(pressure=args.pressure, prestrain_span=args.prestrain_span,
                         prestrain_chord=args.prestrain_chord, rib_thickness_scale=args.rib_thickness_scale,
                         rib_chord_scale=args.rib_chord_scale)
    variables = _variables(args.variables)
    rib_limits = None
    if "rib_shape" in variables and not getattr(args, "evaluate", False):
        if args.rib_shape_terms < 1:
            raise InputError(f"--rib-shape-terms must be at least 1, got {args.rib_shape_terms}")
        initial = initial.replace(rib_shape=[0.0] * (2 * args.rib_shape_terms))
        if not args.no_rib_limits:
            if args.min_rib_thickness > 1:
                raise InputError(f"--min-rib-thickness is a fraction of the starting rib's thickness in "
                                 f"(0, 1], got {args.min_rib_thickness}")
            rib_limits = RibLimits(min_thickness=args.min_rib_thickness, min_radius=args.min_rib_radius)
    all_bounds = {"pressure": args.pressure_bounds, "prestrain_span": args.prestrain_bounds,
                  "prestrain_chord": args.prestrain_bounds, "rib_thickness_scale": args.rib_thickness_bounds,
                  "rib_chord_scale": args.rib_chord_bounds, "rib_shape": args.rib_shape_bounds}
    bounds = {n: tuple(all_bounds[n]) for n in variables if n in all_bounds}
    constraints = (None if args.no_tension_constraints else
                   Constraints(min_tension=args.min_tension, max_tension=args.max_tension))
    return initial, variables, rib_limits, bounds, constraints


def plausibility(args: argparse.Namespace, fabric, parameters, bays, bounds) -> list[str]:
    """`plausibility.check_plausibility`'s lines for the inputs, each shown on stderr as one
    ``warning:`` line (unless ``--quiet``); the caller records them in the summary."""
    from .plausibility import check_plausibility

    lines = check_plausibility(fabric, parameters, bays, bounds, warn=False)
    if not args.quiet:
        for line in lines:
            print(f"{PROG}: warning: {line}", file=sys.stderr)
    return lines


def _aero_angles(args: argparse.Namespace):
    """The angles of ``--aero``, after checking that NeuralFoil is installed (`InputError` if not)."""
    from .aero import AeroUnavailable, alpha_range, require_neuralfoil

    try:
        require_neuralfoil()
    except AeroUnavailable as exc:
        raise InputError(f"--aero: {exc}") from None
    try:
        return alpha_range(*args.alpha_range)
    except ValueError as exc:
        raise InputError(f"--alpha-range: {exc}") from None


def _aero(args: argparse.Namespace, solution, target, alphas, timings: dict):
    """The `inverse_design.aero.AeroComparison` of ``--aero`` (None without it); times it."""
    if not args.aero:
        return None
    from .aero import aerodynamic_cost

    t = time.perf_counter()
    comparison = aerodynamic_cost(solution, target, args.chord, reynolds=args.reynolds, alphas=alphas)
    timings["aero"] = time.perf_counter() - t
    return comparison


def _value_text(name: str, value) -> str:
    """``name value`` for the console (a vector variable as its rounded components)."""
    if isinstance(value, list):
        return f"{name} [{', '.join(f'{v:.4f}' for v in value)}]"
    return f"{name} {value:.6g}" + (" Pa" if name == "pressure" else "")


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
    says so rather than leave a worse error unexplained.
    """
    at_start = summary["constraints"].get("violated_at_start") or {}
    if not at_start:
        return None
    broke = "; ".join(f"{name} {_amount_text(name, amount)}" for name, amount in at_start.items())
    err = summary["errors"]
    if summary["constraints"]["violated"]:
        verdict = "the design still breaks a limit (above)"
    elif err["after"]["rms"] > err["before"]["rms"]:
        verdict = ("the design is feasible but its error is larger than the infeasible start's "
                   f"({err['after']['rms']:.3e} against {err['before']['rms']:.3e} chord)")
    else:
        verdict = "the design is feasible"
    return f"  note: the start broke {broke}; {verdict}"


def _describe(summary: dict) -> list[str]:
    """The console lines of a finished run."""
    if summary["mode"] == "wing":
        from .wing_cli import describe_wing

        return describe_wing(summary)
    case, res, err = summary["case"], summary["results"], summary["errors"]
    v = res["values"]
    lines = [f"{case['target']}, {case['grid'][0]}x{case['grid'][1]} grid, {err['objective']} objective"]
    if summary["mode"] == "evaluate":
        eq = res["equilibrium"]
        lines.append(f"  equilibrium at {v['pressure_pa']:.6g} Pa: {eq['result']} in {eq['steps']} steps")
        lines.append(f"  error rms {err['after']['rms']:.3e}, max {err['after']['max']:.3e} chord "
                     f"(mid-bay rms {err['mid_bay_after']['rms']:.3e}, max {err['mid_bay_after']['max']:.3e})")
    else:
        chosen = ", ".join(_value_text(n, v['pressure_pa' if n == 'pressure' else n]) for n in res["variables"])
        lines.append(f"  {res['method']}: {chosen}")
        lines.append(f"  error rms {err['before']['rms']:.3e} -> {err['after']['rms']:.3e} chord, "
                     f"max {err['before']['max']:.3e} -> {err['after']['max']:.3e} chord")
        violated = summary["constraints"]["violated"] or {}
        lines.append(f"  active constraints: {', '.join(summary['constraints']['active']) or 'none'}; "
                     f"violated: {', '.join(f'{k} by {v:.4g} N/m' for k, v in violated.items()) or 'none'}; "
                     f"{res['iterations']} iterates, {res['forward_solves']} forward solves")
        start_line = start_violation_line(summary)
        if start_line:
            lines.append(start_line)
        grid = res.get("grid_change")
        if grid:
            moves = ", ".join(f"{n} {c:+.2%}" if n == "pressure" else f"{n} {c:+.4f}"
                              for n, c in grid["change"].items())  # a vector: its largest move
            lines.append(f"  refined {grid['grids'][0][0]}x{grid['grids'][0][1]} -> "
                         f"{grid['grids'][1][0]}x{grid['grids'][1][1]}: {moves}")
    aero = summary.get("aero")
    if aero:
        worst, alphas = aero["max_abs_difference"]["mid_bay"], aero["alphas_deg"]
        lines.append(f"  aerodynamics at Re {aero['reynolds']:.3g}, {alphas[0]:g} to {alphas[-1]:g} deg: mid-bay "
                     f"max |dCL| {worst['cl']:.3g}, |dCD| {worst['cd']:.3g}, |dCM| {worst['cm']:.3g} "
                     f"(confidence >= {aero['min_confidence']['mid_bay']:.2f})")
    wrinkled = res["equilibrium"]["wrinkled_fraction"]
    if wrinkled:
        lines.append(f"  wrinkled cells: {100 * wrinkled:.1f}% of the skin")
    lines.append(f"  {summary['timings_s']['total']:.1f} s (report {summary['timings_s']['report']:.1f} s)")
    lines.append(f"wrote {summary['out']} ({', '.join(summary['files'])})")
    return lines


def _safe_point(entry=None) -> None:
    """The optimiser's per-iterate callback: raise a stop that was recorded but lost (`interrupts.check`)."""
    interrupts.check()


def _exit_now(code: int) -> None:
    """End the process at once (``os._exit``) after flushing the output.

    An interruption can abandon an XLA compilation that goes on in a thread
    of JAX's own; the interpreter's normal shutdown then destroys the CPU
    client under it and the process dies of SIGSEGV instead of exiting with
    ``code`` (seen with JAX 0.10.2, Ctrl-C and SIGTERM alike). The output
    folder's staging has been cleaned up by then (the exception unwound it).
    """
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``optimise-pressure`` console script; returns the exit code.

    While it runs, SIGTERM raises `Terminated`, which unwinds like Ctrl-C
    (the staging folder is removed): exit code 143, or 130 for Ctrl-C. Both
    are recorded too (`interrupts.install`), so that one lost inside a
    callback is raised again at the next safe point. The previous handlers
    are restored on return. Run as the command
    (``argv`` None), an interrupted or terminated run ends the process
    itself with that code (see `_exit_now`); called with ``argv`` it returns.
    """
    started = time.perf_counter()
    previous = interrupts.install()
    try:
        code = _main(argv, started)
    except Terminated:  # before the run (importing JAX) or after its folder was written
        print(f"{PROG}: terminated", file=sys.stderr)
        code = EXIT_TERMINATED
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        code = EXIT_INTERRUPTED
    finally:
        interrupts.restore(previous)
    if argv is None and code in (EXIT_INTERRUPTED, EXIT_TERMINATED):
        _exit_now(code)
    return code


def compilation_cache_dir() -> Path:
    """Where the command keeps JAX's compiled functions between runs (module docstring)."""
    for variable in ("INFLATABLE_WING_CACHE", "JAX_COMPILATION_CACHE_DIR"):
        if os.environ.get(variable):
            return Path(os.environ[variable])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "inflatable-wing" / "jax"


def use_compilation_cache(path: Path) -> None:
    """Turn on JAX's persistent compilation cache in ``path`` for this process (every entry kept:
    the solver's functions compile in 0.3-6 s each and load in milliseconds)."""
    import jax

    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)


def _interrupted(exc: KeyboardInterrupt, out: str) -> int:
    """The one-line message and exit code of a run stopped by Ctrl-C or SIGTERM."""
    terminated = isinstance(exc, Terminated)
    print(f"{PROG}: {'terminated' if terminated else 'interrupted'}; nothing was written to {out}",
          file=sys.stderr)
    return EXIT_TERMINATED if terminated else EXIT_INTERRUPTED


def _main(argv: list[str] | None, started: float) -> int:
    try:
        args, sources = parse_arguments(argv)
    except InputError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    progress = sys.stderr.isatty() and not (args.quiet or args.json)
    try:
        from forward_solver import ConvergenceError  # (JAX, unless the package imported it already)

        if not args.no_compilation_cache:
            use_compilation_cache(compilation_cache_dir())
    except KeyboardInterrupt as exc:
        return _interrupted(exc, args.out)
    try:
        summary = run(args, sources, progress=progress, started=started)
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM (`Terminated`)
        return _interrupted(exc, args.out)
    except ConvergenceError as exc:  # a forward solve failed: the reason, exit 1
        print(f"{PROG}: failed: {exc}; nothing was written to {args.out}", file=sys.stderr)
        return 1
    except ValueError as exc:  # bad input: one line, no traceback
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # input files are read (and checked) before: this is the output
        print(f"{PROG}: failed: could not write {args.out}: {exc}", file=sys.stderr)
        return 1
    try:
        interrupts.check()  # a stop that arrived while the files were put in place
    except KeyboardInterrupt as exc:
        terminated = isinstance(exc, Terminated)
        print(f"{PROG}: {'terminated' if terminated else 'interrupted'} after the report was complete "
              f"in {summary['out']}", file=sys.stderr)
        return EXIT_TERMINATED if terminated else EXIT_INTERRUPTED
    if args.json:
        print(json.dumps(summary, indent=2))
    elif not args.quiet:
        print("\n".join(_describe(summary)))
    if not summary["results"]["success"]:
        why = ("the design breaks its tension limits" if summary["constraints"]["violated"]
               else "the optimiser did not converge")
        print(f"{PROG}: failed: {why}: {summary['results']['message']} "
              f"(the results are in {summary['out']})", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    # `python -m inverse_design.cli` runs this file as __main__, a second copy of the module beside
    # the inverse_design.cli that wing_cli imports: its InputError would not be this copy's, and bad
    # wing input would end in a traceback. Run the package's own module instead.
    from inverse_design.cli import main as package_main

    sys.exit(package_main())
