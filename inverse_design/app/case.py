"""`Case`: what a run of ``optimise-pressure`` is asked, from options and a case file, checked once.

Precedence: the defaults of `options.OPTIONS`, then the case file
(``--config``, `case_file.read_config`), then the command line. Whatever
the source, a case is a wing of ribs (`Rib`): the ``[[rib]]`` tables of a
case file, or, for a bay given by options (``--target``, ``--rib``,
``--chord``, ``--rib-spacing``), the two ribs of that bay. Every section is
loaded once, here, so that a bad one is refused with one line before any
work, and every check that needs no solver runs here too (`Case.from_arguments`).
The library inputs the case implies (`Case.fabric`, `Case.wing`,
`Case.targets`, `Case.start`, `Case.bounds`, `Case.limits`, `Case.layout`)
are made by `inverse_design.app.design`, the app's one module of library calls.

Nothing here imports JAX or `targets` at import: a report worker imports
this module (through `cli`) and must not.
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import sys
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

from ..defaults import VARIABLES
from .case_file import read_config
from .option_checks import (check_combinations, check_rib_spacings, check_values, fabric_law, given,
                            marker_request)
from .options import InputError, build_parser

__all__ = ["Case", "Options", "Rib", "load_section"]

#: Names of `output_folder.REPORT_FILES` that a kind of run never writes (`Case.may_write`).
_NEVER = {
    "any": r"cut_pattern\.csv|mid_bay_section\.png|aero\.png",  # (an earlier layout's names)
    "several_bays": r"equilibrium\.npz|deviation\.png|tensions\.png|rib\.dat|rib_design\.png",
    "evaluate": r"history\.png|rib(_[0-9]+)?\.dat|rib_design\.png",
    "unshaped": r"rib(_[0-9]+)?\.dat|rib_design\.png",
    "no_aero": r"(bay_[0-9]+_)?aero\.png",
    "no_patterns": r"pattern_.*|rib_[0-9]+\.dxf",
    "no_figures": r".*\.png",
    "no_tolerances": r"tolerance\.png|tolerance_samples\.csv",
    "no_samples": r"tolerance_samples\.csv",
    "no_marker": r"marker\.(dxf|svg|png)",
}


class Options(argparse.Namespace):
    """Every option's value (defaults < case file < command line), read-only: ``options.n_span``; the case
    file's ``[[rib]]`` tables as ``wing``, the manufacturing tolerances as ``tolerances`` (``NAME=VALUE``)."""

    def __init__(self, values: Mapping):
        for name, value in values.items():
            object.__setattr__(self, name, value)

    def __setattr__(self, name, value):
        raise AttributeError(f"a case's options are read-only ({name})")


@dataclass(frozen=True)
class Rib:
    """One rib of a case, root to tip.

    Attributes:
        section: the rib's section (`targets.Airfoil`, chord-normalised).
        chord: its chord, m.
        station: its span position y, m.
        target: the section the skin must match at this rib (`targets.Airfoil`).
    """

    section: object
    chord: float
    station: float
    target: object


