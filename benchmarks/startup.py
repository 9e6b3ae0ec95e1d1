"""The command's wall time against another checkout of the package, in one run, alternating.

Each run is a fresh ``python -m inverse_design.app.cli --quiet --out DIR``
process with ``PYTHONPATH`` at one checkout (this one, ``--base`` the
other) and its own compilation cache folder (``INFLATABLE_WING_CACHE``), so
the two never share programs. Both checkouts are byte-compiled first.
Cases: the default case with a warm cache (after one run that fills it;
median of ``--repeats`` alternating runs each), the default case without the
cache (``--no-compilation-cache``; ``--cold-repeats`` each), and the 40-cell
wing (``--config inverse_design/cases/wing_40_cells.toml``, ``--wing-repeats``
each; the first with a cache that holds the default case's programs only), and with
``--tolerance-repeats N`` both again with the first-order tolerance analysis
(``--tolerance defaults``), whose ratio to the design's own optimisation time
(``timings_s``: ``tolerance`` over ``optimisation``, median per checkout) is
noted beside the wall times (after one unrecorded run per checkout, which
compiles the analysis's programs into its cache). Writes ``benchmarks/results/startup.json``.

Run:  python -m benchmarks.startup --base /path/to/other/checkout [--repeats 5]

Absolute times depend on the machine and its load (recorded with them);
the ratios are what compare.
"""

from __future__ import annotations

import argparse
import compileall
import datetime
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
WING = "inverse_design/cases/wing_40_cells.toml"


def _run(tree: Path, cache: Path, work: Path, extra: list[str]) -> tuple[float, dict]:
    out = Path(tempfile.mkdtemp(dir=work))
    env = dict(os.environ, PYTHONPATH=str(tree), INFLATABLE_WING_CACHE=str(cache))
    started = time.perf_counter()
    ran = subprocess.run([sys.executable, "-m", "inverse_design.app.cli", "--quiet", "--out", str(out / "o"), *extra],
                         cwd=tree, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - started
    if ran.returncode != 0:
        raise RuntimeError(f"{tree}: exit {ran.returncode}: {ran.stderr[-2000:]}")
    return wall, json.loads((out / "o" / "summary.json").read_text())["timings_s"]


def _alternate(trees: dict, caches: dict, work: Path, extra: list[str], repeats: int) -> tuple[dict, dict, list]:
    """Wall times and summary timings (``timings_s``) per checkout, and the load averages after each run."""
    times, phases, loads = {label: [] for label in trees}, {label: [] for label in trees}, []
    for _ in range(repeats):
        for label, tree in trees.items():
            wall, timings = _run(tree, caches[label], work, extra)
            times[label].append(wall)
            phases[label].append(timings)
            loads.append(os.getloadavg()[0])
            print(label, extra, f"{wall:.2f} s", timings, f"load {loads[-1]:.1f}", flush=True)
    return times, phases, loads


def _phases(timings: list) -> str:
    """Median seconds of the design's phases over runs (summary.json ``timings_s``)."""
    return ", ".join(f"{name} {statistics.median(t[name] for t in timings):.2f}"
                     for name in ("setup", "optimisation", "tolerance", "report") if all(name in t for t in timings))


def _share(timings: list) -> str:
    """Median over runs of the tolerance analysis's seconds over the optimisation's, and the runs'."""
    ratios = [t["tolerance"] / t["optimisation"] for t in timings]
    return f"{statistics.median(ratios):.3f} ({' '.join(f'{r:.3f}' for r in ratios)})"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", required=True, type=Path, help="the other checkout (e.g. a git worktree)")
    parser.add_argument("--new", type=Path, default=ROOT, help="this checkout (default the repository)")
    parser.add_argument("--base-label", default="base")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--cold-repeats", type=int, default=2)
    parser.add_argument("--wing-repeats", type=int, default=1)
    parser.add_argument("--tolerance-repeats", type=int, default=0,
                        help="runs each of the default case and the 40-cell wing with --tolerance defaults")
    parser.add_argument("--name", default="startup", help="the result's name in benchmarks/results")
    args = parser.parse_args(argv)
    trees = {"new": args.new.resolve(), args.base_label: args.base.resolve()}
    for tree in trees.values():
        for package in ("forward_solver", "inverse_design", "targets"):
            compileall.compile_dir(tree / package, quiet=1)
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        caches = {label: work / f"cache-{label}" for label in trees}
        rows, notes = [], []
        # (name, options, runs each, whether one unrecorded run per checkout first fills its cache)
        cases = [("default case, cached", [], args.repeats, False),
                 ("default case, cold (--no-compilation-cache)", ["--no-compilation-cache"], args.cold_repeats, False),
                 ("40-cell wing, its first run with that cache", ["--config", WING], args.wing_repeats, False),
                 ("default case, cached, --tolerance defaults", ["--tolerance", "defaults"], args.tolerance_repeats,
                  True),
                 ("40-cell wing, cached, --tolerance defaults", ["--config", WING, "--tolerance", "defaults"],
                  args.tolerance_repeats, True)]
        for label in trees:  # (fills each cache with the default case's programs)
            _run(trees[label], caches[label], work, [])
        for name, extra, repeats, warm_up in cases:
            if repeats < 1:
                continue
            if warm_up:
                for label in trees:
                    _run(trees[label], caches[label], work, extra)
            times, phases, loads = _alternate(trees, caches, work, extra, repeats)
            new, base = statistics.median(times["new"]), statistics.median(times[args.base_label])
            rows.append([name, repeats, round(new, 2), round(base, 2), round(new / base, 3),
                         " ".join(f"{t:.2f}" for t in times["new"]),
                         " ".join(f"{t:.2f}" for t in times[args.base_label]),
                         f"{min(loads):.1f}-{max(loads):.1f}"])
            notes.append(f"{name}: median phases (summary.json timings_s, s): new {_phases(phases['new'])}; "
                         f"{args.base_label} {_phases(phases[args.base_label])}")
            if "--tolerance" in extra:
                notes.append(f"{name}: the tolerance analysis over the optimisation (timings_s, median): new "
                             f"{_share(phases['new'])}; {args.base_label} {_share(phases[args.base_label])}")
    result = {
        "title": f"Start-up: the command against {args.base_label}, alternating runs",
        "command": f"python -m benchmarks.startup --base {args.base} --base-label {args.base_label} "
                   f"--repeats {args.repeats} --cold-repeats {args.cold_repeats} --wing-repeats {args.wing_repeats}"
                   + (f" --tolerance-repeats {args.tolerance_repeats}" if args.tolerance_repeats else "")
                   + ("" if args.name == "startup" else f" --name {args.name}"),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.python_version()}; load average "
                   f"{load:.1f} at the start, {os.getloadavg()[0]:.1f} at the end",
        "date": datetime.date.today().isoformat(),
        "columns": ["case", "runs each", "new median s", f"{args.base_label} median s", "ratio new/base",
                    "new runs s", f"{args.base_label} runs s", "load average after the runs"],
        "rows": rows,
        "notes": ["each run a fresh process, each checkout with its own compilation cache folder; medians",
                  "a phase is timed from the start of the checkout's cli.main: this checkout imports JAX there "
                  "(setup), an older one may import it with the module, before any phase; the wall times "
                  "are what compare", *notes],
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{args.name}.json").write_text(json.dumps(result, indent=2) + "\n")
    for row in rows:
        print(row)


if __name__ == "__main__":
    main()
