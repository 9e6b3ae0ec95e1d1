"""The optimise-pressure command: the output folder, case files, exit codes and messages.

The command runs in a subprocess, as a user runs it. JAX compilation
dominates, so one run of the default case (on a small grid) serves every
check of the output folder, and the runs share a JAX persistent compilation
cache (a temporary folder of this module), so later runs reuse the compiled
solvers of earlier ones (about a third of the compute of a fresh run).
"""

import gc
import json
import os
import shutil
import signal
import struct
import subprocess
import sys
import time
from importlib.metadata import version
from pathlib import Path

import numpy as np
import pytest

from inverse_design.app import cli, interrupts, output_folder, resources, run
from inverse_design.app.case import Case
from support.cases import SMALL
from support.command import environment, launch
from support.reports import earlier_report

ROOT = Path(__file__).resolve().parents[2]
FOLDER = {"summary.json", "wing.npz", "equilibrium.npz", "skin.obj", "skin.stl", "bay_0_cut_pattern.csv",
          "wing_overview.png", "bay_0_mid_bay_section.png", "deviation.png", "tensions.png", "history.png",
          "rib_0.dxf", "rib_1.dxf",
          *(f"pattern_bay_0_{panel}.{kind}" for panel in ("upper", "lower") for kind in ("dxf", "svg"))}


@pytest.fixture(scope="module")
def cli_env(tmp_path_factory):
    """The environment of the command's subprocesses (`support.command.environment`: the code under test
    whether or not, and however, the package is installed), with a JAX cache of this module's."""
    cache = tmp_path_factory.mktemp("jax-cache")
    return environment(JAX_COMPILATION_CACHE_DIR=str(cache), JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0",
                       JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="0")


@pytest.fixture(scope="module")
def run_cli(cli_env):
    """Run the command in a subprocess (`support.command`: its report written serially):
    ``run_cli(*args, cwd=folder)``."""

    def run(*args, cwd, timeout=600):
        return subprocess.run(launch(*args), cwd=cwd, env=cli_env, capture_output=True, text=True, timeout=timeout)

    return run


@pytest.fixture(scope="module")
def start_cli(cli_env):
    """Start the command in a subprocess and return at once: ``start_cli(*args, cwd=folder)``."""

    def start(*args, cwd):
        return subprocess.Popen(launch(*args), cwd=cwd, env=cli_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)

    return start


def _leftovers(folder: Path):
    """Hidden staging or backup folders a run might leave next to its output."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def _main_in(folder: Path, monkeypatch, capsys, *args):
    """`cli.main` on ``args`` in ``folder``, in this process: its exit code and output as a finished
    subprocess's (``returncode``, ``stdout``, ``stderr``)."""
    monkeypatch.chdir(folder)
    code = cli.main(list(args))
    captured = capsys.readouterr()
    return subprocess.CompletedProcess(args, code, captured.out, captured.err)


def _one_line_error(done, *fragments):
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("optimise-pressure: error:")
    for fragment in fragments:
        assert fragment in lines[0]
    assert "Traceback" not in done.stderr and done.stdout == ""


# ------------------------------------------------------------------ the default case
@pytest.fixture(scope="module")
def default_run(tmp_path_factory, run_cli):
    base = tmp_path_factory.mktemp("default")
    done = run_cli(*SMALL, "--out", "out", cwd=base)
    assert done.returncode == 0, done.stderr
    out = base / "out"
    return base, out, done, json.loads((out / "summary.json").read_text())


def test_the_default_case_writes_a_complete_folder_and_says_where(default_run):
    base, out, done, summary = default_run
    assert {p.name for p in out.iterdir()} == FOLDER
    assert set(summary["files"]) == FOLDER and summary["skipped"] == {}
    assert _leftovers(base) == []
    assert done.stdout.strip().splitlines()[-1].startswith(f"wrote {out.resolve()}")
    # stderr is not a terminal: no progress bar (only the warning of the small test grid)
    assert [line for line in done.stderr.splitlines() if "span nodes, fewer than" not in line] == []


def test_the_summary_holds_inputs_results_errors_constraints_timings_version(default_run):
    *_, summary = default_run
    assert summary["package"] == {"name": "inflatable-wing", "version": version("inflatable-wing")}
    inputs = summary["inputs"]
    assert inputs["target"] == "naca2412" and inputs["rib"] is None and inputs["config"] is None
    assert (inputs["n_span"], inputs["n_contour"]) == (5, 32)
    assert inputs["sources"] == {"n_span": "command line", "n_contour": "command line",
                                 "out": "command line"}
    assert summary["case"]["grid"] == [5, 32] and summary["mode"] == "optimise"
    # One layout for a bay and a wing: the bay axis has this bay's one entry.
    assert summary["schema"] == 3 and summary["case"]["n_bays"] == 1
    assert [(r["target"], r["chord_m"], r["station_m"]) for r in summary["case"]["ribs"]] == [
        ("NACA 2412", 1.0, 0.0), ("NACA 2412", 1.0, 0.25)]
    (bay,) = summary["bays"]
    assert bay["errors_after"]["rms"] == pytest.approx(summary["errors"]["after"]["rms"], rel=1e-12)
    assert bay["errors_before"]["rms"] == pytest.approx(summary["errors"]["before"]["rms"], rel=1e-12)
    assert bay["result"] == "converged" and bay["span_m"] == [0.0, pytest.approx(0.25)]
    results = summary["results"]
    assert results["success"] is True and results["message"]
    assert results["variables"] == ["pressure", "rib_thickness_scale"]
    values = results["values"]
    assert 1e3 <= values["pressure_pa"] <= 1e5 and 0.7 <= values["rib_thickness_scale"] <= 1.0
    assert values["prestrain_span"] == values["prestrain_chord"] == 0.02
    assert results["equilibrium"]["result"] == "converged" and results["equilibrium"]["steps"] > 0
    assert results["equilibrium"]["relative_residual"] < 1e-6
    assert results["iterations"] == len(summary["history"]) > 0
    errors = summary["errors"]
    assert errors["objective"] == "average" and errors["unit"] == "fraction of the local chord"
    # The optimiser must improve on its start; max >= rms by definition.
    assert 0 < errors["after"]["rms"] < errors["before"]["rms"]
    assert errors["after"]["max"] >= errors["after"]["rms"]
    constraints = summary["constraints"]
    assert isinstance(constraints["active"], list)
    assert constraints["values"]["min_tension_floor"] == 0.0
    assert constraints["values"]["max_tension"] > constraints["values"]["min_tension"]
    assert constraints["violated_at_start"] == {}  # the default start is taut
    # the default case lies inside the validated ranges (the small test grid is below the design's 17 span nodes)
    assert [w for w in summary["warnings"] if "span nodes, fewer than" not in w] == []
    timings = summary["timings_s"]
    assert {"setup", "optimisation", "report", "total"} <= set(timings)
    assert timings["total"] >= timings["optimisation"] + timings["report"] > 0