@dataclass(frozen=True, eq=False)
class Case:
    """A run's case: its options and its ribs, checked (module docstring).

    Attributes:
        options: every option's value (`Options`).
        sources: ``{option: "config" or "command line"}`` for every option not at its default.
        ribs: the ribs, root to tip (two for a single bay).
        variables: the design variables' names (``--variables``).
        from_ribs: the ribs are a case file's ``[[rib]]`` tables (else: a bay given by options, whose
            two ribs take one rib shape and one cut field, as `inverse_design.optimise_pressure`'s).
        notes: the warnings raised while the case was read (a section renormalised to unit chord, ...):
            the run shows them with its own and records them in the summary.
        law: the fibre law fitted to ``--fabric-test`` (a `forward_solver.FittedLaw`), or None (eq. 10).
        marker: the shop's marker asked for (``--roll-width``: an `inverse_design.marker.MarkerRequest` with
            the gap, the warp and the time limit), or None.
    """

    options: Options
    sources: Mapping
    ribs: tuple
    variables: tuple
    from_ribs: bool
    notes: tuple = ()
    law: object = None
    marker: object = None

    @classmethod
    def from_arguments(cls, argv: list[str] | None = None) -> "Case":
        """The case of a command line (default ``sys.argv[1:]``): options, case file and sections read
        and checked (module docstring).

        Raises:
            InputError: one line for any bad option, case file, section or combination
                (docs/errors.md).
            SystemExit: for ``--help``.
        """
        options, sources = _merged_options(sys.argv[1:] if argv is None else list(argv))
        variables = _variables(options, sources)
        check_combinations(options, sources, variables)
        check_values(options, sources)
        marker = marker_request(options, sources)
        law = fabric_law(options)
        with warnings.catch_warnings(record=True) as caught:  # (a section renormalised, a field per bay on one)
            warnings.simplefilter("always")
            ribs = _ribs(options, sources)
            check_rib_spacings(options, ribs)
            case = cls(options=options, sources=sources, ribs=ribs, variables=variables,
                       from_ribs=options.wing is not None, law=law, marker=marker)
            case._check_fields()
        return dataclasses.replace(case, notes=tuple(dict.fromkeys(str(w.message) for w in caught)))

    # ------------------------------------------------------------------ what the run does
    @property
    def n_bays(self) -> int:
        return len(self.ribs) - 1

    @property
    def designed(self) -> tuple:
        """The variables a design optimises: none with ``--evaluate`` (one equilibrium)."""
        return () if self.options.evaluate else self.variables

    @property
    def bays(self) -> list:
        """``(rib_spacing, mean chord)`` of each bay, m (`inverse_design.plausibility.check_plausibility`)."""
        return [(b.station - a.station, 0.5 * (a.chord + b.chord)) for a, b in zip(self.ribs, self.ribs[1:])]

    @property
    def inputs(self) -> dict:
        """The options as ``summary.json`` records them: the values, ``wing`` (a case file's rib tables,
        else None) and ``sources``."""
        return {"wing": None, **vars(self.options), "sources": dict(self.sources)}

    def may_write(self, name: str) -> bool:
        """Whether this run's report may write a file of that name.

        Every report file name (`output_folder.REPORT_FILES`) but those this
        kind of run never writes (a single bay's extras in a run of several
        bays, ``history.png`` with ``--evaluate``, ``rib.dat`` without a rib
        shape, the patterns with ``--no-patterns``, the figures with ``--no-figures``, ...). Used to refuse,
        before the long work, a file an earlier report wrote and someone
        edited since, which this run would replace
        (`output_folder.check_output_folder`); the run keeps such a file that
        it does not write, and says so.
        """
        return self._never.fullmatch(name) is None

    @cached_property
    def _never(self):
        o = self.options
        kinds = {"any": True, "several_bays": self.n_bays > 1, "evaluate": o.evaluate,
                 "unshaped": "rib_shape" not in self.variables, "no_aero": not o.aero, "no_patterns": o.no_patterns,
                 "no_figures": o.no_figures,
                 "no_tolerances": not o.tolerances, "no_samples": bool(o.tolerances) and not o.samples,
                 "no_marker": self.marker is None}
        return re.compile("|".join(f"(?:{_NEVER[kind]})" for kind, never in kinds.items() if never))

    def ignored_options(self) -> list[str]:
        """Options given that the run does not use: one warning line each (docs/errors.md).

        ``--variables`` with ``--evaluate`` (the equilibrium is solved at the
        given values; its fields are refused as the case is read);
        ``--shape-spec``, ``--samples``, ``--seed`` or ``--scheduler`` without tolerances.
        """
        o, sources, lines = self.options, self.sources, []
        if not o.tolerances:
            for name in ("shape_spec", "samples", "seed", "scheduler"):
                if name in sources:
                    lines.append(f"{given(name, sources)} is ignored without tolerances (--tolerance NAME=VALUE or "
                                 "a [tolerances] table), which turn on the tolerance analysis")
        elif "scheduler" in sources and not o.samples:
            lines.append(f"{given('scheduler', sources)} is ignored without --samples: the first-order analysis "
                         "runs here; the cluster solves Monte Carlo wings")
        if o.evaluate and "variables" in sources:
            lines.append(f"{given('variables', sources)} {o.variables} is ignored with "
                         f"{given('evaluate', sources)}, which solves the equilibrium at the given values "
                         "(--pressure, --prestrain-span, ...) and optimises nothing")
        return lines

    # ------------------------------------------------------------------ the library inputs
    @cached_property
    def fabric(self):
        """The skin's `forward_solver.Fabric`."""
        return _design().fabric(self)

    @cached_property
    def wing(self):
        """The `forward_solver.Wing` of the ribs (made once: it keeps its bays)."""
        return _design().wing(self)

    @property
    def targets(self) -> list:
        """Each rib's target section (`targets.Airfoil`), root to tip."""
        return [rib.target for rib in self.ribs]

    @cached_property
    def start(self):
        """The starting `forward_solver.Parameters` (zero rib-shape and cut-field coefficients when designed)."""
        return _design().start(self)

    @property
    def bounds(self) -> dict:
        """``{name: (lower, upper)}`` of the designed variables."""
        o = self.options
        every = {"pressure": o.pressure_bounds, "prestrain_span": o.prestrain_bounds,
                 "prestrain_chord": o.prestrain_bounds, "rib_thickness_scale": o.rib_thickness_bounds,
                 "rib_chord_scale": o.rib_chord_bounds, "rib_shape": o.rib_shape_bounds,
                 "cut_pattern": o.cut_pattern_bounds}
        return {name: tuple(every[name]) for name in self.variables if name in every}

    @cached_property
    def limits(self):
        """The `inverse_design.Limits`: tension limits (None with ``--no-tension-constraints``) and rib
        limits (None without a designed rib shape, or with ``--no-rib-limits``)."""
        return _design().limits(self)

    @property
    def layout(self):
        """The `inverse_design.Layout` of the design: the grid, and a bay given by options as
        `inverse_design.optimise_pressure` lays it out (one rib shape, one cut field)."""
        return _design().layout(self)

    # ------------------------------------------------------------------ checks
    def _check_fields(self) -> None:
        """Refuse a designed rib shape or cut field whose options make no sense (before any solve); say
        that a cut field per bay on a bay given by options is the shared one."""
        o = self.options
        if "rib_shape" in self.designed:
            if not o.no_rib_limits and o.min_rib_thickness > 1:
                raise InputError(f"--min-rib-thickness is a fraction of the starting rib's thickness in "
                                 f"(0, 1], got {o.min_rib_thickness}")
        if "cut_pattern" in self.designed:
            if o.cut_pattern_terms > o.n_contour:  # (beyond one term per node a term moves nothing)
                raise InputError(f"a cut pattern of {o.cut_pattern_terms} terms per fibre direction on "
                                 f"{o.n_contour} contour nodes: at most one term per contour node moves the skin; "
                                 f"give --cut-pattern-terms {o.n_contour} or fewer, or more --n-contour")
            if o.cut_pattern_layout == "per_bay" and not self.from_ribs:
                # (a case file's two ribs reach `variables.DesignVariables.build`, which says so itself)
                warnings.warn("--cut-pattern-layout per_bay on one bay is the shared field: the design optimises "
                              "one cut field", stacklevel=3)


