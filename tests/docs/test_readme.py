"""Every fenced code block of README.md (and of the docs pages in `PAGES`) runs as written, and
docs/performance.md is up to date.

Each block is preceded by a marker that says how it is checked::

    <!-- readme-test: run -->          run as written
    <!-- readme-test: small grid -->   run as written on a small grid (below)
    <!-- readme-test: small grid, from the repository root -->   ... with the repository's
                                       built-in case files (inverse_design/cases) at hand
    <!-- readme-test: case file -->    a case file: read and checked as the command reads it (`case.Case`)
    <!-- readme-test: case file, small grid -->   ... and run with --config on the small grid
    <!-- readme-test: error of the case file above ... -->   the command's message, reproduced (below)
    <!-- readme-test: skip (why) -->   not run, and why

A block without a marker, or with another one, fails the test, so a new
block gets a decision. Every block runs in a fresh temporary folder, so
the files the examples write (relative paths: ``--out DIR``, the default
``optimise-pressure-out/``, ``section.dat``) never land in the repository.
Python blocks run in a subprocess with the repository first on PYTHONPATH;
shell blocks run each command (``&&`` splits them) with ``optimise-pressure``
as ``python -m support.command`` (the code under test, its report written
serially: tests/support/command.py) and skip ``pip install`` lines. "Small
grid" is the one substitution: every ``n_span=N`` and ``n_contour=N`` of a Python block becomes 5 and 32, and every
``optimise-pressure`` command gets ``--n-span 5 --n-contour 32``
(the default grids take minutes; the blocks' outcomes do not depend on the
grid). 5x32 is the grid of the command's other tests (tests/command/), so
the subprocesses reuse the programs those compile: every block runs with the
run's one JAX compilation cache (tests/conftest.py), which its subprocesses
inherit from the environment.
"""

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from inverse_design.app.case import Case
from support.command import environment, launch

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
#: The pages whose code blocks run here: the README, then the docs pages with examples.
PAGES = (README, ROOT / "docs" / "command.md", ROOT / "docs" / "patterns.md", ROOT / "docs" / "compilation.md",
         ROOT / "docs" / "fabric_test.md")
SMALL = {"n_span": 5, "n_contour": 32}
SMALL_ARGS = ["--n-span", str(SMALL["n_span"]), "--n-contour", str(SMALL["n_contour"])]
TIMEOUT = 300
MARKER = re.compile(r"<!-- readme-test: (.+?) -->\s*$")
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)
#: The error block's marker, and the rib it adds to the case file above it.
ERROR_MARKER = "error of the case file above with a third rib at station 0.2 m"
FROM_ROOT = "small grid, from the repository root"
THIRD_RIB = '\n[[rib]]\nsection = "naca2412"\nchord = 0.7\nstation = 0.2\n'


def _blocks():
    """``[(where, language, text, marker or None)]`` of every fenced block of `PAGES`, ``where`` as page:line."""
    blocks = []
    for page in PAGES:
        text = page.read_text()
        for match in FENCE.finditer(text):
            line = text.count("\n", 0, match.start()) + 1
            before = text[:match.start()].rstrip("\n").splitlines()
            marker = MARKER.search(before[-1]) if before else None
            blocks.append((f"{page.relative_to(ROOT)}:{line}", match.group(1), match.group(2),
                           marker.group(1) if marker else None))
    return blocks


BLOCKS = _blocks()


@pytest.fixture(scope="module")
def env():
    # Compilation is most of the blocks' time: the subprocesses inherit the run's compilation cache
    # (JAX_COMPILATION_CACHE_DIR and INFLATABLE_WING_CACHE, set by tests/conftest.py), shared with
    # every other test process and subprocess of the run.
    return environment(MPLBACKEND="Agg")


def _small_python(code: str) -> str:
    for name, value in SMALL.items():
        code = re.sub(rf"\b{name}=\d+", f"{name}={value}", code)
    return code


def _commands(text: str):
    """The shell block's commands as argument lists (comments dropped, ``&&`` split)."""
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        for command in filter(None, (c.strip() for c in line.split("&&"))):
            yield shlex.split(command)


def _command(args: list, small: bool):
    """The argument list to run, or None for a line that is not run (pip install)."""
    if args[:4] == ["python", "-m", "pip", "install"] or args[:2] == ["pip", "install"]:
        return None
    if args[0] == "optimise-pressure":
        return launch(*args[1:], *(SMALL_ARGS if small else []))
    if args[0] == "python":
        return [sys.executable, *args[1:]]
    return args


def _run(args, cwd, env):
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=TIMEOUT)


def _previous_case_file(index: int) -> str:
    earlier = [b for b in BLOCKS[:index] if b[1] == "toml"]
    return earlier[-1][2]


def test_every_block_has_a_known_marker():
    assert len(BLOCKS) >= 8
    known = ("run", "small grid", FROM_ROOT, "case file", "case file, small grid", ERROR_MARKER)
    for line, language, _, marker in BLOCKS:
        assert marker is not None, f"{line}: a ```{language} block without a readme-test marker"
        assert marker in known or marker.startswith("skip ("), f"{line}: unknown marker {marker!r}"


