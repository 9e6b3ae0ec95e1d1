"""XLA compilations and compile seconds of the default case and of a first solve, in fresh processes.

Each run is a fresh Python process with a `jax.monitoring` listener on
``/jax/core/compile/backend_compile_duration`` (one event per XLA
compilation, or persistent-cache retrieval, with the compiled function's
name). Runs:

1. ``default``: the default case of the command (``python -m
   inverse_design.app.cli --quiet --out DIR``), (a) without the persistent
   compilation cache (``--no-compilation-cache``), (b) with an empty cache
   (it fills it), (c) with that cache; and (d) as (a) with XLA's default
   CPU emitters (``XLA_FLAGS=--xla_cpu_use_fusion_emitters=true``, which the
   command leaves as the caller set it), for the ratio of
   `forward_solver.compilation.enable_fast_compilation`;
2. ``first_solve``: a notebook's first ``solve_equilibrium`` on the default
   bay (NACA 2412, chord 1 m, ribs 0.25 m apart, default fabric, 1 kPa,
   prestrain 2%) at 17x256, no persistent cache, imports included; then a
   second solve at a new pressure and prestrain (the compilations it adds
   must be none); once as the library does by default and once after
   ``forward_solver.compilation.enable_fast_compilation()``;
3. ``resolve``: for the ratio of item 3, one process: the default bay
   (17x64) at the default case's start (10 kPa, prestrain 2%), re-solved
   (method "auto") warm-started from its equilibrium after a 1% change of
   the pressure, the chord prestrain or the rib thickness scale, against a
   cold solve of the same change: steps and wall time (medians of 15,
   alternating, after a warm-up that compiles both paths), the largest node
   difference, and the compilations a warm re-solve adds (none).

Before the runs the package's sources are byte-compiled (``compileall``, as
``pip install .`` does when it installs them), so that no run spends time
compiling the package's Python source: an environment with
``PYTHONDONTWRITEBYTECODE=1`` (the development container has it) otherwise
recompiles every module in every run, 0.1-0.2 s of the cached default case;
``--no-bytecode`` leaves that to the environment.

Prints a table (wall time, compilations, compile seconds, the top compile
consumers) and writes ``benchmarks/results/compilation.json``.

Run:  python -m benchmarks.compilation [--skip-default] [--top N]

Absolute times depend on the machine and its load: quote them with it.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"

#: Prepended to every child: the listener, and a JSON dump of what it saw at exit.
_LISTENER = r"""
import atexit, json, time, collections
import jax.monitoring as _monitoring
_EVENTS = []
_T0 = time.perf_counter()
import os as _os, sys as _sys
_ROOT = _os.getcwd() + _os.sep
def _site():
    # the innermost frame of the repository (not this listener) that led to the compilation
    frame = _sys._getframe(2)
    while frame is not None:
        name = frame.f_code.co_filename
        if name.startswith(_ROOT) and "site-packages" not in name:
            return f"{name[len(_ROOT):]}:{frame.f_lineno} ({frame.f_code.co_name})"
        frame = frame.f_back
    return "?"
def _listen(event, duration, **kwargs):
    if event == "/jax/core/compile/backend_compile_duration":
        _EVENTS.append((kwargs.get("fun_name", "?"), float(duration), time.perf_counter() - _T0, _site()))
_monitoring.register_event_duration_secs_listener(_listen)
def _dump():
    with open(__REPORT__, "w") as f:
        json.dump({"events": _EVENTS, "marks": _MARKS}, f)
_MARKS = {}
atexit.register(_dump)
"""

_FIRST_SOLVE = r"""
_MARKS["imports_start"] = time.perf_counter() - _T0
if __FAST__:
    from forward_solver.compilation import enable_fast_compilation
    enable_fast_compilation()
