"""The robust design against the nominal one, each checked by Monte Carlo under the default tolerances.

Two cases, each designed twice by the command (``optimise-pressure``, in a fresh
process each): with the bay-average objective (the nominal design) and with
``--objective robust`` (the linearised 95th percentile of the rms, the tension
limits at each cell's own percentile; docs/tolerances.md), both followed by
the tolerance analysis under every default tolerance with ``--samples``
Monte Carlo wings (seed 0: the same draws for both designs):

* the default case: ``optimise-pressure`` with its defaults (NACA 2412 bay,
  chord 1 m, ribs 0.25 m apart, 17x64, pressure and rib thickness scale);
* the default case with both prestrains designed too (``--variables
  pressure,prestrain_span,prestrain_chord,rib_thickness_scale``): a smaller
  nominal error, so the scatter is a larger part of the 95th percentile;
* the built-in wing: ``inverse_design/cases/wing_taper.toml`` (3 bays, 17x64,
  the pressure alone).

What no design can beat, under the linear model: for a symmetric scatter
``ms(e) + ms(-e) = 2 ms0 + 2 |J e|^2 / n >= 2 ms0``, so at least half the
wings have an rms of at least the design's own nominal rms: the 95th
percentile is at least the median, which is at least the nominal rms, which
is at least the least nominal rms over the design space (the nominal
design's, whose limits are the looser). The largest reduction of the 95th
percentile any design can give is therefore ``1 - rms_nominal / p95_nominal``
(both of the nominal design); the table gives it beside the measured one.

A tighter bound where a source's columns ``A_p`` do not depend on the design
(the rib outlines' scatter: its part of the mean square is the same at both
designs, to 3 digits, below): over the four sign flips of ``(z_p, z_rest)``
the mean square averages ``|r|^2 + |A_p z_p|^2 + |A_rest z_rest|^2``, so with
probability at least 1/4 it is at least ``|r|^2 + |A_p z_p|^2``, and the 95th
percentile of the mean square is at least ``ms0 + t`` with ``t`` the 80th
percentile of ``|A_p z_p|^2``, itself at least ``1.642 tr(A_p^T A_p) / m``
(the largest of its ``m`` eigenvalues times the 80th percentile of a
chi-square of one degree).

Writes ``benchmarks/results/robust_design.json`` (``benchmarks/performance_doc.py`` puts it in
``docs/performance.md``). Quote the machine and its load with the numbers.

Run:  PYTHONPATH=. python benchmarks/robust_design.py [--samples 256] [--cases default,wing]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.results import print_result, save_result  # noqa: E402

CASES = {"default": [], "prestrains": ["--variables", "pressure,prestrain_span,prestrain_chord,rib_thickness_scale"],
         "wing": ["--config", str(ROOT / "inverse_design" / "cases" / "wing_taper.toml")]}
LABELS = {"default": "default case (1 bay)", "prestrains": "default case, prestrains designed too",
          "wing": "built-in wing (3 bays)"}


#: The 80th percentile of a chi-square variable of one degree of freedom.
CHI2_1_P80 = 1.6423744151498


def _outline_part(tolerance: dict) -> tuple[float, int]:
    """The rib outlines' part of the linear model's mean square (mm^2) and their column count, from a
    summary's ``tolerance`` section (each column's rms sensitivity times its standard deviation)."""
    std = {p["name"]: p["std"] for p in tolerance["parameters"]}
    columns = [p["name"] for p in tolerance["parameters"] if p["source"] == "rib_profile"]
    return sum((tolerance["sensitivities"][c]["rms_distance"] * std[c]) ** 2 for c in columns), len(columns)


def run(case: str, objective: str, samples: int, out: Path) -> dict:
    """One command run: the design, the tolerance analysis with ``samples`` wings; its summary."""
    args = [sys.executable, "-m", "inverse_design.app.cli", *CASES[case], "--objective", objective,
            "--tolerance", "defaults", "--shape-spec", "10", "--samples", str(samples), "--seed", "0",
            "--no-patterns", "--quiet", "--out", str(out)]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    start = time.perf_counter()
    done = subprocess.run(args, cwd=ROOT, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").exists() else None
    if summary is None:
        raise RuntimeError(f"{' '.join(args)} failed ({done.returncode}): {done.stderr[-2000:]}")
    summary["_wall"], summary["_code"] = wall, done.returncode
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=256)
    parser.add_argument("--cases", default="default,prestrains,wing")
    options = parser.parse_args()
    rows, notes = [], []
    with tempfile.TemporaryDirectory(prefix="robust-benchmark-") as folder:
        for case in options.cases.split(","):
            found = {}
            for objective in ("average", "robust"):
                summary = run(case, objective, options.samples, Path(folder) / f"{case}-{objective}")
                found[objective] = summary
                t = summary["tolerance"]
                results = summary["results"]
                values = {k: v for k, v in results["values"].items() if k.split("_pa")[0] in results["variables"]
                          or k in results["variables"]}
                constraint = summary.get("constraints", {}).get("values", {})
                rows.append([
                    LABELS[case], "robust" if objective == "robust" else "nominal (average)",
                    ", ".join(f"{k.replace('_pa', '')} {v:.5g}" for k, v in values.items()),
                    round(t["budget"]["nominal_rms"], 4), round(t["linear"]["rms"]["p95"], 4),
                    round(t["sampled"]["rms"]["p95"], 4), round(t["sampled"]["min_tension"]["p5"], 2),
                    round(constraint["min_tension_p5"], 2) if "min_tension_p5" in constraint else None,
                    f"{t['sampled']['failed']} / {t['sampled']['count']}", results["forward_solves"],
                    round(summary["timings_s"].get("optimisation", float("nan")), 1),
                    round(summary["timings_s"].get("samples", float("nan")), 1), summary["_code"]])
                shares = ", ".join(f"{s} {100 * v:.0f}%" for s, v in sorted(t["shares"]["rms"].items(),
                                                                            key=lambda x: -x[1]) if v >= 0.01)
                notes.append(f"{LABELS[case]}, {objective}: {results['message']}; shares of the rms's scatter "
                             f"(mean-square increase): {shares}")
            nominal, robust = (found[o]["tolerance"] for o in ("average", "robust"))
            outline = [_outline_part(found[o]["tolerance"]) for o in ("average", "robust")]
            floor = nominal["budget"]["nominal_rms"] ** 2 + CHI2_1_P80 * outline[0][0] / outline[0][1]
            outline_bound = 1.0 - floor ** 0.5 / nominal["linear"]["rms"]["p95"]
            notes.append(f"{LABELS[case]}: the rib outlines' (rib_profile) part of the mean square is "
                         f"{outline[0][0]:.4g} mm^2 at the nominal design and {outline[1][0]:.4g} mm^2 at the robust "
                         f"one ({outline[0][1]} columns); with it, no design can lower the linear p95 by more than "
                         f"{100 * outline_bound:.1f}%")
            change = robust["sampled"]["rms"]["p95"] / nominal["sampled"]["rms"]["p95"] - 1.0
            linear = robust["linear"]["rms"]["p95"] / nominal["linear"]["rms"]["p95"] - 1.0
            bound = 1.0 - nominal["budget"]["nominal_rms"] / nominal["linear"]["rms"]["p95"]
            sampled_bound = 1.0 - nominal["budget"]["nominal_rms"] / nominal["sampled"]["rms"]["p95"]
            notes.append(f"{LABELS[case]}: the robust design's p95 of the rms is {100 * change:+.1f}% of the nominal "
                         f"design's sampled ({100 * linear:+.1f}% linear; goal -20%); under the linear model no "
                         f"design can lower it by more than {100 * bound:.1f}% ({100 * sampled_bound:.1f}% against "
                         "the sampled p95): the nominal design's own rms over its p95, the module docstring's bound")
    notes.append("rms in mm (area-weighted over the bays, every row from rib to rib); 'nominal rms' is the design's "
                 "own, without scatter; p95 linear from the linearised distances (4000 draws), sampled from the "
                 "Monte Carlo wings (the same seed, so the same draws, for both designs); least tension p5: the "
                 "5th percentile over the sampled wings of their least cell tension; cell p5: the least over the "
                 "cells of each cell's own linearised 5th percentile, which the robust design holds at the floor "
                 "(0 N/m)")
    notes.append("times: the design ('optimisation', compilation included, JAX's persistent cache on) and the "
                 "samples, in seconds, on the machine described (its load included)")
    columns = ["case", "design", "design values", "nominal rms (mm)", "p95 linear (mm)", "p95 sampled (mm)",
               "least tension p5 sampled (N/m)", "cell p5 linear (N/m)", "failed samples", "wing solves",
               "design (s)", "samples (s)", "exit code"]
    path = save_result("robust_design", title=f"Robust against nominal design under the default tolerances, "
                       f"{options.samples} Monte Carlo wings each",
                       command=f"PYTHONPATH=. python benchmarks/robust_design.py --samples {options.samples}",
                       columns=columns, rows=rows, notes=notes)
    print_result(path, rows, notes)


if __name__ == "__main__":
    main()