def test_a_start_that_broke_a_limit_is_said_on_the_console():
    # The numbers of `--target e387.dat` (17x64): the start wrinkled, the feasible design's error
    # is larger; without the line a worse design read as a plain success.
    from inverse_design.app.console import start_violation_line

    summary = {"case": {"n_bays": 1}, "constraints": {"violated": {}, "violated_at_start": {"min_tension": 624.6}},
               "errors": {"before": {"rms": 6.807e-3}, "after": {"rms": 9.115e-3}}}
    assert start_violation_line(summary) == (
        "  note: the start broke min_tension by 624.6 N/m; the design is feasible but its error is larger "
        "than the infeasible start's (9.115e-03 against 6.807e-03 chord)")
    summary["errors"]["after"]["rms"] = 5e-3
    assert start_violation_line(summary).endswith("; the design is feasible")
    wing = {"case": {"n_bays": 3, "ribs": [{}] * 4},
            "constraints": {"violated": {"max_tension": 2.0}, "violated_at_start": {"max_tension": 10.0},
                            "violated_at_start_where": {"max_tension": {"bay 0": 10.0, "bay 2": 5.0}}},
            "errors": {"before": {"rms": 1e-2}, "after": {"rms": 2e-2}}}
    assert start_violation_line(wing) == ("  note: the start broke max_tension by 10 N/m in bay 0, by 5 N/m "
                                          "in bay 2; the design still breaks a limit (above)")
    summary["constraints"]["violated_at_start"] = {}
    assert start_violation_line(summary) is None


def test_the_npz_holds_the_equilibrium_and_its_parameters(default_run):
    _, out, _, summary = default_run
    with np.load(out / "equilibrium.npz") as data:
        assert data["nodes"].shape == (5, 32, 3)
        assert data["tension_span"].shape == data["tension_chord"].shape == data["wrinkled"].shape == (4, 32)
        assert data["wrinkled"].dtype == bool and data["deviation"].shape == (5, 32)
        assert data["target_xz"].shape[1] == 2 and data["mid_bay_section"].shape == (32, 2)
        assert float(data["pressure"]) == pytest.approx(summary["results"]["values"]["pressure_pa"], rel=1e-12)
        assert list(data["variables"]) == ["pressure", "rib_thickness_scale"]
        assert data["history_values"].shape == (len(summary["history"]), 2)
        # The ribs hold the skin: rib rows lie in the planes y = 0 and y = rib spacing.
        assert np.allclose(data["nodes"][0, :, 1], 0.0) and np.allclose(data["nodes"][-1, :, 1], 0.25)


def test_the_obj_and_stl_meshes_match_the_grid_and_point_outwards(default_run):
    _, out, _, _ = default_run
    with np.load(out / "equilibrium.npz") as data:
        nodes = data["nodes"]
    lines = (out / "skin.obj").read_text().splitlines()
    assert any(line.startswith("#") and "metres" in line for line in lines)
    vertices = np.array([[float(v) for v in line.split()[1:]] for line in lines if line.startswith("v ")])
    faces = np.array([[int(v) for v in line.split()[1:]] for line in lines if line.startswith("f ")])
    assert vertices.shape == (5 * 32, 3) and faces.shape == (4 * 32, 4)  # periodic contour: 32 cells a row
    assert faces.min() == 1 and faces.max() == 5 * 32
    np.testing.assert_allclose(vertices, nodes.reshape(-1, 3), atol=1e-8)

    raw = (out / "skin.stl").read_bytes()
    (count,) = struct.unpack("<I", raw[80:84])
    assert count == 2 * 4 * 32 and len(raw) == 84 + 50 * count
    record = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    tri = np.frombuffer(raw[84:], dtype=record)
    corners = tri["corners"].astype(np.float64)
    area_vectors = 0.5 * np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    centroids = corners.mean(axis=1)
    # Divergence theorem over the open tube (its ends face +-y, so x and z see no ends):
    # with outward normals the enclosed volume is positive and about the section area (NACA 2412:
    # 0.0822 chord^2, Report 824) times the rib spacing; 10% covers the bulge and the coarse grid.
    volume = 0.5 * np.sum(centroids[:, 0] * area_vectors[:, 0] + centroids[:, 2] * area_vectors[:, 2])
    assert volume == pytest.approx(0.0822 * 0.25, rel=0.1)


def test_every_png_is_an_image(default_run):
    _, out, _, _ = default_run
    for name in FOLDER:
        if name.endswith(".png"):
            data = (out / name).read_bytes()
            assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000, name


