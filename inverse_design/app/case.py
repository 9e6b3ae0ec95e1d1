"""The one case reader: options and TOML case files to what a run needs.

Precedence: the defaults of `options.OPTIONS`, then the case file
(``--config``), then the command line (`parse_arguments`). A case file's
keys are the long option names; ``[[rib]]`` tables describe a wing (`read_ribs`;
a single bay is the wing of its two ribs). Sections are NACA codes or
Selig/Lednicer ``.dat`` files, a relative path being relative to the case
file's folder (`case_path`). `design_inputs` turns the options into the
design's starting `forward_solver.Parameters`, variables, bounds, tension
constraints and rib limits, for one bay and a wing alike.

A wing case file::

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

An example: ``inverse_design/cases/wing_taper.toml`` (`EXAMPLE_CASE`).
"""

from __future__ import annotations

import argparse
import math
import re
import sys
import warnings
from pathlib import Path

from .options import OPTION_SPECS, PROG, InputError, build_parser

__all__ = ["EXAMPLE_CASE", "RIB_KEYS", "case_path", "check_equilibrium_method", "check_option_combinations",
           "design_inputs", "ignored_options", "load_section", "parse_arguments", "read_config", "read_ribs",
           "read_tolerances",
           "report_may_write", "variable_names"]

#: Keys of a ``[[rib]]`` table: required, then optional.
RIB_KEYS = (("section", "chord", "station"), ("target",))
#: The built-in example: a 3-bay tapered NACA 2412 wing.
EXAMPLE_CASE = Path(__file__).parents[1] / "cases" / "wing_taper.toml"


def _toml_value(path: str, key: str, value):
    """A case-file value converted and validated as the command line would."""
    dest = key.replace("-", "_")
    spec = OPTION_SPECS.get(dest)
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

            values["wing"] = read_ribs(str(path), value)
            continue
        if key == "tolerances" and isinstance(value, dict):
            values["tolerances"] = read_tolerances(str(path), value)
            continue
        if dest in values:
            raise InputError(f"{path}: {key!r} is given twice (with - and _)")
        values[dest] = _toml_value(str(path), key, value)
        if dest == "tolerance" and isinstance(values[dest], str):
            raise InputError(f"{path}: tolerance is the optimiser's convergence tolerance, a number; give "
                             "manufacturing tolerances in a [tolerances] table (pressure = \"2%\", ...)")
        if dest in ("target", "rib"):
            values[dest] = case_path(path, values[dest])
    return values


def read_tolerances(path: str, table: dict) -> list[str]:
    """A case file's ``[tolerances]`` table as ``NAME=VALUE`` items (``defaults = true``: every source at
    its default first); the names and values are checked with the command line's before any solve
    (`inverse_design.tolerance.parse_tolerances`).

    Raises:
        InputError: for a value that is neither a number nor a string.
    """
    items = []
    for name, value in table.items():
        if name == "defaults":
            if value is not True:
                raise InputError(f"{path}: [tolerances] defaults must be true (every source at its default), "
                                 f"got {value!r}")
            items.insert(0, "defaults")
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float, str)):
            raise InputError(f"{path}: [tolerances] {name} must be a number (the standard deviation) or a string "
                             f"such as \"2%\" or \"uniform:0.5\", got {value!r}")
        items.append(f"{name}={value}")
    return items


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
    # tolerances: the case file's table, then the command line's (a name given on both: the command line's)
    merged["tolerances"] = [*(config.get("tolerances") or []), *(given.get("tolerances") or [])] or None
    if merged.get("objective") == "robust" and not merged["tolerances"]:  # (designed for the defaults)
        merged["tolerances"] = ["defaults"]
    sources = {**{k: "config" for k in config}, **{k: "command line" for k in given}}
    args = argparse.Namespace(**merged)
    check_option_combinations(args, sources)
    return args, sources


#: The fields a design can take that ``--evaluate`` (one equilibrium at the given values) has no values for.
_DESIGNED_FIELDS = ("rib_shape", "cut_pattern")


def _given(name: str, sources: dict) -> str:
    """How an option was given, for a message: ``--min-tension`` or ``min-tension (case file)``."""
    flag = name.replace("_", "-")
    return f"--{flag}" if sources.get(name) != "config" else f"{flag} (case file)"


