"""A warning is one whole line on stderr, and the summary keeps the same text (docs/errors.md, "Warnings")."""

import json

import numpy as np

from inverse_design.app import cli
from targets import naca

from support.cases import SMALL


def test_a_section_renormalised_to_unit_chord_is_warned_whole_and_kept_in_the_summary(tmp_path, capsys):
    section = naca("2412", n_points=81)
    dat = tmp_path / "off.dat"  # a chord of 1.004: renormalised (up to 0.005 off), with a warning
    np.savetxt(dat, np.column_stack([section.x * 1.004, section.z * 1.004]), header="OFF CHORD", comments="")
    out = tmp_path / "out"
    code = cli.main(["--target", str(dat), "--evaluate", *SMALL, "--no-figures", "--no-compilation-cache",
                     "--out", str(out)])
    err = capsys.readouterr().err.splitlines()
    assert code == 0
    kept = json.loads((out / "summary.json").read_text())["warnings"]
    said = [line.removeprefix("optimise-pressure: warning: ") for line in err if line.startswith("optimise-pressure: warning:")]
    renormalised = [line for line in kept if "renormalised to unit chord" in line]
    assert len(renormalised) == 1 and renormalised[0].endswith("x and z scaled by 0.996015936")
    assert renormalised[0] in said  # (the same text, whole)
