"""Ribs so close that the flat panels cannot be laid out are refused before the design, not after it
(`inverse_design.app.resources.check_flat_panels`)."""

import pytest

from inverse_design import optimise as design_module
from inverse_design.app import cli

# A tapered bay 1 mm wide: chord 1 m at the root, 0.5 m at the tip. Its ribs pass the rounding check
# (the span edges are long diagonals), so the design would run; its panels do not lay flat.
CASE = """variables = ["pressure"]
n-span = 9
n-contour = 32
[[rib]]
section = "naca2412"
chord = 1.0
station = 0.0
[[rib]]
section = "naca2412"
chord = 0.5
station = 0.001
"""


def test_ribs_too_close_to_lay_the_panels_flat_are_refused_before_the_design(tmp_path, capsys, monkeypatch):
    designs = []

    def design(*args, **kwargs):
        designs.append(args)
        raise KeyboardInterrupt  # (stops a run that got this far)

    monkeypatch.setattr(design_module, "optimise_wing", design)
    case = tmp_path / "wing.toml"
    case.write_text(CASE)
    argv = ["--config", str(case), "--out", str(tmp_path / "out"), "--no-compilation-cache", "--quiet"]
    code = cli.main(argv)
    err = capsys.readouterr().err
    assert code == 2 and designs == [] and err.count("\n") == 1, err
    assert err.startswith("optimise-pressure: error: bay 0 (ribs 0 and 1, 0.001 m apart, chords 1 and 0.5 m): its "
                          "flat panels cannot be laid out at its cut lengths (the cut lengths cannot be laid flat")
    assert "--no-patterns" in err and not (tmp_path / "out").exists()
    # Without patterns there is nothing to lay out: the design starts.
    assert cli.main([*argv, "--no-patterns"]) == cli.EXIT_INTERRUPTED and len(designs) == 1


@pytest.mark.parametrize("spacing", ["0.25", "0.001"])
def test_a_bay_whose_panels_lay_flat_is_not_refused(tmp_path, capsys, monkeypatch, spacing):
    monkeypatch.setattr(design_module, "optimise_pressure", lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt))
    code = cli.main(["--rib-spacing", spacing, "--n-span", "5", "--n-contour", "32", "--variables", "pressure",
                     "--out", str(tmp_path / "out"), "--no-compilation-cache", "--quiet"])
    assert code == cli.EXIT_INTERRUPTED, capsys.readouterr().err  # (the design began)