_COUNTED = r"""
import json, sys
from inverse_design.app import cli, workers as report_workers

saved = []
finish = report_workers.ReportWorkers.finish
report_workers.ReportWorkers.finish = lambda self, *a, **k: saved.append(sorted(finish(self, *a, **k))) or set(saved[-1])
code = cli.main(sys.argv[1:])
print(json.dumps({"code": code, "saved": saved}))
"""


def test_the_report_workers_write_the_files_a_serial_report_writes(default_run, cli_env):
    """The command's report workers (started before the design) and the command's process between them
    save every figure and DXF and SVG pattern of a single bay's report, byte for byte as the report
    writes them in one process (the default run's, `support.command`; ``--quiet`` changes only stdout)."""
    base, out, _, _ = default_run
    counted = subprocess.run([sys.executable, "-c", _COUNTED, *SMALL, "--quiet", "--out", "counted"], cwd=base,
                             env=cli_env, capture_output=True, text=True, timeout=600)
    assert counted.returncode == 0, counted.stderr
    ran = json.loads(counted.stdout.strip().splitlines()[-1])
    if report_workers_possible():  # five figures, two panels' DXF and SVG (a task each), two ribs' DXF: all done
        assert ran["saved"] == [list(range(9))]
    for name in sorted(n for n in FOLDER if n.endswith((".png", ".svg"))):
        assert (base / "counted" / name).read_bytes() == (out / name).read_bytes(), name
    for name in sorted(n for n in FOLDER if n.endswith(".dxf")):  # (the header dates each file: the drawing)
        assert _dxf_entities(base / "counted" / name) == _dxf_entities(out / name), name



def test_without_figures_the_report_workers_write_the_patterns(default_run, cli_env):
    """With ``--no-figures`` the workers, started for the patterns alone, take them as they take the figures:
    the same DXF and SVG drawings as the serial report's, and no figure."""
    base, out, _, _ = default_run
    counted = subprocess.run([sys.executable, "-c", _COUNTED, *SMALL, "--no-figures", "--quiet", "--out", "drawings"],
                             cwd=base, env=cli_env, capture_output=True, text=True, timeout=600)
    assert counted.returncode == 0, counted.stderr
    ran = json.loads(counted.stdout.strip().splitlines()[-1])
    if report_workers_possible():  # two panels' DXF and SVG (a task each), two ribs' DXF: all done
        assert ran["saved"] == [list(range(4))]
    assert not list((base / "drawings").glob("*.png"))
    for name in sorted(n for n in FOLDER if n.endswith(".svg")):
        assert (base / "drawings" / name).read_bytes() == (out / name).read_bytes(), name
    for name in sorted(n for n in FOLDER if n.endswith(".dxf")):
        assert _dxf_entities(base / "drawings" / name) == _dxf_entities(out / name), name

def test_the_command_keeps_the_solvers_top_level_programs_beside_its_cache(default_run, cli_env):
    """A run leaves its relaxation, Newton and static-state programs exported in the cache's
    ``programs`` folder (docs/compilation.md); a later run (the one above) loads them, and draws the same
    figures to the byte."""
    cache = Path(cli_env.get("INFLATABLE_WING_CACHE") or cli_env["JAX_COMPILATION_CACHE_DIR"])
    names = {path.name.split("-")[0] for path in (cache / "programs").glob("*.bin")}
    assert {"relax_jit", "static_state", "_jacobian_values", "prepare", "mounted_nodes"} <= names


def _dxf_entities(path) -> str:
    """The ENTITIES section of a DXF file (what is drawn, without the header's dates and GUIDs)."""
    text = path.read_text()
    start = text.index("ENTITIES")
    return text[start:text.index("ENDSEC", start)]


def report_workers_possible() -> bool:
    """Whether the command starts report workers here (two cores or more)."""
    from inverse_design.app import workers as report_workers

    return report_workers._cores() > 1


# ------------------------------------------------------------------ case files
def test_a_case_file_is_read_and_the_command_line_overrides_it(run_cli, tmp_path):
    (tmp_path / "case.toml").write_text(
        'evaluate = true\ntarget = "naca0012"\nn-span = 5\nn_contour = 24\npressure = 2e4\n'
        'prestrain-bounds = [0.0, 0.04]\njson = true\n')
    done = run_cli("--config", "case.toml", "--n-contour", "32", "--out", "out", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)  # --json (from the file): stdout is the summary alone
    assert summary == json.loads((tmp_path / "out" / "summary.json").read_text())
    inputs = summary["inputs"]
    assert inputs["config"] == "case.toml" and inputs["target"] == "naca0012"
    assert (inputs["n_span"], inputs["n_contour"], inputs["pressure"]) == (5, 32, 2e4)
    assert inputs["prestrain_bounds"] == [0.0, 0.04]
    assert inputs["sources"]["n_contour"] == "command line" and inputs["sources"]["n_span"] == "config"
    assert summary["mode"] == "evaluate" and summary["case"]["grid"] == [5, 32]
    assert summary["results"]["equilibrium"]["result"] == "converged"
    assert summary["errors"]["before"] is None and summary["errors"]["after"]["rms"] > 0
    # A single equilibrium has no optimiser history: the plot is skipped and the summary says why.
    assert "history.png" in summary["skipped"] and not (tmp_path / "out" / "history.png").exists()


