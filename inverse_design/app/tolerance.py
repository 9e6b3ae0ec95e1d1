"""The command's tolerance analysis: its options checked before any solve, the run after the design.

``--tolerance NAME=VALUE`` (repeatable) and a case file's ``[tolerances]``
table turn on `inverse_design.tolerance.tolerance_analysis` after the design
(or after ``--evaluate``); ``--shape-spec MM`` asks for the budget,
``--samples N`` and ``--seed`` for the Monte Carlo check, whose rows stream to
a temporary file that the report copies into ``tolerance_samples.csv``
(docs/tolerances.md); ``--scheduler ADDRESS`` solves its wings on a Dask
cluster, whose scheduler must answer before any solve.
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
import tempfile

from .options import PROG, InputError

__all__ = ["SAMPLES_FILE", "check_tolerance_options", "run_tolerance"]

#: The Monte Carlo samples' file in the output folder.
SAMPLES_FILE = "tolerance_samples.csv"


def check_tolerance_options(args: argparse.Namespace, fabric) -> dict | None:
    """The parsed tolerances (``{name: Tolerance}``), or None when none are given; bad input refused.

    Raises:
        InputError: one line: an unknown or negative tolerance, a stiffness
            scatter of 100% or more of the fabric's, ``--samples`` below 0
            (the spec's sign is checked by its option type), a ``--scheduler``
            that does not answer or without the ``distributed`` package.
    """
    from ..tolerance import SOURCE_UNITS, connect_scheduler, parse_tolerances

    if args.samples < 0:
        raise InputError(f"--samples must be 0 (first order only) or a positive number of wings, got {args.samples}")
    if not args.tolerances:
        return None
    try:
        tolerances = parse_tolerances(args.tolerances)
    except ValueError as exc:
        raise InputError(f"--{exc}") from None
    if getattr(args, "objective", None) == "robust" and not any(t.value > 0 for t in tolerances.values()):
        raise InputError("--objective robust designs for the scatter of the tolerances, and every tolerance given "
                         "is 0: give at least one (e.g. --tolerance pressure=2%), or none for the defaults")
    for name in ("stiffness_span", "stiffness_chord"):
        t = tolerances.get(name)
        nominal = getattr(fabric, name)
        if t is not None and not t.relative and t.spread(nominal) >= nominal:
            raise InputError(f"--tolerance {name}={t.text} {SOURCE_UNITS[name]} is a scatter of 100% or more of "
                             f"the fabric's {nominal:g} N/m (zero or negative stiffness): give less")
    if args.scheduler and args.samples:  # (the samples connect again: no connection is held through the design)
        try:
            connect_scheduler(args.scheduler).close()
        except (ImportError, ValueError) as exc:
            raise InputError(f"--scheduler: {exc}") from None
    return tolerances


def run_tolerance(args: argparse.Namespace, result, tolerances: dict, timings: dict, notes: list):
    """`tolerance_analysis` of ``result`` with the options' spec, samples and seed; the samples stream to
    a temporary CSV file (its path in the analysis' ``samples_file``, for the report to copy).

    Adds ``tolerance`` and ``samples`` (s) to ``timings``. A design that does not solve again at its own
    values (the analysis' nominal solve) is not lost: the analysis is skipped with a warning line, kept
    in ``notes`` (the summary's warnings), and None returned.
    """
    from forward_solver import ConvergenceError

    from ..tolerance import Sampling, tolerance_analysis

    stream = {"file": None, "writer": None}

    def on_sample(row: dict) -> None:
        if stream["writer"] is None:
            handle, path = tempfile.mkstemp(prefix="tolerance-samples-", suffix=".csv")
            stream["path"] = path
            stream["file"] = os.fdopen(handle, "w", newline="")
            stream["writer"] = csv.DictWriter(stream["file"], fieldnames=list(row))
            stream["writer"].writeheader()
        stream["writer"].writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in row.items()})
        stream["file"].flush()

    try:
        analysis = tolerance_analysis(result, tolerances, spec=args.shape_spec, sampling=Sampling(
            samples=args.samples, seed=args.seed, on_sample=on_sample, scheduler=args.scheduler or None))
    except BaseException as exc:
        if stream["file"] is not None:
            stream["file"].close()
            os.unlink(stream["path"])
        if not isinstance(exc, ConvergenceError):
            raise
        line = (f"the tolerance analysis is skipped: the design did not solve again at its own values, which the "
                f"analysis linearises about ({exc}); the design's report is written without it")
        notes.append(line)
        if not args.quiet:
            print(f"{PROG}: warning: {line}", file=sys.stderr)
        return None
    if stream["file"] is not None:
        stream["file"].close()
    analysis.samples_file = stream.get("path")
    timings["tolerance"] = analysis.timings["tolerance"]
    timings["samples"] = analysis.timings.get("samples", 0.0)
    return analysis
