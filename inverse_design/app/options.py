"""The options of ``optimise-pressure``: one table (`OPTIONS`) for the command line and case files.

Each option is ``(group, flag, argparse keywords)``; `build_parser` builds the
parser from it and `case.read_config` converts a case file's values with the
same types and choices, so an option means the same in both places. Bad
input raises `InputError` (exit code 2, one line).
"""

from __future__ import annotations

import argparse
import math
import re

from .. import defaults
from .resources import MAX_NODES

__all__ = ["DEFAULT_VARIABLES", "InputError", "OPTIONS", "OPTION_SPECS", "PROG", "build_parser"]

PROG = "optimise-pressure"
#: ``--variables`` of the default case.
DEFAULT_VARIABLES = ",".join(defaults.DESIGN_VARIABLES)


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

    number.numeric = True  # (a case file gives it as a TOML number, not a string: `case_file`)
    return number


def _folder(text):
    """``--out``: any path but the empty one (an unset shell variable, which would mean the current folder)."""
    if text == "":
        raise argparse.ArgumentTypeError("the output folder is an empty name (an unset shell variable?), which "
                                         "would put the report's files in the current folder: give a folder "
                                         "name, or . for the current folder")
    return text


def _tolerance_value(text):
    """``--tolerance``: a number (the optimiser's tolerance, positive), or NAME=VALUE / defaults (a
    manufacturing tolerance, checked by `inverse_design.tolerance.parse_tolerances` before any solve)."""
    text = str(text).strip()
    if "=" in text or text == "defaults":
        return text
    return _number(positive=True)(text)


class _Tolerance(argparse.Action):
    """``--tolerance``: a number sets the optimiser's tolerance; NAME=VALUE appends to ``tolerances``."""

    def __call__(self, parser, namespace, value, option_string=None):
        if isinstance(value, str):
            namespace.tolerances = [*(getattr(namespace, "tolerances", None) or []), value]
        else:
            setattr(namespace, self.dest, value)


def _whole(least: int, why: str = ""):
    """A type function for a whole number of at least ``least`` (``why``: the reason, for the message)."""

    def whole(text):
        try:
            value = int(text)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
        if value < least:
            raise argparse.ArgumentTypeError(f"must be {least} or more{why}, got {text!r}")
        return value

    whole.numeric = True
    return whole