def test_inputs_outside_the_validated_ranges_warn_on_stderr_and_in_the_summary(run_cli, tmp_path):
    done = run_cli(*SMALL, "--evaluate", "--no-figures", "--prestrain-chord", "0.08", "--rib-spacing", "0.6", "--out", "out",
                   cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 3 and all(line.startswith("optimise-pressure: warning: ") for line in lines)
    assert "prestrain chord 0.08 (8%) lies outside the range the model is validated for (-2% to 5%)" in lines[0]
    assert "rib spacing 0.6 m lies outside" in lines[1] and "rib spacing / chord 0.6 lies outside" in lines[2]
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["warnings"] == [line.removeprefix("optimise-pressure: warning: ") for line in lines]


def test_case_file_values_are_checked_like_options(tmp_path):
    case = tmp_path / "case.toml"
    case.write_text('variables = ["pressure", "prestrain_span"]\npressure-bounds = [2e3, 5e4]\n'
                    'no_tension_constraints = true\nmax-iterations = 7\n')
    read = Case.from_arguments(["--config", str(case), "--max-iterations", "9"])
    options, sources = read.options, read.sources
    assert options.variables == "pressure,prestrain_span" and options.pressure_bounds == (2e3, 5e4)
    assert read.variables == ("pressure", "prestrain_span")
    assert options.no_tension_constraints is True and options.max_iterations == 9
    assert sources["max_iterations"] == "command line" and sources["pressure_bounds"] == "config"
    for text, fragment in [("n-span = 9.5\n", "n-span"), ("chord = -1\n", "chord"),
                           ("pressure-bounds = 5\n", "pressure-bounds"), ("quiet = 1\n", "quiet"),
                           ('method = "newton"\n', "method")]:
        case.write_text(text)
        with pytest.raises(cli.InputError, match=fragment):
            Case.from_arguments(["--config", str(case)])


@pytest.mark.parametrize(
    "text, message",
    [
        ("n-spam = 5\n", "unknown key 'n-spam'"),
        ("n-span = 'nine'\n", "n-span"),
        ("chord = [1\n", "not valid TOML"),
    ],
)
def test_a_bad_case_file_exits_2_with_one_line(tmp_path, monkeypatch, capsys, text, message):
    (tmp_path / "case.toml").write_text(text)
    _one_line_error(_main_in(tmp_path, monkeypatch, capsys, "--config", "case.toml", "--out", "out"),
                    "case.toml", message)
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------ bad input and failures
@pytest.mark.parametrize(
    "args, message",
    [
        (["--target", "naca24x12"], "NACA"),
        (["--target", "missing.dat"], "missing.dat"),
        (["--rib", "garbled.dat"], "garbled.dat"),
        (["--chord", "-1"], "chord"),
        (["--pressure", "-5"], "pressure"),
        (["--pressure", "abc"], "pressure"),
        (["--pressure-bounds", "1e5", "1e3"], "pressure"),
        (["--n-span", "2"], "argument --n-span: must be 3 or more"),
        (["--variables", "pressure,thickness"], "thickness"),
        (["--config", "absent.toml"], "absent.toml"),
        (["--target", "."], "--target: . is a directory; give a NACA code such as naca2412 or a .dat file"),
        (["--rib", ".."], "--rib: .. is a directory"),
        (["--variables", "pressure,rib_shape", "--rib-shape-terms", "0"], "argument --rib-shape-terms: must be 1 or more"),
        (["--variables", "pressure,rib_shape", "--min-rib-thickness", "1.5"], "--min-rib-thickness"),
        (["--variables", "pressure,rib_shape", "--rib-shape-bounds", "0.01", "0.05"], "outside its bounds"),
    ],
)
def test_bad_input_exits_2_with_one_line(tmp_path, monkeypatch, capsys, args, message):
    (tmp_path / "garbled.dat").write_text("not an airfoil\n1 2 3\n")
    _one_line_error(_main_in(tmp_path, monkeypatch, capsys, *args, "--out", "out"), message)
    assert not (tmp_path / "out").exists() and _leftovers(tmp_path) == []


def test_bad_input_exits_2_with_one_line_from_a_fresh_process(run_cli, tmp_path):
    """The cases above run `cli.main` in this process (a fresh interpreter each costs seconds); one
    runs as a user runs it: nothing else reaches stderr or stdout on the way (imports, JAX's start)."""
    (tmp_path / "case.toml").write_text("n-spam = 5\n")
    _one_line_error(run_cli("--config", "case.toml", "--out", "out", cwd=tmp_path), "case.toml", "unknown key 'n-spam'")
    _one_line_error(run_cli("--pressure", "-5", "--out", "out", cwd=tmp_path), "pressure")
    assert not (tmp_path / "out").exists() and _leftovers(tmp_path) == []


def test_bad_input_and_help_answer_without_importing_jax(tmp_path):
    """The options are read before JAX is imported (`cli.main`): a refusal or ``--help`` waits for
    no import of JAX, SciPy's solvers or the solver."""
    code = ("import contextlib, io, sys\nfrom inverse_design.app import cli\n"
            "with contextlib.redirect_stderr(io.StringIO()):\n"
            "    refused = cli.main(['--pressure', '-5', '--out', 'out'])\n"
            "    try:\n"
            "        with contextlib.redirect_stdout(io.StringIO()):\n"
            "            cli.main(['--help'])\n"
            "    except SystemExit as exit:\n"
            "        helped = exit.code\n"
            "print(refused, helped, sorted(m for m in ('jax', 'forward_solver') if m in sys.modules))")
    ran = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                         capture_output=True, text=True, timeout=120)
    assert ran.returncode == 0, ran.stderr
    assert ran.stdout.strip() == "2 0 []"


def test_the_run_has_blas_on_one_thread_in_a_fresh_process(tmp_path):
    """Every BLAS the run uses (NumPy's, SciPy's) runs on one thread (module docstring of `cli`): the
    limit is taken once they are loaded, which a fresh process does after reading the options."""
    code = ("import sys, threadpoolctl\nfrom inverse_design.app import cli, run as command_run\n"
            "from inverse_design.app.options import InputError\n"
            "from support.command import NoWorkers\n"
            "seen = []\n"
            "def run(*args, **kwargs):\n"
            "    seen.extend(i['num_threads'] for i in threadpoolctl.threadpool_info() if i['user_api'] == 'blas')\n"
            "    raise InputError('enough')\n"
            "command_run.run_case, cli.ReportWorkers = run, NoWorkers\n"
            "print(cli.main(['--out', 'out', '--quiet']), seen)")
    env = environment()
    ran = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=300)
    assert ran.returncode == 0, ran.stderr
    code, threads = ran.stdout.strip().split(" ", 1)
    assert code == "2" and threads.startswith("[1") and set(eval(threads)) == {1}, ran.stdout


