"""The checks of a case's options that need no solve: contradictions, values, the fabric's test, the marker.

`case.Case.from_arguments` calls them once, whatever the source (options or a
case file), before any work; each refusal is one line (`options.InputError`,
docs/errors.md) that names the option as it was given (`given`). Nothing here
imports JAX at import: a report worker imports it (through `cli`).
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping

from ..marker import MAX_MARKER_SECONDS, MAX_ROLL_WIDTH_MM, MarkerRequest, NesterUnavailable, require_nester
from .options import InputError

__all__ = ["BOUND_OPTIONS", "DESIGNED_FIELDS", "MAX_SEAM_ALLOWANCE_MM", "MAX_SPACING_OVER_CHORD", "NOT_FOR_A_WING",
           "check_combinations", "check_rib_spacings", "check_values", "fabric_law", "given", "marker_request"]

#: Options that a wing's case file gives per rib instead, and where.
NOT_FOR_A_WING = {
    "chord": "give each rib's chord in its [[rib]] table",
    "rib_spacing": "give each rib's station in its [[rib]] table",
    "rib": "give each rib's section in its [[rib]] table",
}
#: The fields a design can take that ``--evaluate`` (one equilibrium at the given values) has no values for.
DESIGNED_FIELDS = ("rib_shape", "cut_pattern")


def given(name: str, sources: Mapping) -> str:
    """How an option was given, for a message: ``--min-tension`` or ``min-tension (case file)``."""
    flag = name.replace("_", "-")
    return f"--{flag}" if sources.get(name) != "config" else f"{flag} (case file)"


def check_combinations(o: argparse.Namespace, sources: Mapping, variables: tuple) -> None:
    """Refuse options that contradict each other (exit 2, one line each; docs/errors.md).

    * ``--no-tension-constraints`` with ``--min-tension`` or ``--max-tension``
      given: the limit would be dropped.
    * ``--evaluate`` with ``--refine``: one equilibrium has no design to refine.
    * ``--evaluate`` with ``rib_shape`` or ``cut_pattern`` among ``--variables``:
      it solves at the given values, and those fields have none to give (it
      would solve the unshaped rib and the uniform cut).
    * ``--objective robust`` with ``--evaluate`` (nothing is designed) or
      with a ``--method`` other than auto or gauss_newton.
    * ``--method root`` on a bay given by options with variables other than
      the pressure alone: root finding (brentq) solves for the pressure alone.
    * A wing's case file with an option it gives per rib (`NOT_FOR_A_WING`),
      or ``--method root`` on several bays.
    """
    if o.no_tension_constraints:
        for name in ("min_tension", "max_tension"):
            if name in sources:
                raise InputError(f"{given(name, sources)} {getattr(o, name):g} N/m contradicts "
                                 f"{given('no_tension_constraints', sources)}, which drops both tension limits: "
                                 "give one or the other")
    if o.objective == "robust" and o.evaluate:
        raise InputError(f"{given('objective', sources)} robust designs for the tolerances, and "
                         f"{given('evaluate', sources)} solves one equilibrium and designs nothing: drop --evaluate, "
                         "or give --objective average with --tolerance for the analysis of that equilibrium")
    if o.objective == "robust" and o.method not in ("auto", "gauss_newton"):
        raise InputError(f"{given('objective', sources)} robust is minimised by gauss_newton (a sum of squares "
                         f"with the tolerance Jacobian's derivatives), got {given('method', sources)} "
                         f"{o.method}: give --method auto or gauss_newton")
    if o.evaluate and o.refine:
        raise InputError(f"{given('refine', sources)} polishes a design on a finer grid, and "
                         f"{given('evaluate', sources)} solves one equilibrium and designs nothing: give one or "
                         "the other")
    fields = [name for name in variables if name in DESIGNED_FIELDS]
    if o.evaluate and "variables" in sources and fields:
        raise InputError(f"{given('evaluate', sources)} solves at the given values, and {', '.join(fields)} "
                         f"of {given('variables', sources)} has no value to give (it would solve the unshaped "
                         "rib and the uniform cut): drop --evaluate to design it, or drop it from --variables")
    if o.method == "root" and o.wing is None and variables != ("pressure",):
        raise InputError(f"{given('method', sources)} root solves for the pressure alone (brentq on one scalar "
                         f"condition at mid-bay, --root-condition), got --variables {','.join(variables)}: give "
                         "--variables pressure, or another --method")
    if o.wing is not None:
        for option, why in NOT_FOR_A_WING.items():
            if option in sources:
                raise InputError(f"{option.replace('_', '-')} does not apply to a wing ([[rib]] tables in "
                                 f"{o.config}): {why}")
        if o.method == "root" and len(o.wing) > 2 and not o.evaluate:
            raise InputError(f"method root does not apply to a wing of {len(o.wing) - 1} bays ([[rib]] tables in "
                             f"{o.config}): root finding solves one scalar condition at one bay's mid-bay "
                             "section: use slsqp, gauss_newton, least_squares or optax")


#: The options that are a (lower, upper) pair of bounds.
BOUND_OPTIONS = ("pressure_bounds", "prestrain_bounds", "rib_thickness_bounds", "rib_chord_bounds", "rib_shape_bounds",
                 "cut_pattern_bounds")


def check_values(o: argparse.Namespace, sources: Mapping) -> None:
    """Refuse the values that the option types leave open (before any solve)."""
    for name in BOUND_OPTIONS:  # (whether its variable is designed or not: a reversed pair is a slip)
        low, high = getattr(o, name)
        if not low < high:
            where = f"{o.config}: {name.replace('_', '-')}" if sources.get(name) == "config" else f"--{name.replace('_', '-')}"
            raise InputError(f"{where} {low:g} {high:g}: the lower bound must lie below the upper; give LOW HIGH "
                             "with LOW < HIGH")
    if not o.shear_stiffness >= 0:
        raise InputError(f"{given('shear_stiffness', sources)} must be 0 N/m or more (0: no shear stiffness, as the "
                         f"paper takes it), got {o.shear_stiffness:g}")
    if o.fabric_test is not None:
        for name in ("stiffness_span", "stiffness_chord", "poisson"):
            if name in sources:
                raise InputError(f"{given(name, sources)} is eq. 10's, and {given('fabric_test', sources)} "
                                 f"{o.fabric_test} gives the fabric's law (its nominal stiffnesses and coupling are "
                                 "fitted to the test): give one or the other (a lot's scatter: --tolerance "
                                 f"{name}=...)")
    if not o.seam_allowance >= 0:
        raise InputError(f"--seam-allowance must be 0 mm or more (the cut line lies outside the sewing line), "
                         f"got {o.seam_allowance:g}: give 0 or a positive number of mm")
    if o.seam_allowance > MAX_SEAM_ALLOWANCE_MM:
        raise InputError(f"--seam-allowance {o.seam_allowance:g} mm puts the cut line more than "
                         f"{MAX_SEAM_ALLOWANCE_MM / 1000:g} m outside the sewing line: give the allowance in "
                         "millimetres (a seam takes 5-20 mm)")


def marker_request(o: argparse.Namespace, sources: Mapping):
    """The marker of ``--roll-width`` (`inverse_design.marker.MarkerRequest`), or None; its values that make
    no sense, and a missing nester, refused here (before any solve; the widest panel after the design)."""
    if o.roll_width is None:
        return None
    width, gap, roll = o.roll_width, o.marker_gap, given("roll_width", sources)
    if width > MAX_ROLL_WIDTH_MM:
        raise InputError(f"{roll} {width:g} mm is wider than any roll ({MAX_ROLL_WIDTH_MM / 1000:g} m at most; "
                         "looms weave up to about 5 m): give the roll's width in millimetres")
    if not 0 <= gap < width:
        raise InputError(f"{given('marker_gap', sources)} must be 0 mm or more and less than {roll} {width:g} mm "
                         f"(the least distance between two cut outlines), got {gap:g}")
    seconds = o.marker_seconds
    if seconds is not None and not 1 <= seconds <= MAX_MARKER_SECONDS:
        raise InputError(f"{given('marker_seconds', sources)} is the nesting's time limit, from 1 to "
                         f"{MAX_MARKER_SECONDS:g} s, got {seconds:g}")
    try:
        require_nester()
    except NesterUnavailable as exc:
        raise InputError(f"{roll}: {exc}") from None
    return MarkerRequest(roll_width_mm=width, gap_mm=gap, warp=o.warp, seconds=seconds)


#: Largest rib spacing over the bay's mean chord: ribs further apart no longer shape the skin between them,
#: which inflates towards a cylinder (the model is validated to 0.5 chords, `inverse_design.plausibility`,
#: and warns beyond; a bay 1000 m long on a 1 m chord was reported as a design of rms 0.15 chord).
MAX_SPACING_OVER_CHORD = 5.0
#: Largest seam allowance, mm (`--seam-allowance`): beyond it a value in metres or micrometres is likelier.
MAX_SEAM_ALLOWANCE_MM = 1000.0


def fabric_law(o: argparse.Namespace):
    """The fibre law fitted to ``--fabric-test`` (`forward_solver.model.biaxial`: read, checked and fitted), or None.

    Raises:
        InputError: the test file's own line (it names the file, where and what to change; docs/errors.md).
    """
    if o.fabric_test is None:
        return None
    from forward_solver.model.biaxial import TestFileError, fit_law, read_test  # (worker: imported through cli by every report worker)

    if not str(o.fabric_test).strip():
        raise InputError("--fabric-test: the test file is an empty name (an unset shell variable?); give the CSV of "
                         "the fabric's biaxial test")
    try:
        return fit_law(read_test(o.fabric_test))
    except TestFileError as exc:
        raise InputError(str(exc)) from None


def check_rib_spacings(o: argparse.Namespace, ribs: tuple) -> None:
    """Refuse a bay whose ribs lie more than `MAX_SPACING_OVER_CHORD` mean chords apart (before any solve)."""
    for k in range(len(ribs) - 1):
        spacing = ribs[k + 1].station - ribs[k].station
        chord = 0.5 * (ribs[k].chord + ribs[k + 1].chord)
        if spacing > MAX_SPACING_OVER_CHORD * chord:
            where = (f"{o.config}: ribs {k} and {k + 1}" if o.wing is not None else f"--rib-spacing {o.rib_spacing:g}")
            raise InputError(f"{where}: the ribs lie {spacing:g} m apart on a {chord:g} m chord, more than "
                             f"{MAX_SPACING_OVER_CHORD:g} chords: ribs so far apart no longer shape the skin between "
                             "them (the model is validated up to 0.5 chords); place the ribs closer, or add ribs")
