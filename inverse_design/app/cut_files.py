"""Cut-ready files of a design: flat panels and rib templates as DXF (1:1, millimetres) and SVG.

Each panel of each bay (`inverse_design.flat_panels.bay_panels`: an airfoil
bay's ``upper`` and ``lower`` panels, split at the trailing and leading
edges) is one DXF file ``pattern_bay_K_NAME.dxf`` and one SVG file for a
quick look; each rib is a template ``rib_R.dxf``. Drawing units are
millimetres (``$INSUNITS`` 4), drawn at scale 1:1, on these layers:

* ``SEW``: the sewing (bonding) line, a closed polyline through the panel's
  boundary nodes: the root rib's edge, the panel's last span fibre, the tip
  rib's edge, its first span fibre. Its edges are the design's cut lengths
  (`rib_design.cut_lengths`).
* ``CUT``: the cut line, the sewing line offset outward by the seam allowance
  (`flat_layout.offset_outline`).
* ``MARK``: alignment notches across the seam allowance (from 3 mm inside
  the sewing line out to the cut line) at every `MARK_EVERY`-th grid node
  along both ribs and both seams, and at their ends; a double notch at the
  leading edge; and what the shop reads (`shop_marks.panel_marks`): the rib
  edges' notch numbers, each edge's label (its rib, or its seam and the
  panel it is sewn to), the warp direction as an arrow (the span fibres, or
  the contour rows for a fabric whose warp runs along the chord), the
  label (bay, panel, scale 1:1, seam allowance), the outside-face mark and a
  100 mm scale bar. Every text is on this layer, at least 8 mm high.
* ``GRID``: the developed grid's span fibres (one open polyline per contour
  node, through its span nodes): the reference the sewing line and marks
  come from, for checking; not to be cut. The layer is off in the file (a
  cutter or viewer shows it only when it is switched on).

A rib template draws the rib itself (`flat_panels.rib_template`): the designed
section (thickness and chord scales and rib shape applied, as the solver
mounts it) at its chord, from the section's smooth contour with a chordal
error below `flat_panels.RIB_CHORDAL_ERROR` (0.05 mm), not the grid's polygon:
``SEW`` the rib outline, the part itself (a rigid rib is cut on it);
``CUT`` offset outward by the seam allowance, the allowance of a fabric rib
(not the part); ``MARK`` attachment ticks at the skin's nodes (the grid's
contour nodes on the rib) where the panels' rib edges have their marks
(every `MARK_EVERY`-th node from the trailing and leading edges), a longer
one at the leading edge, each numbered as the panels' notches that meet it
(`shop_marks.rib_marks`), the rib's name inside the outline, and under it
the notes, whose lines say which line is the part and which the allowance,
and a 100 mm scale bar.

A panel is drawn as its outside face is seen (`flat_panels.bay_panels`);
the SVG's text is sized so that its capitals are as high as the DXF's.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..flat_layout import offset_outline, panel_outline
from .shop_marks import MARK_EVERY, NOTCH_IN, TEXT_HEIGHT, panel_marks, rib_mark_nodes, rib_marks

__all__ = ["HIDDEN_LAYERS", "LAYERS", "MARK_EVERY", "MM", "rib_mark_nodes", "write_dxf", "write_panel_dxf",
           "write_panel_files", "write_panel_svg", "write_rib_dxf", "write_svg"]

#: Layer name -> AutoCAD colour index (red, blue, green, grey).
LAYERS = {"CUT": 1, "SEW": 5, "MARK": 3, "GRID": 8}
#: Layers that are off when a file is opened (module docstring).
HIDDEN_LAYERS = ("GRID",)
#: Millimetres per metre (the drawings' unit).
MM = 1000.0
#: A sans-serif font's capital height over its font size (SVG sizes a font by its em; DXF by its capitals).
_CAP_HEIGHT = 0.72


def _document():
    import ezdxf

    doc = ezdxf.new("R2010", units=ezdxf.units.MM)  # $INSUNITS 4: millimetres
    for name, colour in LAYERS.items():
        layer = doc.layers.add(name, color=colour)
        if name in HIDDEN_LAYERS:
            layer.off()  # kept for checking, not drawn or cut unless switched on
    return doc


def _outward_normals(points) -> np.ndarray:
    """Unit outward normal of a closed polygon at each vertex (the mean of its two edges')."""
    p = np.asarray(points, np.float64)
    area = 0.5 * np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1])
    edge = np.roll(p, -1, axis=0) - p
    edge /= np.linalg.norm(edge, axis=1, keepdims=True)
    normal = (1.0 if area > 0 else -1.0) * np.stack([edge[:, 1], -edge[:, 0]], axis=1)
    mean = normal + np.roll(normal, 1, axis=0)
    return mean / np.linalg.norm(mean, axis=1, keepdims=True)