def test_a_file_of_a_report_name_that_no_report_wrote_is_never_overwritten(run_cli, tmp_path):
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "thesis.tex").write_text("precious")
    (tmp_path / "notes" / "skin.stl").write_bytes(b"my own mesh")  # a report's name, not a report's file
    done = run_cli("--out", "notes", cwd=tmp_path)
    _one_line_error(done, "notes", "skin.stl", "summary.json")
    assert (tmp_path / "notes" / "thesis.tex").read_text() == "precious"
    assert (tmp_path / "notes" / "skin.stl").read_bytes() == b"my own mesh"
    assert sorted(p.name for p in (tmp_path / "notes").iterdir()) == ["skin.stl", "thesis.tex"]


def _snapshot(folder: Path) -> dict:
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}


def test_out_dot_writes_beside_the_users_files_and_replaces_only_its_own(run_cli, tmp_path):
    # Once, --out . in a folder holding the case file, an airfoil and an earlier summary.json
    # deleted the case file and the airfoil (the folder was replaced whole).
    foreign = {"case.toml": b"n-span = 5\nn-contour = 32\n", "clarky.dat": bytes(range(256)),
               "notes.txt": b"keep me\n"}
    for name, data in foreign.items():
        (tmp_path / name).write_bytes(data)
    (tmp_path / "results").mkdir()  # a folder of the user's
    (tmp_path / "results" / "a.csv").write_text("1,2\n")
    done = run_cli("--config", "case.toml", "--quiet", "--out", ".", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    first = _snapshot(tmp_path)
    assert set(first) == FOLDER | set(foreign) and _leftovers(tmp_path) == []
    assert all(first[name] == data for name, data in foreign.items())
    assert (tmp_path / "results" / "a.csv").read_text() == "1,2\n"
    # Again, now a folder holding an earlier report: --evaluate writes no history.png, so the
    # earlier run's history.png (listed in its summary.json) is removed; the rest is replaced.
    done = run_cli("--config", "case.toml", "--evaluate", "--quiet", "--out", ".", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    second = _snapshot(tmp_path)
    assert set(second) == (FOLDER - {"history.png"}) | set(foreign) and _leftovers(tmp_path) == []
    assert all(second[name] == data for name, data in foreign.items())
    summary = json.loads(second["summary.json"])
    assert summary["mode"] == "evaluate" and set(summary["files"]) == FOLDER - {"history.png"}
    assert second["equilibrium.npz"] != first["equilibrium.npz"]  # (the optimised design was another)
    assert (tmp_path / "results" / "a.csv").read_text() == "1,2\n"


def test_a_failed_solve_exits_1_with_the_reason_and_writes_nothing(run_cli, tmp_path):
    # 60 steps of relaxation alone cannot reach equilibrium (the default 'auto' would go on to
    # Newton): the command reports the failure code, no traceback, and leaves neither the output
    # folder nor a staging folder behind.
    done = run_cli("--evaluate", *SMALL, "--equilibrium-method", "relax", "--max-steps", "60", "--out", "out",
                   cwd=tmp_path)
    assert done.returncode == 1
    assert "max_steps_reached" in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "out").exists() and _leftovers(tmp_path) == []


def test_an_optimisation_that_does_not_converge_exits_1_and_keeps_its_results(run_cli, tmp_path):
    done = run_cli(*SMALL, "--max-iterations", "2", "--no-figures", "--quiet", "--out", "out", cwd=tmp_path)
    assert done.returncode == 1 and done.stdout == ""
    assert "did not converge" in done.stderr and "Traceback" not in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and "no panel or rib template (DXF, SVG) was written" in done.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["results"]["success"] is False and summary["results"]["message"]
    assert not list((tmp_path / "out").glob("*.dxf")) and not list((tmp_path / "out").glob("pattern_*"))
    assert "failed design" in summary["skipped"]["patterns"]


# ------------------------------------------------------------------ the atomic folder
def test_an_interrupted_report_leaves_the_earlier_folder_untouched(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    earlier_report(out, {"skin.obj": b"old"})
    before = _snapshot(out)
    for interruption in (RuntimeError("plot failed"), KeyboardInterrupt()):
        with pytest.raises(type(interruption)):
            with output_folder.staged_folder(out) as staging:
                (staging / "skin.obj").write_bytes(b"partial")
                raise interruption
        assert _snapshot(out) == before and _leftovers(tmp_path) == [] and _leftovers(out) == []
    with output_folder.staged_folder(out) as staging:
        earlier_report(staging, {"skin.obj": b"new"}, new=True)
    assert json.loads((out / "summary.json").read_text())["new"] is True
    assert (out / "skin.obj").read_bytes() == b"new"
    assert _leftovers(tmp_path) == [] and _leftovers(out) == []


@pytest.mark.parametrize("kind", ["bay", "wing"])
def test_a_report_replaces_only_the_files_of_the_earlier_report(tmp_path, kind):
    # The rule: the earlier report's files (its summary.json lists them) are replaced, or removed
    # when the new report does not write them (a rib.dat of a rib-shape run, a wing's rib_K.dat and
    # bay_K plots); every other file stays byte for byte; the folder itself is never removed.
    out = tmp_path / "out"
    out.mkdir()
    if kind == "bay":
        earlier = {"equilibrium.npz": b"e1", "skin.obj": b"o1", "rib.dat": b"r1", "rib_design.png": b"p1"}
        new = {"equilibrium.npz": b"e2", "skin.obj": b"o2"}
    else:
        earlier = {"wing.npz": b"w1", "bay_0_mid_bay_section.png": b"b0", "bay_1_mid_bay_section.png": b"b1",
                   "bay_2_mid_bay_section.png": b"b2", "rib_0.dat": b"r0", "rib_1.dat": b"r1", "rib_2.dat": b"r2"}
        new = {"wing.npz": b"w2", "bay_0_mid_bay_section.png": b"c0", "bay_1_mid_bay_section.png": b"c1"}
    earlier_report(out, earlier)
    foreign = {"case.toml": b"target = 'x'\n", "clarky.dat": b"\x00\xff", "rib.dat.bak": b"mine",
               "rib_9.txt": b"mine too"}
    for name, data in foreign.items():
        (out / name).write_bytes(data)
    (out / "plots").mkdir()
    (out / "plots" / "bay_0_mid_bay_section.png").write_bytes(b"in a sub-folder: not the report's")
    inode = out.stat().st_ino
    with output_folder.staged_folder(out) as staging:
        written = earlier_report(staging, new)
    after = _snapshot(out)
    assert after == {**foreign, **new, "summary.json": after["summary.json"]}
    assert staging.parent == out  # staged inside the existing folder, never beside it
    assert json.loads(after["summary.json"]) == written
    assert (out / "plots" / "bay_0_mid_bay_section.png").read_bytes() == b"in a sub-folder: not the report's"
    assert out.stat().st_ino == inode and _leftovers(out) == [] and _leftovers(tmp_path) == []


def test_a_file_of_a_report_name_the_earlier_report_did_not_write_is_refused(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    earlier_report(out, {"skin.obj": b"old"})
    (out / "history.png").write_bytes(b"the user's own")  # not listed in the earlier summary.json
    before = _snapshot(out)
    with pytest.raises(ValueError, match="history.png"):
        output_folder.check_output_folder(out)
    with pytest.raises(ValueError, match="history.png"):  # also when it appears during the run
        (out / "history.png").unlink()
        with output_folder.staged_folder(out) as staging:
            (out / "history.png").write_bytes(b"the user's own")
            earlier_report(staging, {"skin.obj": b"new", "history.png": b"plot"})
    assert _snapshot(out) == before and _leftovers(out) == []
    (out / "summary.json").write_text('{"files": ["summary.json", "history.png"]}')  # not this package's
    with pytest.raises(ValueError, match="summary.json"):
        output_folder.check_output_folder(out)


def test_a_run_killed_while_moving_its_files_in_is_finished_by_the_next(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    earlier_report(out, {"skin.obj": b"old", "rib.dat": b"old rib"})
    (out / "notes.txt").write_text("mine")
    killed = out / ".report.partial-0123abcd"  # its moves had begun: skin.obj is in place already
    killed.mkdir()
    earlier_report(killed, {"skin.obj": b"new", "history.png": b"plot"}, run=2)
    (killed / ".moves.json").write_text(json.dumps({"files": ["history.png", "skin.obj", "summary.json"],
                                                   "remove": ["rib.dat"]}))
    os.replace(killed / "skin.obj", out / "skin.obj")
    assert output_folder.remove_stale_partials(out) == [killed]
    assert _snapshot(out) == {"skin.obj": b"new", "history.png": b"plot", "notes.txt": b"mine",
                              "summary.json": (out / "summary.json").read_bytes()}
    assert json.loads((out / "summary.json").read_text())["run"] == 2 and _leftovers(out) == []


def test_a_killed_runs_staging_folder_is_removed_by_the_next_writer_and_nothing_else(tmp_path):
    out = tmp_path / "out"
    stale = tmp_path / ".out.partial-0123abcd"  # what a SIGKILL leaves: no process holds its lock
    stale.mkdir()
    (stale / "equilibrium.npz").write_bytes(b"half")
    # Not ours, or not that pattern: kept.
    kept = [".out.partial-notes", ".out.partial-0123abcd.bak", ".other.partial-0123abcd",
            ".out.partial-0123ABCD", ".out.partial-89abcdef"]
    for name in kept[:-1]:
        (tmp_path / name).mkdir()
    (tmp_path / kept[-1]).write_text("a file, not a folder")
    with output_folder.staged_folder(out) as staging:
        assert not stale.exists() and all((tmp_path / name).exists() for name in kept)
        with output_folder.staged_folder(out) as second:  # a second writer of the same folder, meanwhile
            assert staging.is_dir()  # the first holds its lock: being written, not stale
            earlier_report(second, {"skin.obj": b"2"}, writer=2)
        earlier_report(staging, {"skin.obj": b"1"}, writer=1)
    assert json.loads((out / "summary.json").read_text())["writer"] == 1  # (merged into the second's)
    assert (out / "skin.obj").read_bytes() == b"1"
    assert _leftovers(tmp_path) == sorted(kept)



# ------------------------------------------------------------------ signals
def _sigterm_handler_installed(pid: int) -> bool:
    """Whether process ``pid`` catches SIGTERM (the SigCgt mask of /proc/PID/status, Linux)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) >> (signal.SIGTERM - 1) & 1)
    return False


def _wait_for(condition, process, what: str, limit: float = 300.0):
    """Poll ``condition()`` every 10 ms until it holds; fail if the process ends first."""
    deadline = time.monotonic() + limit
    while not condition():
        assert process.poll() is None, f"the command ended before {what}: {process.communicate()}"
        assert time.monotonic() < deadline, f"no {what} after {limit} s"
        time.sleep(0.01)


def _swallowed(signum: int) -> None:
    """Send ``signum`` to this process from inside a garbage-collection callback, as when it arrives
    while JAX's ``_xla_gc_callback`` runs: the exception its handler raises there is lost ("Exception
    ignored in ..."), and the code that called the collection goes on."""
    fired = []

    def callback(phase, info):
        if not fired:
            fired.append(phase)
            signal.raise_signal(signum)

    gc.callbacks.append(callback)
    try:
        gc.collect()
    finally:
        gc.callbacks.remove(callback)
    assert fired


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_lost_in_a_gc_callback_is_raised_again_at_the_next_safe_point(signum, capsys):
    stop = cli.Terminated if signum == signal.SIGTERM else KeyboardInterrupt
    before = signal.getsignal(signal.SIGINT)  # (Python's own, or SIG_IGN in a process started in the background)
    state = interrupts.install()
    try:
        interrupts.check()  # nothing recorded: nothing raised
        with pytest.raises(stop):
            signal.raise_signal(signum)  # raised where it arrives...
        with pytest.raises(stop):
            interrupts.check()  # ...and at every safe point after it
        interrupts.restore(interrupts.install())  # (a fresh record)
        _swallowed(signum)  # lost where it arrives
        with pytest.raises(stop):  # recorded, and raised at the next safe point
            interrupts.check()
    finally:
        interrupts.restore(state)
    assert "Exception ignored" not in capsys.readouterr().err  # the lost one printed nothing
    interrupts.check()  # (restored: nothing recorded)
    assert signal.getsignal(signal.SIGINT) is before


def test_a_stop_inside_a_deferred_section_waits_for_its_end():
    state = interrupts.install()
    try:
        with interrupts.deferred():
            signal.raise_signal(signal.SIGTERM)  # recorded, not raised
            interrupts.check()
            finished = True
        assert finished
        with pytest.raises(cli.Terminated):
            interrupts.check()
        with pytest.raises(cli.Terminated), interrupts.deferred():  # raised on entry: never started
            pytest.fail("a deferred section started after a stop")
    finally:
        interrupts.restore(state)


@pytest.mark.parametrize("signum, where", [(signal.SIGINT, "solving"), (signal.SIGTERM, "report"),
                                           (signal.SIGINT, "zip"), (signal.SIGTERM, "clean-up")])
def test_a_stop_lost_in_a_gc_callback_still_ends_the_run_and_writes_nothing(tmp_path, capsys, monkeypatch,
                                                                           signum, where):
    # Once, a Ctrl-C or SIGTERM arriving while JAX's gc callback ran was lost; the run wrote its
    # folder and exited 0. Here the stop is sent from inside a gc callback at the start of the run
    # (before the solve) or while the report is being written (inside its staging folder).
    # "zip": it arrives while a member of the .npz file is being closed, which made zipfile raise
    # ValueError ("Can't close the ZIP file while there is an open writing handle") in its place: the
    # run said "error: ..." and exited 2 (seen in CI). "clean-up": any writer's clean-up that raises
    # an error of its own in place of a stop.
    import zipfile

    from inverse_design.app import folder

    name, module = ("check_grid", run) if where == "solving" else ("plot_section", folder)
    if where == "zip":
        name, module = "close", zipfile._ZipWriteFile  # (private: where the stop landed in CI)
    original = getattr(module, name)

    def lose_a_stop(*args, **kwargs):
        if where == "zip":
            monkeypatch.setattr(module, name, original)
            signal.raise_signal(signum)
        elif where == "clean-up":
            try:
                signal.raise_signal(signum)
            except KeyboardInterrupt:
                raise OSError("a clean-up that failed in its turn") from None
        else:
            _swallowed(signum)
        return original(*args, **kwargs)

    monkeypatch.setattr(module, name, lose_a_stop)
    out = tmp_path / "out"
    code = cli.main([*SMALL, "--evaluate", "--no-compilation-cache", "--quiet", "--out", str(out)])
    word = "terminated" if signum == signal.SIGTERM else "interrupted"
    assert code == (143 if signum == signal.SIGTERM else 130)
    assert capsys.readouterr().err == f"optimise-pressure: {word}; nothing was written to {out}\n"
    assert not out.exists() and _leftovers(tmp_path) == []


@pytest.fixture(scope="module")
def run_seconds(default_run, start_cli, tmp_path_factory):
    """Seconds from the command's signal handlers being in place to its end, its compiled functions
    cached (as in the signal tests below, which run after it)."""
    process = start_cli(*SMALL, "--quiet", "--out", "out", cwd=tmp_path_factory.mktemp("timed"))
    _wait_for(lambda: _sigterm_handler_installed(process.pid), process, "the SIGTERM handler")
    start = time.monotonic()
    _, stderr = process.communicate(timeout=600)
    assert process.returncode == 0, stderr
    return time.monotonic() - start


# (moment: a fraction of `run_seconds` after the handlers are in place, or "report": as soon as the
# report's staging folder appears; signal; whether --out holds an earlier report and a file of the user's)
STOPS = [(0.0, signal.SIGINT, False), (0.1, signal.SIGTERM, True), (0.2, signal.SIGINT, True),
         (0.35, signal.SIGTERM, False), (0.5, signal.SIGINT, True), (0.65, signal.SIGTERM, True),
         ("report", signal.SIGINT, False), ("report", signal.SIGTERM, True)]


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads /proc (Linux)")
@pytest.mark.parametrize("moment, signum, earlier", STOPS)
def test_every_stop_ends_the_run_with_its_code_and_writes_nothing(start_cli, run_seconds, tmp_path, moment,
                                                                   signum, earlier):
    out = tmp_path / "out"
    if earlier:
        out.mkdir()
        earlier_report(out, {"skin.obj": b"earlier"})
        (out / "notes.txt").write_text("mine")
    before = _snapshot(out) if earlier else None
    # A run can end sooner than the timed one when the machine's load falls; then the stop is sent
    # again earlier in a new run (up to 3 runs, each at half the delay), so it always lands in a run.
    for attempt in range(3):
        process = start_cli(*SMALL, "--out", "out", cwd=tmp_path)
        try:
            _wait_for(lambda: _sigterm_handler_installed(process.pid), process, "the SIGTERM handler")
            if moment == "report":
                place, pattern = (out, ".report.partial-*") if earlier else (tmp_path, ".out.partial-*")
                _wait_for(lambda: list(place.glob(pattern)), process, "a staging folder")
            else:
                time.sleep(moment * run_seconds / 2 ** attempt)
            if process.poll() is None:
                process.send_signal(signum)
            stdout, stderr = process.communicate(timeout=120)
        finally:
            if process.poll() is None:
                process.kill()
                process.communicate()
        if process.returncode != 0 or moment == "report":
            break
        # The run ended before the signal: put the folder back as it was and try again.
        assert attempt < 2, f"three runs ended before the signal: {stdout}"
        if earlier:
            shutil.rmtree(out)
            out.mkdir()
            earlier_report(out, {"skin.obj": b"earlier"})
            (out / "notes.txt").write_text("mine")
        elif out.exists():
            shutil.rmtree(out)
    word = "terminated" if signum == signal.SIGTERM else "interrupted"
    stderr = "".join(line for line in stderr.splitlines(True) if "span nodes, fewer than" not in line)
    assert process.returncode == (143 if signum == signal.SIGTERM else 130), stderr
    assert stdout == "" and len(stderr.splitlines()) == 1 and stderr.endswith("\n"), stderr
    assert stderr.startswith(f"optimise-pressure: {word}") and "after" not in stderr, stderr
    if earlier:
        assert _snapshot(out) == before and _leftovers(out) == []
    else:
        assert not out.exists()
    assert _leftovers(tmp_path) == []


def test_main_installs_its_signal_handlers_only_while_it_runs(tmp_path, capsys):
    before = [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)] + [sys.unraisablehook]
    assert cli.main(["--target", "naca24x12", "--out", str(tmp_path / "out")]) == 2
    assert [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)] + [sys.unraisablehook] == before
    assert "NACA" in capsys.readouterr().err


def test_main_raises_the_collectors_threshold_only_while_it_runs(tmp_path, monkeypatch, capsys):
    """The command collects cyclic garbage less often (`cli.GC_THRESHOLD`) and gives the caller's
    thresholds back, also after a refusal."""
    seen = []
    real = cli._main
    monkeypatch.setattr(cli, "_main", lambda *args: seen.append(gc.get_threshold()) or real(*args))
    suite = gc.get_threshold()  # (the suite's processes collect at the command's threshold: tests/conftest.py)
    before = (700, 9, 11)  # a caller's own (Python's default first threshold is 700)
    gc.set_threshold(*before)
    try:
        assert cli.main(["--target", "naca24x12", "--out", str(tmp_path / "out")]) == 2
        assert gc.get_threshold() == before
    finally:
        gc.set_threshold(*suite)
    assert seen == [(cli.GC_THRESHOLD, *before[1:])] and cli.GC_THRESHOLD > before[0]
    assert "NACA" in capsys.readouterr().err


# ------------------------------------------------------------------ grid size
def test_a_grid_too_large_for_the_machine_is_refused_before_the_run(run_cli, tmp_path):
    # A 10000 x 64 optimisation needs tens of GB and hours: refused with the estimate before any
    # compilation (the timeout catches a run that starts anyway).
    done = run_cli("--n-span", "10000", "--out", "out", cwd=tmp_path, timeout=120)
    _one_line_error(done, "10000 x 64", "estimate", "GiB of memory", "--allow-large-grid")
    assert not (tmp_path / "out").exists() and _leftovers(tmp_path) == []


def test_the_estimate_reproduces_its_measurements():
    # Peak memory measured on the development machine (resources' docstring), MiB; the fit is
    # within 3 % of these square-ish grids, 5 % allowed.
    for grid, measured in [((65, 512), 2035), ((129, 1024), 6864)]:
        assert resources.estimate_cost(*grid).memory / 2**20 == pytest.approx(measured, rel=0.05)
    assert resources.estimate_cost(129, 1024, evaluate=True).memory / 2**20 == pytest.approx(1166, rel=0.15)
    small, large = resources.estimate_cost(9, 64), resources.estimate_cost(129, 1024)
    assert small.memory < large.memory
    assert resources.estimate_cost(129, 1024, evaluate=True).memory < large.memory


def test_check_grid_refuses_by_memory_and_by_node_count_and_says_what_to_change():
    plenty = (1e15, "test")
    with pytest.raises(ValueError, match=r"estimate .* GiB of memory .* limit of 1\.0 GiB \(half of the 2\.0 GiB"
                                         r" available, test\).*--allow-large-grid"):
        resources.check_grid(129, 1024, available=(2 * 2**30, "test"))
    assert resources.check_grid(129, 1024, available=(2 * 2**30, "test"), allow_large=True).nodes == 129 * 1024
    over = resources.MAX_NODES // 100 + 1  # x 100 contour nodes: just over the cap
    with pytest.raises(ValueError, match="exceeds the cap of 250,000 nodes: estimate"):
        resources.check_grid(over, 100, evaluate=True, available=plenty)
    # Memory unknown (no /proc/meminfo, no sysconf): the node cap still holds.
    with pytest.raises(ValueError, match="exceeds the cap"):
        resources.check_grid(over, 100, available=(None, "unknown"))
    assert resources.check_grid(9, 64, available=(None, "unknown")).nodes == 576
    assert resources.check_grid(2, 64, available=plenty).nodes == 128  # too small: Bay says so, not this
    free, source = resources.available_memory()
    assert free is None or (free > 0 and source)
