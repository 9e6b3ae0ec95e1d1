"""The XLA programs a design compiles as bays are added: 1, 3 and 40 bays, fresh processes, no cache.

Each case runs the command's design (`benchmarks.design_matrix.design`, the
variables pressure and both prestrains) in a fresh Python process without a
persistent compilation cache or program store, with a `jax.monitoring`
listener on ``/jax/core/compile/backend_compile_duration`` (one event per
XLA compilation, with the compiled function's name). It records the
compilations, the distinct compiled functions, the compile seconds and the
design's wall time: a design whose programs depend on the bay count would
compile more as bays are added (the bays share one grid, so the count should
stay level).

Run:  PYTHONPATH=. python benchmarks/design_programs.py [--cases bay,wing3,wing40]

Writes benchmarks/results/design_programs.json.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.results import fresh_process_json, print_result, save_result  # noqa: E402
from benchmarks.wing_solves import CASES, VARIABLES  # noqa: E402

BAYS = {"bay": 1, "wing3": 3, "wing40": 40}

#: Run in a fresh process: the design with every compilation recorded (JSON on stdout).
PROBE = """
import json, sys, time
sys.path.insert(0, {root!r})
from forward_solver.compilation import enable_fast_compilation
enable_fast_compilation()  # as the command does
import jax.monitoring
events = []
def listen(name, duration, **kwargs):
    if name == "/jax/core/compile/backend_compile_duration":
        events.append((kwargs.get("fun_name", "?"), float(duration)))
jax.monitoring.register_event_duration_secs_listener(listen)
from benchmarks.design_matrix import design
from benchmarks.results import blas_as_in_the_command
start = time.perf_counter()
with blas_as_in_the_command():
    result = design({argv!r})
print(json.dumps({{"seconds": time.perf_counter() - start, "solves": int(result.solves), "events": events}}))
"""


def run(argv: list[str]) -> dict:
    return fresh_process_json(PROBE.format(root=str(ROOT), argv=argv), ROOT)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="bay,wing3,wing40")
    args = parser.parse_args()
    rows = []
    for case in args.cases.split(","):
        out = run([*CASES[case], *VARIABLES])
        names = {name for name, _ in out["events"]}
        rows.append([case, BAYS[case], len(out["events"]), len(names),
                     round(sum(d for _, d in out["events"]), 2), round(out["seconds"], 2), out["solves"]])
    notes = ["fresh process each, no persistent compilation cache and no program store; the XLA fast-compilation "
             "flags on, BLAS on one thread, as in the command"]
    path = save_result("design_programs", title="Programs a design compiles, by bay count (pressure and prestrains)",
                       command=f"PYTHONPATH=. python benchmarks/design_programs.py --cases {args.cases}",
                       columns=["case", "bays", "compilations", "distinct_functions", "compile_s", "design_s",
                                "wing_solves"], rows=rows, notes=notes)
    print_result(path, rows, notes)


if __name__ == "__main__":
    main()