def _panel_drawing(panel, seam_allowance_mm: float) -> dict:
    """The panel's lines in millimetres, by layer: ``{"SEW": [closed], "CUT": [closed], "MARK": [open...],
    "GRID": [open...], "text": [shop_marks.Text]}``."""
    flat = panel.flat * MM
    n, m = flat.shape[:2]
    sew, grid = panel_outline(flat)
    cut = offset_outline(sew, seam_allowance_mm)
    normal = _outward_normals(sew)
    reach = max(seam_allowance_mm, 2.0)
    marks = []
    for q, (i, k) in enumerate(grid):
        on_rib = i in (0, n - 1) and (k % MARK_EVERY == 0 or k == m - 1)
        on_seam = k in (0, m - 1) and (i % MARK_EVERY == 0 or i == n - 1)
        if on_rib or on_seam:
            marks.append([sew[q] - NOTCH_IN * normal[q], sew[q] + reach * normal[q]])
    if panel.leading_edge is not None:
        k = panel.leading_edge
        along = flat[0, k] - flat[-1, k]
        along /= np.linalg.norm(along)
        for q, (i, kk) in enumerate(grid):
            if kk == k and i in (0, n - 1):  # a second notch 2 mm beside the first: the leading edge
                side = 2.0 * (along if i == 0 else -along)
                marks.append([sew[q] - NOTCH_IN * normal[q] + side, sew[q] + reach * normal[q] + side])
    lines, text = panel_marks(panel, flat, sew, grid, normal, seam_allowance_mm)
    fibres = [flat[:, k] for k in range(m)]
    return {"SEW": [sew], "CUT": [cut], "MARK": marks + lines, "GRID": fibres, "text": text}


def write_dxf(path, drawing: dict) -> Path:
    """Write a drawing as DXF, 1:1 in millimetres: ``drawing`` is ``{"SEW": [closed polylines], "CUT":
    [closed], "MARK": [open], "GRID": [open] (optional), "text": [mark_layout.Text]}``, points in mm, on
    the layers of those names (`LAYERS`; texts on MARK). The panels, the ribs and the marker are drawn so."""
    from ezdxf.enums import TextEntityAlignment

    doc = _document()
    msp = doc.modelspace()
    for layer in ("SEW", "CUT"):
        for line in drawing[layer]:
            msp.add_lwpolyline([tuple(p) for p in line], close=True, dxfattribs={"layer": layer})
    for layer in ("MARK", "GRID"):
        for line in drawing.get(layer, []):
            msp.add_lwpolyline([tuple(p) for p in line], dxfattribs={"layer": layer})
    for t in drawing["text"]:
        msp.add_text(t.string, height=t.height, rotation=t.rotation, dxfattribs={"layer": "MARK"}).set_placement(
            (float(t.x), float(t.y)), align=TextEntityAlignment[t.align])
    path = Path(path)
    doc.saveas(path)
    return path


def write_panel_dxf(path, panel, seam_allowance_mm: float = 10.0) -> Path:
    """Write one flat panel (`flat_layout.Panel`) as DXF, 1:1 in millimetres (module docstring)."""
    return write_dxf(path, _panel_drawing(panel, seam_allowance_mm))


def write_panel_svg(path, panel, seam_allowance_mm: float = 10.0) -> Path:
    """Write one flat panel as SVG for a quick look (the DXF's lines, 1 user unit = 1 mm; a text's
    font size is its capitals' height over `_CAP_HEIGHT`, so that its capitals are as high as the DXF's)."""
    return write_svg(path, _panel_drawing(panel, seam_allowance_mm))


def write_panel_files(path, panel, seam_allowance_mm: float = 10.0) -> tuple[Path, Path]:
    """`write_panel_dxf` to ``path`` and `write_panel_svg` beside it (``path`` with the suffix ``.svg``)
    from one drawing: the panel's marks are placed once for both. Returns both paths."""
    drawing = _panel_drawing(panel, seam_allowance_mm)
    path = Path(path)
    return write_dxf(path, drawing), write_svg(path.with_suffix(".svg"), drawing)


