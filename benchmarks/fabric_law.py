"""The fabric law fitted to the example biaxial test against eq. (10): the designs it changes, and its cost.

The example test (`inverse_design/cases/fabric_test_example.csv`, synthetic:
docs/fabric_test.md) is fitted (`forward_solver.fit_law`) and given to the
command (``--fabric-test``); the linear law is eq. (10) with the command's
default fabric (2e5 N/m both ways, Poisson 0.25). Cases, each on the
command's default 17 x 64 grid:

* the default bay (NACA 2412, chord 1 m, ribs 0.25 m apart) and the built-in
  wing (`inverse_design/cases/wing_taper.toml`, three bays);
* designed in pressure and both prestrains (0-5%), and in pressure and a cut
  pattern (``cut_pattern``, the prestrains at their 2% start).

For each: the designed pressure and prestrains, the rms error after the
design, and the largest change in a cut length between the two laws (mm,
over every bay's cut pattern file: the contour's cut arc length at the root
and mid-bay, and the span's cut length, at every contour node). Each command
runs twice in fresh processes, the laws alternating; the second run's
optimisation time (its compilation cache warm) gives the design-time ratio.

The forward solve's cost: one bay of the default case (17 x 64, 10 kPa,
prestrain 2% both ways) solved by ``solve_equilibrium`` with each law in one
process, alternating: the first call (compilation included) and the median
of warm calls.

Run:  PYTHONPATH=. python benchmarks/fabric_law.py [--quick]

``--quick`` runs the default bay's pressure-and-prestrain design only.
Writes benchmarks/results/fabric_law_designs.json and fabric_law_cost.json
(``benchmarks/performance_doc.py`` puts them in docs/performance.md).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.results import print_result, save_result  # noqa: E402

EXAMPLE = ROOT / "inverse_design" / "cases" / "fabric_test_example.csv"
WING = ROOT / "inverse_design" / "cases" / "wing_taper.toml"
CASES = {"default bay": [], "built-in wing": ["--config", str(WING)]}
DESIGNS = {"pressure, prestrains": ["--variables", "pressure,prestrain_span,prestrain_chord",
                                    "--prestrain-bounds", "0", "0.05"],
           "pressure, cut pattern": ["--variables", "pressure,cut_pattern"]}
LAWS = {"eq. 10": [], "fitted": ["--fabric-test", str(EXAMPLE)]}
#: The cut pattern files' cut lengths compared between the laws, m.
CUT_COLUMNS = ("arc_cut_root_m", "arc_cut_mid_m", "span_cut_m")


def _command(args: list[str], out: Path) -> dict:
    """One fresh ``optimise-pressure`` process: its summary, and the cut lengths of every bay's pattern file."""
    ran = subprocess.run([sys.executable, "-m", "inverse_design.app.cli", *args, "--out", str(out), "--quiet"],
                         cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True, text=True)
    if ran.returncode != 0:
        raise RuntimeError(f"{' '.join(args)}: exit {ran.returncode}\n{ran.stderr}")
    summary = json.loads((out / "summary.json").read_text())
    cuts = []
    for path in sorted(out.glob("bay_*_cut_pattern.csv")):
        with path.open() as fh:
            rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
        cuts.append([[float(row[c]) for c in CUT_COLUMNS] for row in rows])
    return {"summary": summary, "cuts": cuts}


def designs(quick: bool) -> tuple[list, list]:
    cases = {"default bay": []} if quick else CASES
    plans = {"pressure, prestrains": DESIGNS["pressure, prestrains"]} if quick else DESIGNS
    rows, notes = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for case, case_args in cases.items():
            for design, design_args in plans.items():
                runs = {law: [] for law in LAWS}
                for repeat in range(2):
                    order = list(LAWS) if repeat == 0 else list(reversed(LAWS))
                    for law in order:
                        out = Path(tmp) / f"{len(rows)}_{law.replace(' ', '').replace('.', '')}_{repeat}"
                        runs[law].append(_command([*case_args, *design_args, *LAWS[law]], out))
                linear, fitted = runs["eq. 10"][-1], runs["fitted"][-1]
                change = max(abs(a - b) for bay_a, bay_b in zip(linear["cuts"], fitted["cuts"])
                             for row_a, row_b in zip(bay_a, bay_b) for a, b in zip(row_a, row_b))
                for law, run in (("eq. 10", linear), ("fitted", fitted)):
                    s = run["summary"]
                    values = s["results"]["values"]
                    rows.append([case, design, law, s["results"]["success"], values["pressure_pa"],
                                 values["prestrain_span"], values["prestrain_chord"], s["errors"]["after"]["rms"],
                                 s["results"]["forward_solves"], s["timings_s"]["optimisation"],
                                 None if law == "eq. 10" else 1e3 * change])
                ratio = fitted["summary"]["timings_s"]["optimisation"] / linear["summary"]["timings_s"]["optimisation"]
                notes.append(f"{case}, {design}: design time fitted / eq. 10 = {ratio:.2f} (second runs, warm cache)")
    return rows, notes


def solve_cost(repeats: int = 7) -> tuple[list, list]:
    """The forward solve with each law, alternating, in this process."""
    from forward_solver import Bay, Fabric, Parameters, Scene, fit_law, read_test, solve_equilibrium
    from targets import naca

    bay = Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=17, n_contour=64)
    scenes = {"eq. 10": Scene(bay, Fabric()), "fitted": Scene(bay, Fabric(law=fit_law(read_test(EXAMPLE))))}
    theta = Parameters(pressure=1e4, prestrain_span=0.02, prestrain_chord=0.02)
    first, warm, steps = {}, {law: [] for law in scenes}, {}
    for law, scene in scenes.items():
        start = time.perf_counter()
        steps[law] = int(solve_equilibrium(scene, theta).steps)
        first[law] = time.perf_counter() - start
    for _ in range(repeats):
        for law, scene in scenes.items():
            start = time.perf_counter()
            solve_equilibrium(scene, theta)
            warm[law].append(time.perf_counter() - start)
    median = {law: statistics.median(times) for law, times in warm.items()}
    rows = [[law, first[law], median[law], steps[law], median[law] / median["eq. 10"]] for law in scenes]
    notes = [f"warm solve fitted / eq. 10 = {median['fitted'] / median['eq. 10']:.2f}; first call (compilation "
             f"included) {first['fitted'] / first['eq. 10']:.2f} (the linear law compiled first, in a fresh process)"]
    return rows, notes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the default bay's pressure-and-prestrain design only")
    args = parser.parse_args()
    command = "PYTHONPATH=. python benchmarks/fabric_law.py" + (" --quick" if args.quick else "")
    rows, notes = solve_cost()
    path = save_result("fabric_law_cost", title="A bay's forward solve with the fitted law against eq. (10)",
                       command=command, columns=["law", "first_call_s", "warm_median_s", "steps", "warm_ratio"], rows=rows, notes=notes)
    print_result(path, rows, notes)
    rows, notes = designs(args.quick)
    path = save_result("fabric_law_designs" + ("_quick" if args.quick else ""),
                       title="Designs with the law fitted to the example test against eq. (10)", command=command,
                       columns=["case", "design", "law", "success", "pressure_pa", "prestrain_span", "prestrain_chord",
                        "rms", "forward_solves", "optimisation_s", "largest_cut_change_mm"], rows=rows, notes=notes)
    print_result(path, rows, notes)


if __name__ == "__main__":
    main()
