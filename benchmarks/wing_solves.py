"""A design's wing solves one by one: time, Newton iterations and relaxation steps, against another checkout.

The design the command runs for a case (`benchmarks.design_matrix.design`),
with every wing solve of its `inverse_design.problem.DesignProblem` timed
and its bays' Newton iterations and relaxation steps summed. With ``--base
DIR`` (a checkout of an earlier commit, e.g. ``git worktree add /tmp/base
cf33329``) the same design runs from that tree too, each in a fresh process,
the two alternating ``--repeats`` times, so that their ratio is taken under
the same load. The compilation cache is the machine's: run once before to
measure warm-cache runs.

Run:  PYTHONPATH=. python benchmarks/wing_solves.py [--base /tmp/base] [--case wing40] [--repeats 2]

Writes benchmarks/results/wing_solves_<case>.json.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.results import print_result, save_result  # noqa: E402

CASES = {"wing40": ["--config", "inverse_design/cases/wing_40_cells.toml"],
         "wing3": ["--config", "inverse_design/cases/wing_taper.toml"], "bay": []}
VARIABLES = ["--variables", "pressure,prestrain_span,prestrain_chord"]

#: Run in a fresh process from a tree: the design, each wing solve recorded (JSON on stdout).
PROBE = """
import json, sys, time
sys.path.insert(0, {root!r})
from inverse_design import problem
from benchmarks.design_matrix import design
solves = []
solve = problem.DesignProblem._solve
def timed(self, u, initial):
    start = time.perf_counter()
    sol = solve(self, u, initial)
    bays = [s.extra for s in sol.solutions or []]
    solves.append({{"seconds": time.perf_counter() - start, "warm": initial is not None,
                   "newton": sum(int(e.get("newton_iterations") or 0) for e in bays),
                   "relax": sum(int(e.get("relax_steps") or 0) for e in bays)}})
    return sol
problem.DesignProblem._solve = timed
start = time.perf_counter()
result = design({argv!r})
print(json.dumps({{"seconds": time.perf_counter() - start, "rms": float(result.rms_error),
                  "solves": solves}}))
"""


def run(root: Path, argv: list[str]) -> dict:
    ran = subprocess.run([sys.executable, "-c", PROBE.format(root=str(root), argv=argv)], cwd=root,
                         env=dict(os.environ, PYTHONPATH=str(root)), capture_output=True, text=True, check=True)
    return json.loads(ran.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", type=Path, help="a checkout of an earlier commit to compare against")
    parser.add_argument("--case", choices=sorted(CASES), default="wing40")
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    argv = [*CASES[args.case], *VARIABLES]
    trees = {"this tree": ROOT} | ({"base": args.base.resolve()} if args.base else {})
    runs = {name: [] for name in trees}
    for _ in range(args.repeats):
        for name, root in trees.items():
            runs[name].append(run(root, argv))
    rows = []
    for name, done in runs.items():
        last = done[-1]["solves"]
        warm = [s for s in last if s["warm"]]
        rows.append([name, statistics.median(d["seconds"] for d in done), done[-1]["rms"], len(last),
                     sum(s["seconds"] for s in warm), sum(s["newton"] for s in warm), sum(s["relax"] for s in warm)])
    notes = []
    if args.base:
        ratio = rows[0][1] / rows[1][1]
        notes.append(f"design time this tree / base = {ratio:.2f} (medians of {args.repeats} alternating fresh runs)")
    command = "PYTHONPATH=. python benchmarks/wing_solves.py" + (f" --base {args.base}" if args.base else "") + \
        f" --case {args.case} --repeats {args.repeats}"
    path = save_result(f"wing_solves_{args.case}", title=f"The design's wing solves ({args.case}, pressure and prestrains)",
                       command=command, columns=["tree", "design_s", "rms", "wing_solves", "warm_solves_s",
                                                 "warm_newton_iterations", "warm_relax_steps"], rows=rows, notes=notes)
    print_result(path, rows, notes)


if __name__ == "__main__":
    main()
