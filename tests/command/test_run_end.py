"""The end of a run, once its report is complete: an output stream that fails, a stop that comes late."""

import errno
import json
import os
import signal

from inverse_design.app import cli

from support.cases import SMALL


class _FullDevice:
    """A standard output on a full device (``> /dev/full``): every write fails."""

    def write(self, text):
        raise OSError(errno.ENOSPC, "No space left on device")

    def flush(self):
        raise OSError(errno.ENOSPC, "No space left on device")


def test_a_failing_standard_output_is_one_line_and_the_report_stays(tmp_path, monkeypatch, capsys):
    out = tmp_path / "out"
    monkeypatch.setattr("sys.stdout", _FullDevice())
    code = cli.main([*SMALL, "--variables", "pressure", "--no-figures", "--no-compilation-cache", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 1
    assert "Traceback" not in err
    line = err.strip().splitlines()[-1]
    assert line == (f"optimise-pressure: failed: could not print the summary on the standard output (No space left "
                    f"on device); the report is complete in {out}")
    assert json.loads((out / "summary.json").read_text())["results"]["success"]


def test_a_stop_that_something_swallows_after_the_report_still_ends_the_run(tmp_path, monkeypatch, capsys):
    # A SIGTERM that arrives as the console lines are printed, inside code that swallows the exception
    # (a garbage-collection callback, a __del__): the command used to end with 0 as if no stop had come.
    describe = cli.describe

    def swallowing(summary):
        try:
            os.kill(os.getpid(), signal.SIGTERM)
        except KeyboardInterrupt:
            pass
        return describe(summary)

    monkeypatch.setattr(cli, "describe", swallowing)
    out = tmp_path / "out"
    code = cli.main([*SMALL, "--variables", "pressure", "--no-figures", "--no-compilation-cache", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == cli.EXIT_TERMINATED
    assert captured.err.strip().splitlines()[-1] == (
        f"optimise-pressure: terminated after the report was complete in {out}")
    assert "wrote" in captured.out  # (the console's lines were printed whole)
    assert (out / "summary.json").exists()