from forward_solver import Bay, Fabric, Parameters, Scene, solve_equilibrium
from targets import naca
_MARKS["imported"] = time.perf_counter() - _T0
scene = Scene(Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=__NS__, n_contour=__NC__), Fabric())
sol = solve_equilibrium(scene, Parameters(pressure=1e3, prestrain_span=0.02, prestrain_chord=0.02))
_MARKS["first_solve"] = time.perf_counter() - _T0
_MARKS["first_steps"] = int(sol.steps)
_MARKS["compiles_after_first"] = len(_EVENTS)
sol2 = solve_equilibrium(scene, Parameters(pressure=1.3e3, prestrain_span=0.021, prestrain_chord=0.019))
_MARKS["second_solve"] = time.perf_counter() - _T0
_MARKS["compiles_after_second"] = len(_EVENTS)
"""

_RESOLVE = r"""
from forward_solver import Bay, Fabric, Parameters, Scene, solve_equilibrium
from targets import naca
scene = Scene(Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=__NS__, n_contour=__NC__), Fabric())
base = Parameters(pressure=1e4, prestrain_span=0.02, prestrain_chord=0.02)  # the default case's start
changes = {"pressure +1%": base.replace(pressure=1.01e4),
           "prestrain_chord +1%": base.replace(prestrain_chord=0.0202),
           "rib_thickness -1%": base.replace(rib_thickness_scale=0.99)}
# warm-up: compile every program both paths use (same shapes), then time
w = solve_equilibrium(scene, base, method="auto", rtol=1e-8)
for p in changes.values():
    solve_equilibrium(scene, p, method="auto", rtol=1e-8, initial=w)
    solve_equilibrium(scene, p, method="auto", rtol=1e-8)
import numpy as np
rows = []
for name, p in changes.items():
    cold_t, warm_t = [], []
    for _ in range(__REPEATS__):  # alternating, medians: the machine is shared
        t = time.perf_counter(); cold = solve_equilibrium(scene, p, method="auto", rtol=1e-8); cold_t.append(time.perf_counter() - t)
        c0 = solve_equilibrium(scene, base, method="auto", rtol=1e-8)
        n0 = len(_EVENTS)
        t = time.perf_counter(); warm = solve_equilibrium(scene, p, method="auto", rtol=1e-8, initial=c0); warm_t.append(time.perf_counter() - t)
    rows.append(dict(change=name, cold_s=float(np.median(cold_t)), cold_steps=int(cold.steps),
                     cold_method=cold.method, warm_s=float(np.median(warm_t)), warm_steps=int(warm.steps),
                     warm_how=warm.extra.get("warm_start", warm.method),
                     newton_iterations=warm.extra.get("newton_iterations"),
                     max_node_difference_m=float(np.max(np.abs(np.asarray(warm.nodes) - np.asarray(cold.nodes)))),
                     new_compilations=len(_EVENTS) - n0))