def check_option_combinations(args: argparse.Namespace, sources: dict) -> None:
    """Refuse options that contradict each other (exit 2, one line each; docs/errors.md).

    * ``--no-tension-constraints`` with ``--min-tension`` or ``--max-tension``
      given: the limit would be dropped.
    * ``--evaluate`` with ``--refine``: one equilibrium has no design to refine.
    * ``--evaluate`` with ``rib_shape`` or ``cut_pattern`` among ``--variables``:
      it solves at the given values, and those fields have none to give (it
      would solve the unshaped rib and the uniform cut).
    * ``--method root`` on a single bay with variables other than the
      pressure alone: root finding (brentq) solves for the pressure alone.
    * ``--objective robust`` with ``--evaluate`` (nothing is designed) or
      with a ``--method`` other than auto or gauss_newton.

    Raises:
        InputError: naming both options and what to change.
    """
    if args.no_tension_constraints:
        for name in ("min_tension", "max_tension"):
            if name in sources:
                raise InputError(f"{_given(name, sources)} {getattr(args, name):g} N/m contradicts "
                                 f"{_given('no_tension_constraints', sources)}, which drops both tension limits: "
                                 "give one or the other")
    if args.objective == "robust" and args.evaluate:
        raise InputError(f"{_given('objective', sources)} robust designs for the tolerances, and "
                         f"{_given('evaluate', sources)} solves one equilibrium and designs nothing: drop --evaluate, "
                         "or give --objective average with --tolerance for the analysis of that equilibrium")
    if args.objective == "robust" and args.method not in ("auto", "gauss_newton"):
        raise InputError(f"{_given('objective', sources)} robust is minimised by gauss_newton (a sum of squares "
                         f"with the tolerance Jacobian's derivatives), got {_given('method', sources)} "
                         f"{args.method}: give --method auto or gauss_newton")
    if args.evaluate and args.refine:
        raise InputError(f"{_given('refine', sources)} polishes a design on a finer grid, and "
                         f"{_given('evaluate', sources)} solves one equilibrium and designs nothing: give one or "
                         "the other")
    names = variable_names(args.variables)
    if args.evaluate and "variables" in sources:
        fields = [n for n in names if n in _DESIGNED_FIELDS]
        if fields:
            raise InputError(f"{_given('evaluate', sources)} solves at the given values, and {', '.join(fields)} "
                             f"of {_given('variables', sources)} has no value to give (it would solve the unshaped "
                             "rib and the uniform cut): drop --evaluate to design it, or drop it from --variables")
    if args.method == "root" and getattr(args, "wing", None) is None and names != ("pressure",):
        raise InputError(f"{_given('method', sources)} root solves for the pressure alone (brentq on one scalar "
                         f"condition at mid-bay, --root-condition), got --variables {','.join(names)}: give "
                         "--variables pressure, or another --method")


def ignored_options(args: argparse.Namespace, sources: dict) -> list[str]:
    """Options given that the run does not use: one warning line each (docs/errors.md).

    ``--variables`` with ``--evaluate`` (the equilibrium is solved at the
    given values; its fields are refused, `check_option_combinations`);
    ``--shape-spec``, ``--samples``, ``--seed`` or ``--scheduler`` without tolerances.
    """
    lines = []
    if not getattr(args, "tolerances", None):
        for name in ("shape_spec", "samples", "seed", "scheduler"):
            if name in sources:
                lines.append(f"{_given(name, sources)} is ignored without tolerances (--tolerance NAME=VALUE or a "
                             "[tolerances] table), which turn on the tolerance analysis")
    elif "scheduler" in sources and not args.samples:
        lines.append(f"{_given('scheduler', sources)} is ignored without --samples: the first-order analysis runs "
                     "here; the cluster solves Monte Carlo wings")
    if args.evaluate and "variables" in sources:
        lines.append(f"{_given('variables', sources)} {args.variables} is ignored with "
                     f"{_given('evaluate', sources)}, which solves the equilibrium at the given values "
                     "(--pressure, --prestrain-span, ...) and optimises nothing")
    return lines