def _design():
    """`inverse_design.app.design`, imported on first use."""
    from . import design  # (worker: a spawned report worker imports this module, through cli, without JAX)

    return design


def _merged_options(argv: list[str]) -> tuple[Options, dict]:
    """The options, defaults < case file < command line, and where each not at its default came from."""
    build_parser().parse_args(argv)  # --help, and every check with the full messages
    given = vars(build_parser(suppress_defaults=True).parse_args(argv))
    defaults = vars(build_parser().parse_args([]))
    config = read_config(given["config"]) if given.get("config") else {}
    merged = {**defaults, **config, **given}
    # tolerances: the case file's table, then the command line's (a name given on both: the command line's)
    merged["tolerances"] = [*(config.get("tolerances") or []), *(given.get("tolerances") or [])] or None
    if merged.get("objective") == "robust" and not merged["tolerances"]:  # (designed for the defaults)
        merged["tolerances"] = ["defaults"]
    merged.setdefault("wing", None)
    sources = {**{k: "config" for k in config}, **{k: "command line" for k in given}}
    return Options(merged), sources


def _variables(o: Options, sources: Mapping) -> tuple:
    """``--variables`` as names, each one a design variable (`inverse_design.defaults.VARIABLES`)."""
    names = tuple(v.strip() for v in o.variables.split(",") if v.strip())
    unknown = [name for name in names if name not in VARIABLES]
    if unknown or not names:
        where = f"{o.config}: variables" if sources.get("variables") == "config" else "--variables"
        what = f"unknown design variable {unknown[0]!r}" if unknown else "no design variable given"
        raise InputError(f"{where}: {what}; choose among {', '.join(VARIABLES)}")
    return names


