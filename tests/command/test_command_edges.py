"""The command's edges: a missing platform, closed streams, an unusable compilation cache, a missing
home folder, Python warnings and long error lines, each one line (inverse_design/app/cli.py)."""

import json
import os
import subprocess
import sys

import pytest

from inverse_design.app import cli
from support.cases import SMALL
from support.command import environment, launch
from targets import naca


def _stderr_lines(captured) -> list[str]:
    return [line for line in captured.err.splitlines() if line.strip()]


def test_a_platform_the_machine_lacks_is_one_line_and_exit_2(tmp_path):
    """``JAX_PLATFORMS=cuda`` where there is no GPU: the platform asked for, those present, the fix."""
    ran = subprocess.run(launch(*SMALL, "--out", tmp_path / "out"), cwd=tmp_path, env=environment(JAX_PLATFORMS="cuda"),
                         capture_output=True, text=True, timeout=600)
    import jax

    if any(d.platform == "gpu" for d in jax.devices()) or "cuda" in [p.lower() for p in cli._platforms_present()]:
        pytest.skip("this machine may have a CUDA platform")
    lines = [line for line in ran.stderr.splitlines() if line.strip()]
    assert ran.returncode == 2, ran.stderr
    assert len(lines) == 1 and lines[0].startswith("optimise-pressure: error: JAX_PLATFORMS=cuda"), ran.stderr
    assert "present: cpu" in lines[0] and "JAX_PLATFORMS=cpu" in lines[0]
    assert not (tmp_path / "out").exists()


def test_a_run_without_stdout_or_home_finishes_and_creates_no_home(tmp_path):
    """stdout closed (``>&-``) and HOME a folder that does not exist: the report is written, exit 0,
    one line says the run goes without the cache, and the home folder is not created."""
    home = tmp_path / "no-such-home"
    # (--evaluate: one equilibrium and its report; without a cache an optimisation compiles its gradients cold)
    command = launch(*SMALL, "--evaluate", "--out", tmp_path / "out")
    ran = subprocess.run(["sh", "-c", 'exec "$@" >&-', "sh", *command],
                         cwd=tmp_path, env=environment(HOME=str(home), XDG_CACHE_HOME=None, XDG_CONFIG_HOME=None,
                                                       INFLATABLE_WING_CACHE=None, JAX_COMPILATION_CACHE_DIR=None,
                                                       MPLCONFIGDIR=None),
                         stderr=subprocess.PIPE, text=True, timeout=900)
    assert ran.returncode == 0, ran.stderr
    # (besides the small grid's own warning, and matplotlib's notice as it builds its font cache in the
    # temporary configuration folder the command gives it without a home)
    lines = [line for line in ran.stderr.splitlines() if line.strip() and "the design grid has" not in line
             and not line.startswith("Matplotlib is building the font cache")]
    assert lines == [f"optimise-pressure: warning: the home folder {home} does not exist: running without the "
                     "compilation cache (set INFLATABLE_WING_CACHE to a folder you can write, or give "
                     "--no-compilation-cache)"], ran.stderr
    assert not home.exists()
    assert (tmp_path / "out" / "summary.json").exists()


def test_ending_with_closed_streams_exits_with_the_runs_code(monkeypatch):
    """The command's end flushes what streams it has: none is no error."""
    monkeypatch.setattr(sys, "stdout", None)
    monkeypatch.setattr(sys, "stderr", None)
    monkeypatch.setattr(os, "_exit", lambda code: (_ for _ in ()).throw(SystemExit(code)))
    with pytest.raises(SystemExit) as ended:
        cli._exit_now(1)
    assert ended.value.code == 1
    cli._say("nothing to say it on")  # (no stderr: nothing printed, no error)


