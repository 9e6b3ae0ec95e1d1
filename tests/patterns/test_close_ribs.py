"""Ribs so close that the flat panels cannot be laid out are refused before the design, not after it
(`inverse_design.app.design.check_flat_panels`)."""

import pytest

from inverse_design.app import cli, design
from support.cases import IN_PROCESS, SMALL, case_text

# A tapered bay 1 mm wide: chord 1 m at the root, 0.5 m at the tip. Its ribs pass the rounding check
# (the span edges are long diagonals), so the design would run; its panels do not lay flat.
CASE = case_text(("naca2412", 1.0, 0.0), ("naca2412", 0.5, 0.001), variables=["pressure"], n_span=9, n_contour=32)


def test_ribs_too_close_to_lay_the_panels_flat_are_refused_before_the_design(tmp_path, capsys, monkeypatch):
    designs = []

    def stop(*args, **kwargs):
        designs.append(args)
        raise KeyboardInterrupt  # (stops a run that got this far)

    monkeypatch.setattr(design, "optimise_wing", stop)
    case = tmp_path / "wing.toml"
    case.write_text(CASE)
    argv = ["--config", str(case), "--out", str(tmp_path / "out"), *IN_PROCESS]
    code = cli.main(argv)
    err = capsys.readouterr().err
    assert code == 2 and designs == [] and err.count("\n") == 1, err
    assert err.startswith("optimise-pressure: error: bay 0 (ribs 0 and 1, 0.001 m apart, chords 1 and 0.5 m): its "
                          "flat panels cannot be laid out at its cut lengths (the cut lengths cannot be laid flat")
    assert "--no-patterns" in err and not (tmp_path / "out").exists()
    # Without patterns there is nothing to lay out: the design starts.
    assert cli.main([*argv, "--no-patterns"]) == cli.EXIT_INTERRUPTED and len(designs) == 1


@pytest.mark.parametrize("spacing", ["0.25", "0.005"])  # (5 mm: close, yet far enough for the 5x32 grid)
def test_a_bay_whose_panels_lay_flat_is_not_refused(tmp_path, capsys, monkeypatch, spacing):
    monkeypatch.setattr(design, "optimise_wing", lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt))
    code = cli.main(["--rib-spacing", spacing, *SMALL, "--variables", "pressure", "--out", str(tmp_path / "out"),
                     *IN_PROCESS])
    assert code == cli.EXIT_INTERRUPTED, capsys.readouterr().err  # (the design began)