@pytest.mark.parametrize("index", range(len(BLOCKS)), ids=[f"{b[0]} {b[1] or 'text'}" for b in BLOCKS])
def test_the_block_runs_as_written(index, env, tmp_path):
    line, language, text, marker = BLOCKS[index]
    if marker is None or marker.startswith("skip ("):
        pytest.skip(f"{line}: {marker}")
    small = "small grid" in marker
    if marker == ERROR_MARKER:
        (tmp_path / "wing.toml").write_text(_previous_case_file(index) + THIRD_RIB)
        done = _run(launch("--config", "wing.toml"), tmp_path, env)
        assert done.returncode == 2 and done.stdout == "", done.stderr
        assert done.stderr.strip() == text.strip()
    elif language == "python":
        (tmp_path / "block.py").write_text(_small_python(text) if small else text)
        done = _run([sys.executable, "block.py"], tmp_path, env)
        assert done.returncode == 0, f"{line}:\n{done.stderr[-3000:]}"
        if line.startswith("README.md"):  # (a reader runs these from wherever they stand; docs' examples write on purpose)
            left = sorted(p.name for p in tmp_path.iterdir() if p.name not in ("block.py", "__pycache__"))
            assert left == [], f"{line}: the example writes into the reader's current folder: {left}"
    elif language == "toml":
        case = tmp_path / "case.toml"
        case.write_text(text)
        assert Case.from_arguments(["--config", str(case)]).options  # every key, value and section checked
        if small:
            done = _run(launch("--config", "case.toml", *SMALL_ARGS, "--out", "out"), tmp_path, env)
            assert done.returncode == 0, f"{line}:\n{done.stderr[-3000:]}"
            assert (tmp_path / "out" / "summary.json").exists()
    elif language == "bash":
        commands = [c for c in (_command(args, small) for args in _commands(text)) if c is not None]
        assert commands, f"{line}: nothing to run"
        if any("--aero" in c for c in commands):
            pytest.importorskip("neuralfoil")
        if marker == FROM_ROOT:  # the built-in case files where a checkout has them, nothing else
            (tmp_path / "inverse_design").mkdir()
            (tmp_path / "inverse_design" / "cases").symlink_to(ROOT / "inverse_design" / "cases")
        for command in commands:
            done = _run(command, tmp_path, env)
            assert done.returncode == 0, f"{line}: {shlex.join(command)}:\n{done.stderr[-3000:]}"
            if command[1:3] == launch()[1:3]:  # the command: the documented outcome, the folder
                out = command[command.index("--out") + 1] if "--out" in command else "optimise-pressure-out"
                assert (tmp_path / out / "summary.json").is_file() and f"wrote {tmp_path / out}" in done.stdout
    else:
        pytest.fail(f"{line}: a ```{language} block marked {marker!r}: nothing knows how to run it")


def test_the_folders_the_examples_write_are_ignored_by_git():
    """Run from a checkout, the README's commands write their output folders in it: git ignores each."""
    text = README.read_text()
    folders = sorted({"optimise-pressure-out", *re.findall(r"--out\s+([a-z0-9][\w.]*-out)\b", text)})
    assert "wing40-out" in folders  # (named in the prose too)
    ignored = subprocess.run(["git", "check-ignore", *folders], cwd=ROOT, capture_output=True, text=True)
    assert sorted(ignored.stdout.split()) == folders


def test_the_performance_page_is_a_table_of_each_result_file(tmp_path):
    from benchmarks import performance_doc
    from benchmarks.results import save_result

    save_result("b_solves", title="Solves of a design", command="python benchmarks/b.py --quick",
                columns=["case", "solves", "wall time, s"], rows=[["bay", 7, 2.904], ["wing | 3 bays", 6, None]],
                notes=["one note"], machine="a test machine", date="2026-01-02", folder=tmp_path)
    save_result("a_first", title="First by name", command="python benchmarks/a.py", columns=["x"], rows=[[1.0]],
                folder=tmp_path)
    page = performance_doc.render(tmp_path, expected={"c_missing": ("a benchmark not run", "python c.py")})
    assert page.index("## First by name") < page.index("## Solves of a design")  # sorted by file name
    section = page[page.index("## Solves of a design"):]
    assert "measured 2026-01-02 on a test machine" in section
    assert "```bash\npython benchmarks/b.py --quick\n```" in section
    assert ("| case | solves | wall time, s |\n| --- | --- | --- |\n| bay | 7 | 2.904 |\n"
            "| wing \\| 3 bays | 6 |  |\n\n- one note\n") in section
    assert "- a benchmark not run: run `python c.py`" in page
    with pytest.raises(ValueError, match="row 0 .* 1 cells for 2 columns"):
        save_result("bad", title="t", command="c", columns=["a", "b"], rows=[[1]], folder=tmp_path)


def test_the_performance_page_is_up_to_date():
    from benchmarks import performance_doc

    assert performance_doc.PAGE.read_text() == performance_doc.render(), (
        "docs/performance.md differs from benchmarks/results/*.json: run python benchmarks/performance_doc.py")


def test_the_readme_is_short_and_the_repository_cites_no_issue_numbers():
    # The README is for users (at most 400 lines; the detail lives in docs/), and what the repository
    # says of itself cites the paper's equations and docs/, never a tracker the reader cannot see nor a
    # design note outside the repository.
    assert len(README.read_text().splitlines()) <= 400
    pattern = re.compile(r"\b[Ii]ssues? #?\d|\b(DESIGN|STYLE)\.md\b")
    packages = [path for package in ("targets", "forward_solver", "inverse_design") for path in (ROOT / package).rglob("*.py")]
    pages = [README, *packages, *(ROOT / "docs").glob("*.md"), *(ROOT / "notebooks").glob("*.ipynb"),
             *(ROOT / "notebooks").glob("*.md"), *(ROOT / "benchmarks").glob("*.py"),
             *(ROOT / "benchmarks").glob("*.md"), *(ROOT / "tests").rglob("*.py"), *(ROOT / "tests").rglob("*.md")]
    found = [f"{page.relative_to(ROOT)}:{n}" for page in pages
             for n, line in enumerate(page.read_text().splitlines(), 1) if pattern.search(line)]
    assert not found, (f"issue numbers or outside notes in {', '.join(found)}: say what the code does and cite "
                       "docs/ instead")
