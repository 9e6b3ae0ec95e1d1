"""The marker's files: ``marker.dxf`` (1:1, millimetres), ``marker.svg`` and a ``marker.png`` preview.

The marker (`inverse_design.marker.Marker`) is drawn in its own frame: ``x``
across the roll from one edge (0) to the other (the roll's width), ``y``
along it from its start. On the layers of the patterns (`cut_files.LAYERS`,
written by `cut_files.write_dxf` and `cut_files.write_svg`):

* ``CUT``: every panel's cut outline where it lies on the roll, the line the
  cutter follows (its pattern file's CUT line, moved or turned by 180 degrees,
  or by 90 and 270 with the warp along the chord);
* ``SEW``: every panel's sewing outline there;
* ``MARK``: each panel's label (``bay 3 upper``) at its middle and its WARP
  arrow beside it, along the roll; the roll's two edges and the end of the
  marker (the length used); a tick across each edge every metre along the
  roll, numbered in metres; the marker's title (roll width, length,
  utilisation, gap) before its start.

``marker.png`` shows the roll turned a quarter (its start on the left, its
length to the right: a turn, never a mirror), the cut outlines filled.
NumPy, ezdxf and matplotlib (Agg) only.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .cut_files import write_dxf, write_svg
from .mark_layout import Text, text_width
from .shop_marks import TEXT_HEIGHT, TITLE_HEIGHT
from .workers import save_figure

__all__ = ["MARKER_FILES", "marker_drawing", "write_marker_files", "write_marker_png"]

#: The marker's files in the output folder.
MARKER_FILES = ("marker.dxf", "marker.svg", "marker.png")
#: mm: a tick every this far along the roll.
_TICK_EVERY = 1000.0
#: mm: a metre tick's length across the roll, inward from each edge.
_TICK = 30.0
#: mm: a WARP arrow's length.
_ARROW = 60.0


def _label(piece) -> str:
    return f"bay {piece.bay} {piece.name}"


def _piece_marks(piece) -> tuple[list, list]:
    """A placed panel's label at the middle of its cut outline's box and its WARP arrow (along +y, the
    roll's length) beside it: ``(lines, texts)``."""
    lo, hi = piece.cut.min(axis=0), piece.cut.max(axis=0)
    x, y = 0.5 * (lo + hi)
    string = _label(piece)
    # a label along the panel's longer side: turned a quarter on a panel longer along the roll than across
    upright = (hi[1] - lo[1]) > (hi[0] - lo[0])
    texts = [Text(float(x), float(y), TITLE_HEIGHT, string, "MIDDLE_CENTER", 90.0 if upright else 0.0)]
    half = 0.5 * text_width(string, TITLE_HEIGHT)
    # the arrow beside the label: to its left (a label across the roll), or under it (a label along it)
    ax, ay = (x - half - 2.0 * TEXT_HEIGHT, y) if not upright else (x + 2.5 * TITLE_HEIGHT, y)
    tail, head = np.array([ax, ay - 0.5 * _ARROW]), np.array([ax, ay + 0.5 * _ARROW])
    lines = [np.array([tail, head]), np.array([head + (-3.0, -6.0), head, head + (3.0, -6.0)])]
    texts.append(Text(float(ax) - 0.5 * TEXT_HEIGHT - 4.0, float(ay), TEXT_HEIGHT, "WARP", "MIDDLE_CENTER", 90.0))
    return lines, texts


def marker_drawing(marker) -> dict:
    """The marker's drawing for `cut_files.write_dxf` (module docstring), mm."""
    width, length = marker.request.roll_width_mm, marker.length_mm
    lines = [np.array([[0.0, 0.0], [0.0, length]]), np.array([[width, 0.0], [width, length]]),
             np.array([[0.0, length], [width, length]])]
    texts = []
    for piece in marker.pieces:
        more, words = _piece_marks(piece)
        lines += more
        texts += words
    for k in range(1, int(length // _TICK_EVERY) + 1):
        y = k * _TICK_EVERY
        lines += [np.array([[0.0, y], [_TICK, y]]), np.array([[width - _TICK, y], [width, y]])]
        texts += [Text(-4.0, y, TEXT_HEIGHT, f"{k} m", "MIDDLE_RIGHT"),
                  Text(width + 4.0, y, TEXT_HEIGHT, f"{k} m", "MIDDLE_LEFT")]
    r = marker.request
    title = (f"MARKER  roll {width:g} mm wide, {length / 1000.0:.3f} m used, utilisation {marker.utilisation:.1%}, "
             f"{len(marker.pieces)} panels, gap {r.gap_mm:g} mm, warp along the roll, outside faces up, 1:1 mm")
    texts.append(Text(0.0, -2.0 * TITLE_HEIGHT, TITLE_HEIGHT, title))
    return {"CUT": [p.cut for p in marker.pieces], "SEW": [p.sew for p in marker.pieces], "MARK": lines,
            "text": texts}


def write_marker_png(path, marker, dpi: int = 100) -> Path:
    """A preview of the marker (module docstring): the roll turned a quarter, its start on the left."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    width, length = marker.request.roll_width_mm, marker.length_mm

    def turned(points):  # a quarter turn: along the roll to the right, across it upwards
        p = np.asarray(points, np.float64)
        return np.stack([p[:, 1], width - p[:, 0]], axis=1) / 1000.0

    size = (min(max(length / width * 3.0, 4.0), 24.0) + 1.0, 4.0)
    figure = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(figure)
    axes = figure.add_subplot()
    axes.fill_between([0.0, length / 1000.0], 0.0, width / 1000.0, color="#f4efe4", zorder=0)
    for piece in marker.pieces:
        outline = turned(piece.cut)
        axes.fill(outline[:, 0], outline[:, 1], facecolor="#9ecae1", edgecolor="#c0392b", linewidth=0.6)
        if len(marker.pieces) <= 40:
            x, y = outline.mean(axis=0)
            axes.text(x, y, _label(piece), ha="center", va="center", fontsize=5)
    axes.set_xlim(0.0, length / 1000.0)
    axes.set_ylim(0.0, width / 1000.0)
    axes.set_aspect("equal")
    axes.set_xlabel("along the roll (warp), m")
    axes.set_ylabel("across, m")
    axes.set_title(f"marker: {len(marker.pieces)} panels, {length / 1000.0:.3f} m of a {width:g} mm roll, "
                   f"utilisation {marker.utilisation:.1%}", fontsize=9)
    path = Path(path)
    save_figure(path, figure, dpi=dpi)
    return path


def write_marker_files(folder, marker, picture: bool = True) -> list[str]:
    """Write ``marker.dxf``, ``marker.svg`` and (with ``picture``) ``marker.png`` into ``folder``; return
    their names."""
    folder = Path(folder)
    drawing = marker_drawing(marker)
    write_dxf(folder / MARKER_FILES[0], drawing)
    write_svg(folder / MARKER_FILES[1], drawing)
    if not picture:
        return list(MARKER_FILES[:2])
    write_marker_png(folder / MARKER_FILES[2], marker)
    return list(MARKER_FILES)