def check_equilibrium_method(args: argparse.Namespace, strategy: str) -> None:
    """Refuse an ``--equilibrium-method`` the design's forward solves cannot honour.

    On the CPU every method is honoured, for one bay and a wing alike (each
    bay solved in turn, `forward_solver.solve_bays`'s "loop"). On an
    accelerator (``strategy`` "batch") the design relaxes every bay together
    in one batch: relax alone (auto becomes relax). ``--evaluate`` solves one
    equilibrium with the method asked for, anywhere.

    Raises:
        InputError: for newton or relax+newton in a design on the batch.
    """
    if strategy == "batch" and not args.evaluate and args.equilibrium_method not in ("auto", "relax"):
        raise InputError(f"--equilibrium-method {args.equilibrium_method}: on this machine's accelerator the "
                         "design relaxes its bays together in one batch, which runs relax alone: give "
                         "--equilibrium-method relax or auto, or run on the CPU (JAX_PLATFORMS=cpu)")


#: Names of `export.REPORT_FILES` that a kind of run never writes (`report_may_write`).
_NEVER = {
    "any": r"cut_pattern\.csv|mid_bay_section\.png|aero\.png",  # (an earlier layout's names)
    "several_bays": r"equilibrium\.npz|deviation\.png|tensions\.png|rib\.dat|rib_design\.png",
    "evaluate": r"history\.png|rib(_[0-9]+)?\.dat|rib_design\.png",
    "unshaped": r"rib(_[0-9]+)?\.dat|rib_design\.png",
    "no_aero": r"(bay_[0-9]+_)?aero\.png",
    "no_patterns": r"pattern_.*|rib_[0-9]+\.dxf",
    "no_tolerances": r"tolerance\.png|tolerance_samples\.csv",
    "no_samples": r"tolerance_samples\.csv",
}


def report_may_write(args: argparse.Namespace):
    """A predicate on a file name: whether the report of this run may write a file of that name.

    Every report file name (`export.REPORT_FILES`) but those this kind of run
    never writes (a single bay's extras in a run of several bays, ``history.png`` with
    ``--evaluate``, ``rib.dat`` without a rib shape, the patterns with
    ``--no-patterns``, ...). Used to refuse, before the long work, a file an
    earlier report wrote and someone edited since, which this run would
    replace (`export.check_output_folder`); the run keeps such a file that it
    does not write, and says so.
    """
    never = [_NEVER["any"]]
    if len(getattr(args, "wing", None) or ()) > 2:
        never.append(_NEVER["several_bays"])
    if args.evaluate:
        never.append(_NEVER["evaluate"])
    if "rib_shape" not in variable_names(args.variables):
        never.append(_NEVER["unshaped"])
    if not args.aero:
        never.append(_NEVER["no_aero"])
    if args.no_patterns:
        never.append(_NEVER["no_patterns"])
    if not getattr(args, "tolerances", None):
        never.append(_NEVER["no_tolerances"])
    elif not args.samples:
        never.append(_NEVER["no_samples"])
    excluded = re.compile("|".join(f"(?:{n})" for n in never))
    return lambda name: excluded.fullmatch(name) is None


def load_section(spec: str, option: str):
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


def variable_names(text: str) -> tuple[str, ...]:
    return tuple(v.strip() for v in text.split(",") if v.strip())