_MARKS["resolve"] = rows
"""


def _child(code: str, report: Path, argv: list[str] | None = None, env=None) -> tuple[float, dict, str]:
    """Run ``code`` (after the listener) in a fresh interpreter; wall time, the report, stderr."""
    source = _LISTENER.replace("__REPORT__", repr(str(report))) + code
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", source, *(argv or [])], cwd=ROOT, env=env,
                          capture_output=True, text=True)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"child failed ({done.returncode}): {done.stderr[-3000:]}")
    return wall, json.loads(report.read_text()), done.stderr


def _summary(label: str, wall: float, report: dict, top: int) -> dict:
    by_name: dict[str, list] = {}
    for name, seconds, *_ in report["events"]:
        entry = by_name.setdefault(name, [0, 0.0])
        entry[0] += 1
        entry[1] += seconds
    ranked = sorted(by_name.items(), key=lambda kv: -kv[1][1])
    sites: dict[str, list] = {}
    for name, seconds, _, site in report["events"]:
        entry = sites.setdefault(f"{name} <- {site}", [0, 0.0])
        entry[0] += 1
        entry[1] += seconds
    return {"run": label, "wall_s": wall, "compilations": len(report["events"]),
            "compile_s": sum(e[1] for e in report["events"]), "distinct_functions": len(by_name),
            "top": [{"function": n, "count": c, "seconds": s} for n, (c, s) in ranked[:top]],
            "sites": [{"site": n, "count": c, "seconds": s}
                      for n, (c, s) in sorted(sites.items(), key=lambda kv: -kv[1][1])],
            "marks": report["marks"]}


def default_case_runs(tmp: Path, top: int, repeats: int = 3) -> list[dict]:
    env = dict(os.environ, INFLATABLE_WING_CACHE=str(tmp / "cache"))
    # as the console script: the command's work, then the process ends without the interpreter's
    # teardown or the exit functions (`cli.command`), so the listener's report is written first
    code = "from inverse_design.app import cli\ncode = cli.main()\n_dump()\ncli._exit_now(code)\n"
    # (every file written in the command's process: no report workers)
    serial = code.replace("code = cli.main()", "cli.ReportWorkers = type('NoWorkers', (), {'start': staticmethod("
                                               "lambda *a, **k: None)})\ncode = cli.main()")
    rows = []
    default_emitters = dict(env, XLA_FLAGS="--xla_cpu_use_fusion_emitters=true")
    # The cached variants alternate, `repeats` times each, for ratios taken in one run: with the
    # report's workers (as the command runs), and with every file written in the command's process.
    cached = [("default, cached", [], env, code), ("default, cached, figures saved serially", [], env, serial)] * repeats
    for label, extra, run_env, run_code in [("default, no cache", ["--no-compilation-cache"], env, code),
                                            ("default, empty cache", [], env, code), *cached,
                                            ("default, no cache, XLA's default emitters", ["--no-compilation-cache"],
                                             default_emitters, code)]:
        out = tmp / f"out-{len(rows)}"
        wall, report, _ = _child(run_code, tmp / f"report-{len(rows)}.json", ["--quiet", "--out", str(out), *extra],
                                 run_env)
        row = _summary(label, wall, report, top)
        summary = json.loads((out / "summary.json").read_text())
        results = summary["results"]
        row["summary"] = {"success": results["success"], "forward_solves": results["forward_solves"],
                          "pressure_pa": results["values"]["pressure_pa"], "rms": summary["errors"]["after"]["rms"],
                          "timings_s": {k: round(v, 2) for k, v in summary["timings_s"].items()}}
        rows.append(row)
    return rows


def cached_medians(runs: list[dict]) -> dict:
    """Median wall time of each cached variant of the default case, and its ratio to the first
    ("default, cached": the command as it runs)."""
    walls: dict = {}
    for run in runs:
        if run["run"].startswith("default, cached"):
            walls.setdefault(run["run"], []).append(round(run["wall_s"], 2))
    medians = {label: float(np.median(w)) for label, w in walls.items()}
    base = medians.get("default, cached")
    return {label: {"wall_s": m, "walls_s": walls[label], "ratio": m / base if base else float("nan")}
            for label, m in medians.items()}


def first_solve_run(tmp: Path, top: int, shape=(17, 256), fast: bool = False) -> dict:
    code = (_FIRST_SOLVE.replace("__NS__", str(shape[0])).replace("__NC__", str(shape[1]))
            .replace("__FAST__", str(fast)))
    env = dict(os.environ, JAX_ENABLE_COMPILATION_CACHE="false")
    env.pop("XLA_FLAGS", None)
    wall, report, _ = _child(code, tmp / f"report-first-{fast}.json", env=env)
    label = "after enable_fast_compilation()" if fast else "the library's default"
    return _summary(f"first solve {shape[0]}x{shape[1]}, {label}", wall, report, top)


def resolve_run(tmp: Path, shape=(17, 64), repeats: int = 15) -> dict:
    code = (_RESOLVE.replace("__NS__", str(shape[0])).replace("__NC__", str(shape[1]))
            .replace("__REPEATS__", str(repeats)))
    env = dict(os.environ, JAX_ENABLE_COMPILATION_CACHE="false")
    wall, report, _ = _child(code, tmp / "report-resolve.json", env=env)
    return {"run": f"re-solve {shape[0]}x{shape[1]}", "wall_s": wall, "rows": report["marks"]["resolve"]}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-default", action="store_true", help="skip the default case runs")
    parser.add_argument("--skip-first", action="store_true", help="skip the first 17x256 solve")
    parser.add_argument("--skip-resolve", action="store_true", help="skip the warm re-solve ratios")
    parser.add_argument("--top", type=int, default=12, help="compile consumers listed per run")
    parser.add_argument("--no-bytecode", action="store_true",
                        help="do not byte-compile the package's sources first (module docstring)")
    parser.add_argument("--repeats", type=int, default=3,
                        help="runs of each cached variant of the default case, alternating (medians printed)")
    args = parser.parse_args(argv)
    load = os.getloadavg()
    machine = f"{platform.machine()} {platform.processor() or ''} {os.cpu_count()} cores, load {load[0]:.1f}"
    print(f"machine: {machine}; python {platform.python_version()}")
    if not args.no_bytecode:
        import compileall

        for package in ("forward_solver", "inverse_design", "targets"):
            compileall.compile_dir(str(ROOT / package), quiet=1)
    print(f"package byte-compiled first: {not args.no_bytecode}; PYTHONDONTWRITEBYTECODE="
          f"{os.environ.get('PYTHONDONTWRITEBYTECODE', '')!r}")
    runs = []
    with tempfile.TemporaryDirectory() as name:
        tmp = Path(name)
        if not args.skip_default:
            runs += default_case_runs(tmp, args.top, args.repeats)
        if not args.skip_first:
            runs += [first_solve_run(tmp, args.top), first_solve_run(tmp, args.top, fast=True)]
        if not args.skip_resolve:
            runs.append(resolve_run(tmp))
    for run in runs:
        if "rows" in run:
            print(f"\n{run['run']} (process {run['wall_s']:.1f} s)")
            for r in run["rows"]:
                print(f"  {r['change']:<22} cold {r['cold_steps']:6d} steps {r['cold_s']:6.3f} s | warm "
                      f"{r['warm_steps']:4d} steps {r['warm_s']:6.3f} s ({r['warm_how']}) | ratio steps "
                      f"{r['warm_steps'] / max(r['cold_steps'], 1):.3f} time {r['warm_s'] / r['cold_s']:.3f} | "
                      f"max |x_warm - x_cold| {r['max_node_difference_m']:.1e} m | new compilations "
                      f"{r['new_compilations']}")
            continue
        print(f"\n{run['run']}: wall {run['wall_s']:.1f} s, {run['compilations']} compilations "
              f"({run['distinct_functions']} functions), {run['compile_s']:.1f} s compiling")
        if run.get("summary"):
            print(f"  summary: {run['summary']}")
        marks = {k: (round(v, 2) if isinstance(v, float) else v) for k, v in run["marks"].items()}
        if marks:
            print(f"  marks: {marks}")
        for t in run["top"]:
            print(f"    {t['seconds']:6.2f} s  {t['count']:3d}x  {t['function']}")
    medians = cached_medians(runs)
    for label, entry in medians.items():
        print(f"\n{label}: median wall {entry['wall_s']:.2f} s of {entry['walls_s']}, "
              f"ratio to the command as it runs {entry['ratio']:.2f}")
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / "compilation.json"
    path.write_text(json.dumps({"machine": machine, "date": time.strftime("%Y-%m-%d"),
                                "byte_compiled": not args.no_bytecode, "runs": runs,
                                "cached_medians": medians}, indent=1))
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
