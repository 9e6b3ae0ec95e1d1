"""The output folder's edge cases: an empty name, a name too long, a file edited since the earlier
report, and two runs into one folder at once (`inverse_design.app.output_folder`).

Most checks call the folder functions directly; the command's part runs in this process
(`cli.main`) and stops before any design, except one small ``--evaluate``.
"""

import json
import os

import pytest

from inverse_design.app import cli, output_folder, run
from inverse_design.app.case import Case
from inverse_design.app.options import InputError
from support.cases import SMALL as GRID
from support.reports import earlier_report

SMALL = [*GRID, "--no-compilation-cache"]


def _hidden(folder):
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


# ------------------------------------------------------------------ an empty name
def test_an_empty_output_folder_name_is_refused(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(InputError, match="empty name"):
        Case.from_arguments(["--out", ""])
    (tmp_path / "case.toml").write_text('out = ""\n')
    with pytest.raises(InputError, match="empty name"):  # a case file's too
        Case.from_arguments(["--config", "case.toml"])
    with pytest.raises(ValueError, match="empty name"):  # the library's check
        output_folder.check_output_folder("")
    code = cli.main(["--out", "", *SMALL])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert err.startswith("optimise-pressure: error: argument --out: the output folder is an empty name")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["case.toml"]  # nothing written here


# ------------------------------------------------------------------ a name too long
@pytest.mark.parametrize("length", [300, 250])  # too long alone; too long for the staging folder beside it
def test_an_output_folder_name_too_long_for_the_file_system_is_refused(tmp_path, capsys, length):
    out = tmp_path / ("x" * length)
    with pytest.raises(ValueError, match=f"too long for this file system: {length} bytes"):
        output_folder.check_output_folder(out)
    code = cli.main(["--out", str(out), *SMALL])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "choose a shorter name" in err
    assert err.startswith("optimise-pressure: error: the output folder name 'xxx")
    assert list(tmp_path.iterdir()) == []
    output_folder.check_output_folder(tmp_path / ("x" * 200))  # a long name that fits


def test_a_too_long_name_inside_a_new_path_is_refused_too(tmp_path):
    with pytest.raises(ValueError, match="300 bytes, more than the 255"):
        output_folder.check_output_folder(tmp_path / ("y" * 300) / "out")


# ------------------------------------------------------------------ a file edited since
def test_a_changed_file_that_the_new_report_does_not_write_is_kept(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    earlier_report(out, {"skin.obj": b"old", "rib.dat": b"the designed rib"}, checksums=True)
    assert output_folder.changed_files(out) == []
    (out / "rib.dat").write_bytes(b"the rib as the shop corrected it")
    assert output_folder.changed_files(out) == ["rib.dat"]
    output_folder.check_output_folder(out)  # (nothing to refuse: the new report may not write rib.dat)
    with output_folder.staged_folder(out) as staging:
        earlier_report(staging, {"skin.obj": b"new"}, checksums=True)  # a run without a rib shape: no rib.dat
    assert (out / "rib.dat").read_bytes() == b"the rib as the shop corrected it"  # kept, not removed
    assert (out / "skin.obj").read_bytes() == b"new"
    assert json.loads((out / "summary.json").read_text())["files"] == ["skin.obj", "summary.json"]
    # No longer the report's: the next report that writes a rib.dat is refused up front.
    with pytest.raises(ValueError, match="rib.dat: no earlier report wrote it"):
        output_folder.check_output_folder(out)


def test_a_changed_file_that_the_new_report_would_replace_is_refused(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    earlier_report(out, {"skin.obj": b"old", "rib.dat": b"the designed rib"}, checksums=True)
    (out / "rib.dat").write_bytes(b"edited")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    # Up front, when the caller says which files the new report may write:
    with pytest.raises(ValueError, match=r"rib\.dat: it changed since the earlier report wrote it") as info:
        output_folder.check_output_folder(out, replaces=lambda name: True)
    assert str(out / "rib.dat") in str(info.value) and "move it away" in str(info.value)
    output_folder.check_output_folder(out, replaces=lambda name: name != "rib.dat")
    # At the latest when the files would move in: nothing moves.
    with pytest.raises(ValueError, match="it changed since the earlier report wrote it"):
        with output_folder.staged_folder(out) as staging:
            earlier_report(staging, {"skin.obj": b"new", "rib.dat": b"new rib"}, checksums=True)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before and _hidden(out) == []


def test_a_summary_without_checksums_is_trusted_as_before(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    earlier_report(out, {"skin.obj": b"old", "rib.dat": b"rib"}, checksums=False)
    (out / "rib.dat").write_bytes(b"edited")
    assert output_folder.changed_files(out) == []
    with output_folder.staged_folder(out) as staging:
        earlier_report(staging, {"skin.obj": b"new"}, checksums=True)
    assert not (out / "rib.dat").exists()


def test_the_command_records_checksums_and_refuses_to_replace_an_edited_file(tmp_path, capsys):
    out = tmp_path / "out"
    code = cli.main(["--evaluate", *SMALL, "--quiet", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    summary = json.loads((out / "summary.json").read_text())
    listed = [name for name in summary["files"] if name != "summary.json"]
    assert sorted(summary["checksums"]) == sorted(listed)
    assert summary["checksums"] == output_folder.file_checksums(out, listed)
    assert output_folder.changed_files(out) == []
    (out / "skin.obj").write_text("# edited in a mesh tool\n")
    capsys.readouterr()
    code = cli.main(["--evaluate", *SMALL, "--quiet", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert f"refusing to overwrite {out / 'skin.obj'}: it changed since the earlier report wrote it" in err
    assert (out / "skin.obj").read_text() == "# edited in a mesh tool\n"


def test_the_command_warns_of_a_changed_file_it_keeps(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    earlier_report(out, {"skin.obj": b"old", "rib.dat": b"rib", "rib_design.png": b"png"}, checksums=True)
    (out / "rib.dat").write_bytes(b"edited")
    case = Case.from_arguments(["--out", str(out), "--variables", "pressure"])
    # A run without a rib shape writes no rib.dat: it may go ahead, and says it keeps the file.
    assert not case.may_write("rib.dat")
    output_folder.check_output_folder(out, replaces=case.may_write)
    lines = run.warn(case)
    err = capsys.readouterr().err.splitlines()
    ours = [line for line in lines if line.startswith("rib.dat")]
    assert ours == [f"rib.dat in {out} changed since the earlier report wrote it: kept as it is (this run writes "
                    "no rib.dat), and no longer counted as a report file"]
    assert f"optimise-pressure: warning: {ours[0]}" in err
    # A rib-shape run would replace it: refused before the design.
    case = Case.from_arguments(["--out", str(out), "--variables", "pressure,rib_shape"])
    with pytest.raises(ValueError, match="rib.dat: it changed"):
        output_folder.check_output_folder(out, replaces=case.may_write)


@pytest.mark.parametrize("argv, writes, never", [
    ([], ["summary.json", "equilibrium.npz", "wing.npz", "bay_0_cut_pattern.csv", "history.png",
          "pattern_bay_0_upper.dxf", "rib_1.dxf"],
     ["rib.dat", "bay_0_aero.png", "cut_pattern.csv", "mid_bay_section.png"]),
    (["--evaluate", "--no-patterns"], ["skin.obj", "tensions.png"], ["history.png", "pattern_bay_0_lower.svg"]),
    (["--variables", "pressure,rib_shape", "--aero"], ["rib.dat", "rib_design.png", "bay_0_aero.png"],
     ["aero.png"]),
], ids=["default", "evaluate", "rib shape"])
def test_what_a_run_may_write(argv, writes, never):
    may = Case.from_arguments(argv).may_write
    assert all(may(name) for name in writes) and not any(may(name) for name in never)


# ------------------------------------------------------------------ two runs at once
def test_a_second_run_into_a_folder_being_written_is_refused(tmp_path, capsys):
    out = tmp_path / "out"
    with output_folder.output_lock(out):  # a run into a new folder: the lock file beside it
        assert (tmp_path / ".out.lock").read_text() == str(os.getpid())
        with pytest.raises(ValueError, match=f"another run is writing the output folder {out} "
                                             rf"\(process {os.getpid()} holds the lock"):
            with output_folder.output_lock(out):
                pass
        code = cli.main(["--evaluate", *SMALL, "--out", str(out)])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and "another run is writing the output folder" in err
        assert not out.exists()
    assert _hidden(tmp_path) == []  # the lock file goes with the lock
    out.mkdir()
    with output_folder.output_lock(out):  # an existing folder: the lock file inside it
        assert (out / ".report.lock").exists()
        with pytest.raises(ValueError, match="another run is writing"):
            with output_folder.output_lock(str(out) + "/"):  # the same folder, spelled otherwise
                pass
    assert _hidden(out) == [] and _hidden(tmp_path) == []
    with output_folder.output_lock(tmp_path / "a" / "b"):  # missing parents: in the nearest existing one
        assert _hidden(tmp_path) == [".a.b.lock"] and not (tmp_path / "a").exists()


def test_runs_into_different_folders_do_not_wait_for_each_other(tmp_path):
    with output_folder.output_lock(tmp_path / "one"), output_folder.output_lock(tmp_path / "two"):
        assert _hidden(tmp_path) == [".one.lock", ".two.lock"]


def test_a_run_in_another_process_holds_the_folder_until_it_ends(tmp_path, capsys):
    import subprocess
    import sys

    out = tmp_path / "out"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys\nfrom inverse_design.app.output_folder import output_lock\n"
         f"with output_lock({str(out)!r}):\n    print('locked', flush=True)\n    sys.stdin.read()\n"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env={**os.environ, "JAX_PLATFORMS": "cpu"})
    try:
        assert holder.stdout.readline() == "locked\n"
        code = cli.main(["--evaluate", *SMALL, "--out", str(out)])
        err = capsys.readouterr().err
        assert code == 2 and f"(process {holder.pid} holds the lock {tmp_path / '.out.lock'})" in err
    finally:
        holder.communicate("", timeout=120)
    assert holder.returncode == 0 and _hidden(tmp_path) == []
    with output_folder.output_lock(out):  # free again
        pass
