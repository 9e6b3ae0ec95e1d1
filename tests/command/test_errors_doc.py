"""docs/errors.md says what the command prints: every row of its tables with an example command is
run (in this process, `cli.main`, in an empty folder) and must exit 2 with that row's message as its
one line on stderr (``…`` in the page stands for the parts that depend on the case)."""

import re
import shlex
from pathlib import Path

import pytest

from inverse_design.app import cli

PAGE = Path(__file__).parents[2] / "docs" / "errors.md"
ROW = re.compile(r"^\| [^|]+ \| `optimise-pressure (?P<args>[^`]*)` \| `(?P<message>[^`]+)` \|")


def _rows():
    rows = [m.groupdict() for line in PAGE.read_text(encoding="utf-8").splitlines() if (m := ROW.match(line))]
    assert len(rows) >= 12, rows  # (a change of the table's layout must not silence this test)
    return rows


@pytest.mark.parametrize("row", _rows(), ids=lambda row: row["args"][:40])
def test_each_refusal_of_the_page_is_what_the_command_prints(row, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code = cli.main([*shlex.split(row["args"]), "--no-compilation-cache", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    prefix = "optimise-pressure: error: "
    assert err.startswith(prefix), err
    pattern = ".*".join(re.escape(part) for part in row["message"].split("…"))
    assert re.fullmatch(pattern, err[len(prefix):].rstrip("\n"), flags=re.DOTALL), (row["message"], err)
    assert list(tmp_path.iterdir()) == []  # nothing written