def write_svg(path, drawing: dict) -> Path:
    """Write a drawing (`write_dxf`'s) as SVG for a quick look: 1 user unit = 1 mm, y up as in the DXF."""
    from xml.sax.saxutils import escape

    points = np.concatenate([np.concatenate(drawing[k]) for k in ("CUT", "MARK")])
    lo, hi = points.min(axis=0) - 2 * TEXT_HEIGHT, points.max(axis=0) + 2 * TEXT_HEIGHT
    width, height = hi - lo

    def xy(p):  # y up in the drawing, down in SVG
        return f"{p[0] - lo[0]:.3f},{hi[1] - p[1]:.3f}"

    colours = {"CUT": "red", "SEW": "blue", "MARK": "green", "GRID": "#bbbbbb"}
    body = []
    for layer in ("GRID", "SEW", "CUT", "MARK"):
        closed = layer in ("SEW", "CUT")
        for line in drawing.get(layer, []):
            tag = "polygon" if closed else "polyline"
            body.append(f'<{tag} class="{layer}" points="{" ".join(xy(p) for p in line)}" fill="none" '
                        f'stroke="{colours[layer]}" stroke-width="0.5"/>')
    for t in drawing["text"]:
        anchor = "end" if t.align.endswith("RIGHT") else "middle" if t.align.endswith("CENTER") else "start"
        y = t.y - 0.5 * t.height if t.align.startswith("MIDDLE") else t.y  # (SVG's y is the baseline)
        turn = f' transform="rotate({-t.rotation:g} {t.x - lo[0]:.3f} {hi[1] - t.y:.3f})"' if t.rotation else ""
        body.append(f'<text x="{t.x - lo[0]:.3f}" y="{hi[1] - y:.3f}" font-size="{t.height / _CAP_HEIGHT:.3f}" '
                    f'text-anchor="{anchor}" font-family="sans-serif" fill="green"{turn}>{escape(t.string)}</text>')
    svg = (f'<svg xmlns="http://www.w3.org/2000/svg" width="{width:.1f}mm" height="{height:.1f}mm" '
           f'viewBox="0 0 {width:.3f} {height:.3f}">\n' + "\n".join(body) + "\n</svg>\n")
    path = Path(path)
    path.write_text(svg)
    return path


def write_rib_dxf(path, outline, nodes, label: str, seam_allowance_mm: float = 10.0, title: str | None = None) -> Path:
    """Write a rib template as DXF, 1:1 in millimetres (module docstring).

    Args:
        path: the file.
        outline: ``(n, 2)`` the rib's outline, x-z in metres, Selig order (`flat_panels.rib_template`).
        nodes: ``(n_contour, 2)`` the skin's nodes on the rib (the grid's contour nodes), x-z in metres.
        label: the rib's name and chord.
        seam_allowance_mm: the allowance, mm (>= 0).
        title: the short name inside the outline (``"rib 1"``; None: the label up to its first comma).
    """
    sew = np.asarray(outline, np.float64) * MM
    keep = np.r_[True, np.linalg.norm(np.diff(sew, axis=0), axis=1) > 1e-9]
    sew = sew[keep]
    cut = offset_outline(sew, seam_allowance_mm)
    normal = _outward_normals(sew)
    attach = np.asarray(nodes, np.float64) * MM
    le = int(np.argmin(attach[:, 0]))

    def normal_at(j):  # the outline's normal at its point nearest the node
        return normal[int(np.argmin(np.linalg.norm(sew - attach[j], axis=1)))]

    marks = [[attach[j] - (10.0 if j == le else 5.0) * normal_at(j), attach[j]]  # the leading edge: longer
             for j in rib_mark_nodes(attach.shape[0], le)]
    notes = [f"{label}  scale 1:1 mm",
             "SEW (blue): the rib outline, the part: cut a rigid rib on this line",
             f"CUT (red): {seam_allowance_mm:g} mm outside, the seam allowance of a fabric rib, not the part",
             "numbers: each tick meets the panels' notches of the same number"]
    lines, text = rib_marks(sew, cut, attach, normal_at, seam_allowance_mm,
                            label.split(",")[0] if title is None else title, notes)
    return write_dxf(path, {"SEW": [sew], "CUT": [cut], "MARK": marks + lines, "text": text})