def _ribs(o: Options, sources: Mapping) -> tuple:
    """The case's ribs, each section loaded once: a case file's ``[[rib]]`` tables, or the bay of the options."""
    if o.wing is None:
        target = load_section(o.target, "--target")
        rib = target if o.rib is None else load_section(o.rib, "--rib")
        return (Rib(rib, o.chord, 0.0, target), Rib(rib, o.chord, o.rib_spacing, target))
    where = f"{o.config}: rib"
    loaded = {}  # spec -> section: a wing's ribs mostly name one (the 40-cell wing's 41 ribs: 0.35 s, now once)

    def section_of(spec, option):
        if spec not in loaded:
            loaded[spec] = load_section(spec, option)
        return loaded[spec]

    sections = [section_of(r["section"], f"{where} {k}: section") for k, r in enumerate(o.wing)]
    common = section_of(o.target, "--target") if "target" in sources else None
    return tuple(Rib(section, r["chord"], r["station"],
                     section_of(r["target"], f"{where} {k}: target") if "target" in r else
                     common if common is not None else section)
                 for k, (section, r) in enumerate(zip(sections, o.wing)))


def load_section(spec: str, option: str):
    """The `targets.Airfoil` of a NACA code or a Selig/Lednicer ``.dat`` file, for the option (or the case
    file's rib) ``option``.

    Raises:
        InputError: one line for a folder, a missing file, a file that is not an airfoil (the airfoil
            reader's own message, which names the file and the line) or an unknown code.
    """
    from targets import load_airfoil, naca, parse_naca  # (worker: imported through cli by every report worker; 0.3 s of SciPy)

    if not str(spec).strip():
        raise InputError(f"{option}: the section is an empty name (an unset shell variable?); give a NACA code such "
                         "as naca2412 or a .dat file")
    path = Path(spec)
    if path.is_dir():
        raise InputError(f"{option}: {spec} is a directory; give a NACA code such as naca2412 or a .dat file")
    if path.suffix.lower() == ".dat" or path.exists():
        if not path.is_file():
            raise InputError(f"{option}: no such file {spec!r}; give a NACA code such as naca2412 or the "
                             "path of a Selig/Lednicer .dat file")
        try:
            section = load_airfoil(path)
        except OSError as exc:
            raise InputError(f"{option}: cannot read {spec}: {exc.strerror or exc}") from None
        except ValueError as exc:
            raise InputError(str(exc)) from None
        if section.surface_error is not None:  # (a bay needs single-valued surfaces: refused here, not mid-run)
            raise InputError(f"{spec}: airfoil {section.name!r}: {section.surface_error}")
        return section
    try:
        parse_naca(spec)
    except ValueError as exc:
        raise InputError(f"{option} {spec!r} is neither a NACA code nor a .dat file: {exc}") from None
    try:
        return naca(spec)
    except ValueError as exc:
        raise InputError(f"{option} {spec}: {exc}") from None

