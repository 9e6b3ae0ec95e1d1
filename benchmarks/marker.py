"""The shop's marker: every panel of a wing nested on the roll by sparrow, against a shelf layout.

Four cases, each wing's panels as the command lays them out
(`inverse_design.app.case.Case` and `inverse_design.flat_panels.bay_panels`
at the case's starting parameters: the cut lengths of its starting
prestrains, no design, which moves them by about a percent), seam allowance
10 mm, gap 5 mm (the command's defaults):

* the default bay (NACA 2412, chord 1 m, ribs 0.25 m apart; 2 panels) on a 1,400 mm roll;
* the built-in 3-bay wing (``inverse_design/cases/wing_taper.toml``; 6 panels) on 1,400 mm;
* the 40-cell wing (``inverse_design/cases/wing_40_cells.toml``; 80 panels, the root's about 2.5 m
  around its section) on 2,600 mm with the warp along the span, and on 1,400 mm with the warp along
  the chord (the panels turned by 90 or 270 degrees).

Each is nested by sparrow (`inverse_design.marker.nest_panels`, its default
time limit, seed 0, `inverse_design.marker.NEST_WORKERS` threads) and laid out
in shelves of the panels' bounding boxes (``nester="shelf"``, first fit
decreasing height): the length of roll each takes, the utilisation (the cut
outlines' area over the roll's width times the length), the nesting time and
how much less roll sparrow takes. The machine is shared: its load is recorded.

Run (from the repository root):
    PYTHONPATH=. python benchmarks/marker.py            # every case: about 3 minutes on 2 cores
    PYTHONPATH=. python benchmarks/marker.py --cases bay,wing3
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.results import machine_description, print_result, save_result  # noqa: E402

CASES_FOLDER = ROOT / "inverse_design" / "cases"
#: name -> (what, command-line arguments of the case, roll width mm, warp)
CASES = {
    "bay": ("default bay", [], 1400.0, "span"),
    "wing3": ("built-in 3-bay wing", ["--config", str(CASES_FOLDER / "wing_taper.toml")], 1400.0, "span"),
    "wing40": ("40-cell wing", ["--config", str(CASES_FOLDER / "wing_40_cells.toml")], 2600.0, "span"),
    "wing40_chord": ("40-cell wing", ["--config", str(CASES_FOLDER / "wing_40_cells.toml")], 1400.0, "chord"),
}
COLUMNS = ["case", "panels", "warp", "roll width (mm)", "sparrow length (mm)", "sparrow utilisation",
           "sparrow seconds", "ended", "shelf length (mm)", "shelf utilisation", "less roll than shelf",
           "load start/end"]


def case_panels(arguments: list, warp: str) -> list:
    """The panels of a case as the command lays them out, at the case's starting parameters."""
    from inverse_design.app.case import Case
    from inverse_design.flat_panels import bay_panels

    case = Case.from_arguments([*arguments, "--warp", warp])
    o = case.options
    scenes = case.wing.scenes(case.fabric, n_span=o.n_span, n_contour=o.n_contour)
    return [panel for k, scene in enumerate(scenes) for panel in bay_panels(scene, case.start, bay=k)]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", default=",".join(CASES), help=f"comma-separated among {', '.join(CASES)}")
    parser.add_argument("--out", default="marker", help="the result file's stem in benchmarks/results")
    options = parser.parse_args(argv)
    from inverse_design.marker import MarkerRequest, nest_panels

    rows = []
    for name in options.cases.split(","):
        what, arguments, width, warp = CASES[name]
        panels = case_panels(arguments, warp)
        load = os.getloadavg()[0]
        start = time.perf_counter()
        nested = nest_panels(panels, MarkerRequest(roll_width_mm=width, warp=warp), progress=sys.stderr.isatty())
        print(f"{name}: nested in {time.perf_counter() - start:.1f} s", file=sys.stderr)
        shelf = nest_panels(panels, MarkerRequest(roll_width_mm=width, warp=warp, nester="shelf"))
        less = 1.0 - nested.length_mm / shelf.length_mm
        rows.append([what, len(panels), warp, width, round(nested.length_mm, 1), round(nested.utilisation, 4),
                     round(nested.seconds, 1), nested.ended, round(shelf.length_mm, 1), round(shelf.utilisation, 4),
                     f"{less:.1%}", f"{load:.1f}/{os.getloadavg()[0]:.1f}"])
        print(rows[-1], file=sys.stderr)
    notes = ["panels at each case's starting parameters (2% prestrain both ways), 17x64 nodes per bay; seam "
             "allowance 10 mm, gap 5 mm; sparrow's default time limit (inverse_design.marker.default_seconds), "
             "seed 0, 2 worker threads",
             "utilisation: the cut outlines' area over the roll's width times the length used; less roll than "
             "shelf: 1 - sparrow's length / the shelf layout's (first fit decreasing height of the bounding "
             "boxes, turned as the warp asks)",
             "ended: converged (sparrow's search ended on its own: the same marker every run) or time limit",
             f"machine shared with other work: load at each case's start and end in its row ({machine_description()})"]
    path = save_result(options.out, title="The shop's marker: the panels nested by sparrow against a shelf layout",
                       command="PYTHONPATH=. python benchmarks/marker.py"
                       + (f" --cases {options.cases}" if argv and "--cases" in argv else ""),
                       columns=COLUMNS, rows=rows, notes=notes)
    print_result(path, rows, notes)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