# One entry per option: (group, flag, argparse keyword arguments). The TOML
# reader converts a case file's values with the same types and choices.
_GROUPS = {
    "target": "target and ribs",
    "bay": "bay and grid",
    "fabric": "fabric",
    "design": "design variables and bounds",
    "constraints": "tension constraints",
    "rib": "rib shape (--variables ...,rib_shape)",
    "cut": "cut pattern (--variables ...,cut_pattern)",
    "optimiser": "optimiser",
    "aero": "aerodynamics",
    "marker": "the shop's marker (--roll-width: every panel nested on the fabric roll)",
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
    ("bay", "--n-span", dict(type=_whole(3, " (the two ribs and at least one row between)"), default=defaults.N_SPAN,
                             metavar="N",
                             help=f"grid nodes along the span, ribs included (default {defaults.N_SPAN}: with fewer, "
                             "the skin's contour strain next to the ribs is under-resolved and shows "
                             "spurious compression, which the wrinkle constraint then obeys)")),
    ("bay", "--n-contour", dict(type=_whole(12, " (nodes around an airfoil)"), default=defaults.N_CONTOUR,
                                metavar="N",
                                help=f"grid nodes around the contour (default {defaults.N_CONTOUR})")),
    ("bay", "--allow-large-grid", dict(action="store_true",
                                       help="run a grid that is refused otherwise: one whose estimated peak "
                                       "memory exceeds half of the available memory, or with more than "
                                       f"{MAX_NODES:,} nodes (hours per design); and --samples beyond their "
                                       "memory and time limits (not beyond the machine's memory)")),
    ("fabric", "--stiffness-span", dict(type=_number("N/m", positive=True), default=2e5, metavar="N/M",
                                        help="tensile stiffness E11 of the span fibres per unit width, N/m, of "
                                        "eq. 10 (default 2e5; with --fabric-test, the test's law gives it)")),
    ("fabric", "--stiffness-chord", dict(type=_number("N/m", positive=True), default=2e5, metavar="N/M",
                                         help="tensile stiffness E22 of the contour fibres, N/m (default 2e5)")),
    ("fabric", "--poisson", dict(type=_number(), default=0.25, metavar="NU",
                                 help="Poisson coupling nu12 = nu21, in [0, 1) (default 0.25)")),
    ("fabric", "--fabric-test", dict(default=None, metavar="FILE",
                                     help="the fabric's biaxial test, a CSV of readings (strain_warp, strain_weft, "
                                     "tension_warp, tension_weft[, load_ratio]; strains as fractions, N/m): the "
                                     "design takes the fibre law fitted to it instead of eq. 10's constant "
                                     "stiffnesses (docs/fabric_test.md)")),
    ("fabric", "--warp", dict(default="span", choices=("span", "chord"),
                              help="which way the fabric's warp (the roll's length, the test's warp) runs on the "
                              "wing; the patterns' WARP arrow follows it (default span)")),
    ("fabric", "--shear-stiffness", dict(type=_number("N/m"), default=0.0, metavar="N/M",
                                         help="shear stiffness G of the fabric, N/m, 0 or more: the T12 terms of the "
                                         "paper's eq. 1 (textiles have about 2%% of their tensile stiffness; "
                                         "default 0, as the paper takes it)")),
    ("fabric", "--prestrain-span", dict(type=_number("fraction"), default=defaults.PRESTRAIN_SPAN, metavar="E",
                                        help="span prestrain, fraction: the fabric is cut 1 + E times "
                                        f"shorter (start if optimised, default {defaults.PRESTRAIN_SPAN:g})")),
    ("fabric", "--prestrain-chord", dict(type=_number("fraction"), default=defaults.PRESTRAIN_CHORD, metavar="E",
                                         help="contour prestrain, fraction (start if optimised, default "
                                         f"{defaults.PRESTRAIN_CHORD:g})")),
    ("design", "--pressure", dict(type=_number("Pa", positive=True), default=defaults.PRESSURE, metavar="PA",
                                  help="internal overpressure, Pa: the start of the optimisation, or the "
                                  f"value evaluated with --evaluate (default {defaults.PRESSURE:g})")),
    ("design", "--variables", dict(default=DEFAULT_VARIABLES, metavar="NAMES",
                                   help=f"comma-separated design variables among {', '.join(defaults.VARIABLES)} "
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
    ("rib", "--rib-shape-terms", dict(type=_whole(1), default=4, metavar="K",
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
    ("cut", "--cut-pattern-terms", dict(type=_whole(1), default=6, metavar="K",
                                        help="B-spline terms per fibre direction of the prestrain field along "
                                        "the contour (2 K coefficients added to the uniform prestrains, "
                                        "started at zero; default 6)")),
    ("cut", "--cut-pattern-bounds", dict(type=_number("fraction"), nargs=2, default=(-0.02, 0.05),
                                         metavar=("LOW", "HIGH"),
                                         help="bounds of the local prestrain of the cut pattern, both "
                                         "directions, fraction (default -0.02 0.05)")),
    ("cut", "--cut-pattern-layout", dict(default="shared", choices=("shared", "per_bay"),
                                         help="a wing's cut pattern: one field for every bay (shared, the "
                                         "default) or one per bay, each cell's panel cut on its own (per_bay: "
                                         "n_bays x 2 K coefficients)")),
    ("optimiser", "--objective", dict(default=defaults.OBJECTIVE, choices=defaults.OBJECTIVES,
                                      help="sections that must match the target: the mid-bay one, every "
                                      f"row from rib to rib, or the worst row (default {defaults.OBJECTIVE}); robust: "
                                      "every row's linearised 95th percentile under the tolerances "
                                      "(--tolerance, default every default), the tension limits at their "
                                      "own percentile (docs/tolerances.md)")),
    ("optimiser", "--method", dict(default="auto", choices=("auto", "slsqp", "gauss_newton", "least_squares",
                                                            "root", "optax"),
                                   help="optimiser: auto (gauss_newton; slsqp with --objective worst), "
                                   "slsqp (the tension limits as constraints), gauss_newton "
                                   "(trust-region SQP on the row distances with their Jacobian, the limits "
                                   "as constraints: few solves for many variables), "
                                   "least_squares or optax (as penalties), root (brentq; takes "
                                   "--variables pressure) (default auto)")),
    ("optimiser", "--root-condition", dict(default="thickness", choices=("thickness", "mean_offset"),
                                           help="scalar condition of --method root at mid-bay "
                                           "(default thickness)")),
    ("optimiser", "--max-iterations", dict(type=_whole(1), default=50, metavar="N",
                                           help="cap on the optimiser's iterations (default 50)")),
    ("optimiser", "--tolerance", dict(type=_tolerance_value, action=_Tolerance, default=None, metavar="TOL",
                                      help="a number: the convergence tolerance of the optimiser (default: slsqp "
                                      "1e-6 of the starting objective, gauss_newton 1e-3 of the merit (the model's "
                                      "predicted fall), the others 1e-8); NAME=VALUE (repeatable): a manufacturing "
                                      "tolerance, the standard deviation of pressure (Pa), stiffness_span, "
                                      "stiffness_chord (N/m, per bay), cut_span, cut_chord (mm, per bay), "
                                      "rib_station, rib_profile (mm, per rib), or 2%% of the nominal, or "
                                      "uniform:VALUE, or default; 'defaults' sets every one at its default "
                                      "(docs/tolerances.md); turns on the tolerance analysis after the design")),
    ("optimiser", "--shape-spec", dict(type=_number("mm", positive=True), default=None, metavar="MM",
                                       help="with tolerances: the shape specification, 95%% of wings within this "
                                       "rms distance from the target, mm; the report gives the tolerance budget "
                                       "that meets it")),
    ("optimiser", "--samples", dict(type=_whole(0, " (0: first order only)"), default=0, metavar="N",
                                    help="with tolerances: Monte Carlo wings solved to check the first-order "
                                    "analysis (default 0: first order only); tolerance_samples.csv. More than "
                                    "an hour of solves here, or than half of the available memory holds, is "
                                    "refused before the run (docs/tolerances.md)")),
    ("optimiser", "--seed", dict(type=_whole(0), default=0, metavar="N",
                                 help="seed of the Monte Carlo draws (default 0: the same wings every run)")),
    ("optimiser", "--scheduler", dict(default=None, metavar="ADDRESS",
                                      help="with --samples: solve the Monte Carlo wings on the Dask cluster of "
                                      "this scheduler (tcp://host:8786; the dask extra) instead of in this "
                                      "process; the same seed gives the same numbers")),
    ("optimiser", "--refine", dict(action="store_true",
                                   help="confirm and polish the design on a grid with twice the span "
                                   "resolution (2 n-span - 1 nodes) and report how far it moved")),
    ("optimiser", "--evaluate", dict(action="store_true",
                                     help="only solve the equilibrium at the given values and report it "
                                     "(no optimisation, no history plot)")),
    ("optimiser", "--max-steps", dict(type=_whole(1), default=200_000, metavar="N",
                                      help="step cap of each relaxation of every equilibrium solve, in every "
                                      "mode (default 200000)")),
    ("optimiser", "--equilibrium-method", dict(default="auto", choices=("auto", "relax", "newton", "relax+newton"),
                                               help="equilibrium solver: auto tries relax+newton, then Newton from "
                                               "where it stopped, then Newton with load continuation, before "
                                               "failing; or one method alone, for every bay of a wing too "
                                               "(default auto; a design on an accelerator relaxes its bays "
                                               "together: auto or relax)")),
    ("aero", "--aero", dict(action="store_true",
                            help="compare lift, drag and moment of the cured mid-bay and bay-average sections "
                            "with the target's (NeuralFoil: pip install \"inflatable-wing[aero]\"); "
                            "per bay; writes bay_K_aero.png and each bay's aero entry in summary.json")),
    ("aero", "--reynolds", dict(type=_number(positive=True), default=1e6, metavar="RE",
                                help="chord Reynolds number of --aero (default 1e6)")),
    ("aero", "--alpha-range", dict(type=_number("deg"), nargs=3, default=(-4.0, 10.0, 1.0),
                                   metavar=("START", "STOP", "STEP"),
                                   help="angles of attack of --aero, deg, stop included, within +-20 "
                                   "(default -4 10 1)")),
    ("marker", "--roll-width", dict(type=_number("mm", positive=True), default=None, metavar="MM",
                                    help="nest every bay's panels (their cut outlines) on a fabric roll this wide, "
                                    "mm, each turned by 0 or 180 degrees so that its warp runs along the roll (90 "
                                    "or 270 with --warp chord), never mirrored: marker.dxf, .svg, .png and "
                                    "summary.json's marker (the marker extra: pip install "
                                    "\"inflatable-wing[marker]\"; docs/patterns.md)")),
    ("marker", "--marker-gap", dict(type=_number("mm"), default=5.0, metavar="MM",
                                    help="with --roll-width: the least distance between two cut outlines, and "
                                    "half of it from the roll's edges, mm (default 5)")),
    ("marker", "--marker-seconds", dict(type=_number("s", positive=True), default=None, metavar="S",
                                        help="with --roll-width: the nesting's time limit, s (default: 20 s and half a "
                                        "second per panel, 21 s for a bay, 60 s for 80 panels; a search that ends "
                                        "on its own before it gives the same marker every run)")),
    ("output", "--config", dict(default=None, metavar="CASE.TOML",
                                help="read options from a TOML file (keys: the long option names); "
                                "command-line options override it")),
    ("output", "--out", dict(type=_folder, default="optimise-pressure-out", metavar="DIR",
                             help="output folder (may be . or hold other files, which are never touched): "
                             "an earlier report's files in it are replaced (or removed) when the new "
                             "report is complete (default optimise-pressure-out)")),
    ("output", "--magnification", dict(type=_number(positive=True), default=None, metavar="X",
                                       help="deviation factor of the section plot (default: automatic, "
                                       "1, 2, 5, 10, ...)")),
    ("output", "--seam-allowance", dict(type=_number("mm"), default=10.0, metavar="MM",
                                        help="seam allowance of the cut-ready patterns: the cut line lies this "
                                        "far outside the sewing line, mm, 0 or more (default 10)")),
    ("output", "--no-patterns", dict(action="store_true",
                                     help="do not write the flat panels and rib templates (pattern_bay_*.dxf, "
                                     ".svg, rib_*.dxf)")),
    ("output", "--no-figures", dict(action="store_true",
                                    help="do not draw the report's figures (every .png, the marker's too): the "
                                    "data files, patterns and summary.json alone, about a second sooner (a sweep "
                                    "of runs)")),
    ("output", "--json", dict(action="store_true", help="print the summary as JSON on stdout, nothing else")),
    ("output", "--quiet", dict(action="store_true", help="print nothing but errors")),
    ("output", "--no-compilation-cache", dict(action="store_true",
                                              help="do not keep JAX's compiled functions between runs "
                                              "(default: kept in $INFLATABLE_WING_CACHE, else "
                                              "$JAX_COMPILATION_CACHE_DIR, else $XDG_CACHE_HOME/inflatable-wing/jax, "
                                              "else ~/.cache/inflatable-wing/jax)")),
)
OPTION_SPECS = {flag[2:].replace("-", "_"): kwargs for _, flag, kwargs in OPTIONS}

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
                        timings, package version, the files written, a bay axis
  wing.npz              every bay: nodes (n_bays, n_span, n_contour, 3) m, tensions N/m,
                        wrinkled cells, deviation from the targets, parameters
  skin.obj, skin.stl    the equilibrium skin as one mesh, metres
  wing_overview.png     every bay: deviation map, errors and tensions per bay
  bay_K_mid_bay_section.png   bay K's mid-bay section against its rib and target (magnified)
  history.png           the optimiser's iterates (not with --evaluate)
  bay_K_aero.png        bay K's lift, drag and moment against its target (with --aero)
  bay_K_cut_pattern.csv bay K's cut lengths along the contour and the span
  rib.dat or rib_K.dat  the designed rib(s), Selig (with --variables ...,rib_shape)
  (with --variables ...,cut_pattern the cut lengths follow the designed field)
  one bay also: equilibrium.npz (the bay in full), deviation.png (deviation over the
                        bay), tensions.png (wrinkled cells marked), rib_design.png
  pattern_bay_K_upper.dxf, pattern_bay_K_lower.dxf   the flat panels, cut-ready, 1:1 in mm:
                        layers SEW (sewing line at the cut lengths), CUT (at the seam
                        allowance), MARK (alignment marks numbered as the ribs' ticks,
                        each edge's rib or seam, warp, label, outside face, 100 mm
                        scale bar), GRID (the
                        developed span fibres; a layer off when opened); .svg of each for
                        a quick look; rib_K.dxf the rib templates (SEW the rib itself, CUT
                        its seam allowance; a successful design only; not with
                        --no-patterns)
  marker.dxf, .svg, .png  with --roll-width: every panel nested on the roll, grain-true
                        (docs/patterns.md; summary.json's marker: length, utilisation)
  (with --no-figures no .png is drawn; summary.json's skipped names each)

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
estimate); --allow-large-grid runs it anyway. So are --samples that would take more than an
hour of solves in this process (not with --scheduler) or more than half of the available memory,
unless --allow-large-grid (never more than the machine's memory).

A second run into a DIR that a run is writing is refused (exit 2); a file of an earlier
report that was edited since (its size or SHA-256 differ from summary.json's record) is
kept: a run that would replace it is refused (exit 2), any other says so and leaves it.

exit codes: 0 done; 1 the run failed (the reason on stderr); 2 bad input (every refusal
and its message: docs/errors.md); 130 interrupted (Ctrl-C); 143 terminated (SIGTERM).
Interrupted or terminated, nothing is written.

environment: JAX's compiled functions are kept between runs in $INFLATABLE_WING_CACHE,
else $JAX_COMPILATION_CACHE_DIR, else $XDG_CACHE_HOME/inflatable-wing/jax, else
~/.cache/inflatable-wing/jax (--no-compilation-cache: not kept; deleting the folder
clears it). The command also reads JAX_PLATFORMS, XLA_FLAGS, MPLCONFIGDIR and HOME;
what each does: docs/command.md, "Environment".
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