@pytest.mark.parametrize("kind", ["file", "missing home"])
def test_a_cache_folder_that_cannot_be_used_is_one_line_and_the_run_goes_without(tmp_path, monkeypatch, capsys, kind):
    import jax

    before = jax.config.jax_compilation_cache_dir
    for variable in ("INFLATABLE_WING_CACHE", "JAX_COMPILATION_CACHE_DIR", "XDG_CACHE_HOME"):
        monkeypatch.delenv(variable, raising=False)
    if kind == "file":
        (tmp_path / "cache").write_text("not a folder")
        monkeypatch.setenv("INFLATABLE_WING_CACHE", str(tmp_path / "cache"))
        why = f"{tmp_path / 'cache'} is not a folder"
    else:
        monkeypatch.setenv("HOME", str(tmp_path / "home"))
        why = f"the home folder {tmp_path / 'home'} does not exist"
    assert cli.use_compilation_cache(cli.compilation_cache_dir()) is False
    lines = _stderr_lines(capsys.readouterr())
    assert len(lines) == 1 and lines[0].startswith(f"optimise-pressure: warning: {why}: running without"), lines
    assert jax.config.jax_compilation_cache_dir == before
    assert not (tmp_path / "home").exists()


def test_jax_cache_warnings_become_one_line_and_turn_the_cache_off(capsys, monkeypatch):
    """A damaged entry makes JAX warn at every program; the command says it once and goes on without."""
    import jax

    monkeypatch.setattr(cli, "_CACHE_WARNED", False)
    previous = jax.config.jax_enable_compilation_cache
    try:
        for name in ("jit_relax", "jit_prepare", "jit_static_state"):
            cli._show_warning(UserWarning(f"Error reading persistent compilation cache entry for '{name}': "
                                          "XlaRuntimeError: INVALID_ARGUMENT: bad data\nmore detail"),
                              UserWarning, "compiler.py", 1)
        assert jax.config.jax_enable_compilation_cache is False
    finally:
        jax.config.update("jax_enable_compilation_cache", previous)
    lines = _stderr_lines(capsys.readouterr())
    assert len(lines) == 1 and lines[0].startswith("optimise-pressure: warning: the compilation cache in "), lines
    assert "running without it" in lines[0] and len(lines[0]) < 300


def test_an_airfoil_warning_is_one_warning_line_of_the_command(tmp_path, capsys):
    """A section whose chord is renormalised warns as the command, not as a Python warning."""
    section = naca("0012")
    dat = tmp_path / "wide.dat"
    dat.write_text("wide chord\n" + "".join(f"{x:.6f} {z:.6f}\n" for x, z in zip(section.x * 1.002,
                                                                                  section.z * 1.002)))
    (tmp_path / "file").write_text("")
    code = cli.main(["--target", str(dat), *SMALL, "--no-compilation-cache", "--out", str(tmp_path / "file" / "out")])
    lines = _stderr_lines(capsys.readouterr())
    assert code == 2
    assert lines[0].startswith("optimise-pressure: warning: ") and "renormalised to unit chord" in lines[0], lines
    assert not any("AirfoilWarning" in line or "case.py" in line or "warnings.warn" in line for line in lines), lines
    assert lines[-1].startswith("optimise-pressure: error: ")


def test_a_long_error_is_cut_to_its_reason_and_fix_and_whole_under_json(capsys):
    message = ("the design breaks its limits; " + "; ".join(f"rib {k}: tension 1.5 N/m below the floor at "
                                                          f"x = 0.{k} chord" for k in range(30))
               + "; raise the pressure or lower --min-tension")
    assert len(message) > 900
    short = cli.shorten(message)
    assert len(short) <= cli.CONSOLE_WIDTH
    assert short.startswith("the design breaks its limits; ") and short.endswith("raise the pressure or lower --min-tension")
    assert cli.shorten("a short line\nwith a break") == "a short line with a break"

    class Args:
        json = True

    cli._error(Args(), "failed", message)
    captured = capsys.readouterr()
    assert len(captured.err.strip()) < cli.CONSOLE_WIDTH + 40 and "\n" not in captured.err.strip()
    assert json.loads(captured.out) == {"error": message}