def read_ribs(path: str, tables) -> list[dict]:
    """Check the ``[[rib]]`` tables of a case file; return them as ``[{section, chord, station, target}]``.

    Each section (and target) is loaded once here, so that an unknown one is
    refused before any work.

    Raises:
        cli.InputError: one line naming the file, the rib (0 is the root) and what to change.
    """

    required, optional = RIB_KEYS
    if not isinstance(tables, list) or len(tables) < 2:
        n = len(tables) if isinstance(tables, list) else 0
        raise InputError(f"{path}: a wing needs at least two [[rib]] tables (root and tip), got {n}; add ribs")
    ribs = []
    for k, table in enumerate(tables):
        where = f"{path}: rib {k}"
        unknown = sorted(set(table) - set(required) - set(optional))
        if unknown:
            raise InputError(f"{where}: unknown key(s) {unknown}; a [[rib]] table has {', '.join(required)} "
                         f"and optionally {', '.join(optional)}")
        missing = [key for key in required if key not in table]
        if missing:
            raise InputError(f"{where}: missing {', '.join(missing)}; every [[rib]] needs section (a NACA code "
                         "or a .dat file), chord (m) and station (m, span position)")
        rib = {}
        for key in ("chord", "station"):
            value = table[key]
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise InputError(f"{where}: {key} must be a finite number in m, got {value!r}")
            rib[key] = float(value)
        if not rib["chord"] > 0:
            raise InputError(f"{where}: chord must be a positive length in m, got {rib['chord']!r}")
        if k and not rib["station"] > ribs[-1]["station"]:
            raise InputError(f"{where}: station {rib['station']:g} m does not lie beyond rib {k - 1}'s "
                         f"({ribs[-1]['station']:g} m); list the ribs root to tip with increasing stations")
        for key in ("section", "target"):
            if key not in table:
                continue
            if not isinstance(table[key], str):
                raise InputError(f"{where}: {key} must be a NACA code such as \"naca2412\" or a .dat path, "
                             f"got {table[key]!r}")
            rib[key] = case_path(path, table[key])  # a relative .dat path: beside the case file
            load_section(rib[key], f"{where}: {key}")  # refuses an unknown section now
        ribs.append(rib)
    return ribs


def design_inputs(args: argparse.Namespace) -> tuple:
    """What the options say of the design, for one bay and for a wing alike.

    Returns:
        ``(initial, variables, rib_limits, bounds, constraints)``: the
        starting `forward_solver.Parameters` (a zero rib shape of 2
        ``--rib-shape-terms`` coefficients when ``rib_shape`` is optimised,
        a zero cut pattern of 2 ``--cut-pattern-terms`` when ``cut_pattern``
        is),
        the variable names, the `rib_design.RibLimits` (None without a rib
        shape or with ``--no-rib-limits``), ``{name: (low, high)}`` of the
        variables and the tension `constraints.Constraints` (None with
        ``--no-tension-constraints``).

    Raises:
        InputError: for rib-shape options that make no sense.
    """
    from forward_solver import Parameters

    from ..constraints import Constraints
    from ..rib_design import RibLimits

    initial = Parameters(pressure=args.pressure, prestrain_span=args.prestrain_span,
                         prestrain_chord=args.prestrain_chord, rib_thickness_scale=args.rib_thickness_scale,
                         rib_chord_scale=args.rib_chord_scale)
    variables = variable_names(args.variables)
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
    if "cut_pattern" in variables and not getattr(args, "evaluate", False):
        if args.cut_pattern_terms < 1:
            raise InputError(f"--cut-pattern-terms must be at least 1, got {args.cut_pattern_terms}")
        if args.cut_pattern_terms > args.n_contour:  # (as `inverse_design.problem.check_field_terms`)
            raise InputError(f"a cut pattern of {args.cut_pattern_terms} terms per fibre direction on {args.n_contour} "
                             f"contour nodes: at most one term per contour node moves the skin; give "
                             f"--cut-pattern-terms {args.n_contour} or fewer, or more --n-contour")
        initial = initial.replace(cut_pattern=[0.0] * (2 * args.cut_pattern_terms))
        if args.cut_pattern_layout == "per_bay" and getattr(args, "wing", None) is None:
            # (a case file's two ribs reach `variables.DesignVariables.build`, which says so itself)
            warnings.warn("--cut-pattern-layout per_bay on one bay is the shared field: the design optimises "
                          "one cut field", stacklevel=2)
    all_bounds = {"pressure": args.pressure_bounds, "prestrain_span": args.prestrain_bounds,
                  "prestrain_chord": args.prestrain_bounds, "rib_thickness_scale": args.rib_thickness_bounds,
                  "rib_chord_scale": args.rib_chord_bounds, "rib_shape": args.rib_shape_bounds,
                  "cut_pattern": args.cut_pattern_bounds}
    bounds = {n: tuple(all_bounds[n]) for n in variables if n in all_bounds}
    constraints = (None if args.no_tension_constraints else
                   Constraints(min_tension=args.min_tension, max_tension=args.max_tension))
    return initial, variables, rib_limits, bounds, constraints
