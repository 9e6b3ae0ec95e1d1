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
  along both ribs and both seams, and at their ends; a double notch and
  "LE" at the leading edge; the warp (span fibre) direction as an arrow; the
  label (bay, panel, scale 1:1, seam allowance).
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
one at the leading edge, and the label, whose lines say which line is the
part and which the allowance.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..flat_layout import offset_outline, panel_outline

__all__ = ["HIDDEN_LAYERS", "LAYERS", "MARK_EVERY", "MM", "rib_mark_nodes", "write_panel_dxf", "write_panel_svg",
           "write_rib_dxf"]

#: Layer name -> AutoCAD colour index (red, blue, green, grey).
LAYERS = {"CUT": 1, "SEW": 5, "MARK": 3, "GRID": 8}
#: Layers that are off when a file is opened (module docstring).
HIDDEN_LAYERS = ("GRID",)
#: Alignment marks at every this many grid nodes along the ribs and the seams.
MARK_EVERY = 4
#: Notch length inside the sewing line, mm.
_NOTCH_IN = 3.0
#: Text height of labels, mm.
_TEXT = 8.0
#: Millimetres per metre (the drawings' unit).
MM = 1000.0


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
    "GRID": [open...], "text": [(x, y, height, string)]}``."""
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
            marks.append([sew[q] - _NOTCH_IN * normal[q], sew[q] + reach * normal[q]])
    text = []
    if panel.leading_edge is not None:
        k = panel.leading_edge
        along = flat[0, k] - flat[-1, k]
        along /= np.linalg.norm(along)
        for q, (i, kk) in enumerate(grid):
            if kk == k and i in (0, n - 1):  # a second notch 2 mm beside the first: the leading edge
                side = 2.0 * (along if i == 0 else -along)
                marks.append([sew[q] - _NOTCH_IN * normal[q] + side, sew[q] + reach * normal[q] + side])
        middle = 0.5 * (flat[0, k] + flat[-1, k])
        text.append((middle[0] + (-3.0 if k == m - 1 else 3.0) * _TEXT, middle[1], _TEXT, "LE"))
    # the warp: an arrow midway between the two middle span fibres, from a quarter to three quarters
    k = max(m // 2 - 1, 0)
    between = 0.5 * (flat[:, k] + flat[:, min(k + 1, m - 1)])
    tail, head = between[n // 4], between[(3 * (n - 1)) // 4 + (n == 2)]
    d = head - tail
    d /= np.linalg.norm(d)
    side = np.array([-d[1], d[0]])
    marks += [[tail, head], [head, head - 6.0 * d + 3.0 * side], [head, head - 6.0 * d - 3.0 * side]]
    text.append((tail[0] + 4.0, 0.5 * (tail[1] + head[1]), _TEXT, "WARP"))
    centre = np.mean(flat.reshape(-1, 2), axis=0)
    # The label runs across the span fibres (along the contour): below the arrow's tail, halfway to the
    # root rib, so that it never crosses the arrow (at the panel's centre it ran through it).
    below = tail - 0.5 * float(np.dot(tail - np.mean(flat[0], axis=0), d)) * d
    text.append((centre[0] - 0.25 * (flat[0, -1, 0] - flat[0, 0, 0]), below[1] - 0.5 * _TEXT, _TEXT,
                 f"bay {panel.bay} {panel.name} panel  scale 1:1 mm  seam allowance {seam_allowance_mm:g} mm"))
    fibres = [flat[:, k] for k in range(m)]
    return {"SEW": [sew], "CUT": [cut], "MARK": marks, "GRID": fibres, "text": text}


def _write_dxf(path, drawing: dict) -> Path:
    doc = _document()
    msp = doc.modelspace()
    for layer in ("SEW", "CUT"):
        for line in drawing[layer]:
            msp.add_lwpolyline([tuple(p) for p in line], close=True, dxfattribs={"layer": layer})
    for layer in ("MARK", "GRID"):
        for line in drawing.get(layer, []):
            msp.add_lwpolyline([tuple(p) for p in line], dxfattribs={"layer": layer})
    for x, y, height, string in drawing["text"]:
        msp.add_text(string, height=height, dxfattribs={"layer": "MARK"}).set_placement((float(x), float(y)))
    path = Path(path)
    doc.saveas(path)
    return path


def write_panel_dxf(path, panel, seam_allowance_mm: float = 10.0) -> Path:
    """Write one flat panel (`flat_layout.Panel`) as DXF, 1:1 in millimetres (module docstring)."""
    return _write_dxf(path, _panel_drawing(panel, seam_allowance_mm))


def write_panel_svg(path, panel, seam_allowance_mm: float = 10.0) -> Path:
    """Write one flat panel as SVG for a quick look (the DXF's lines, 1 user unit = 1 mm)."""
    drawing = _panel_drawing(panel, seam_allowance_mm)
    points = np.concatenate([np.concatenate(drawing[k]) for k in ("CUT", "MARK")])
    lo, hi = points.min(axis=0) - 2 * _TEXT, points.max(axis=0) + 2 * _TEXT
    width, height = hi - lo

    def xy(p):  # y up in the drawing, down in SVG
        return f"{p[0] - lo[0]:.3f},{hi[1] - p[1]:.3f}"

    colours = {"CUT": "red", "SEW": "blue", "MARK": "green", "GRID": "#bbbbbb"}
    body = []
    for layer in ("GRID", "SEW", "CUT", "MARK"):
        closed = layer in ("SEW", "CUT")
        for line in drawing[layer]:
            tag = "polygon" if closed else "polyline"
            body.append(f'<{tag} class="{layer}" points="{" ".join(xy(p) for p in line)}" fill="none" '
                        f'stroke="{colours[layer]}" stroke-width="0.5"/>')
    for x, y, size, string in drawing["text"]:
        body.append(f'<text x="{x - lo[0]:.3f}" y="{hi[1] - y:.3f}" font-size="{size:g}" '
                    f'fill="green">{string}</text>')
    svg = (f'<svg xmlns="http://www.w3.org/2000/svg" width="{width:.1f}mm" height="{height:.1f}mm" '
           f'viewBox="0 0 {width:.3f} {height:.3f}">\n' + "\n".join(body) + "\n</svg>\n")
    path = Path(path)
    path.write_text(svg)
    return path


def rib_mark_nodes(n_contour: int, leading_edge: int) -> list[int]:
    """The contour nodes of a rib that carry attachment marks: those the panels' rib edges mark (every
    `MARK_EVERY`-th panel column from each panel's first, and each panel's last), so the notches meet."""
    upper = [j for j in range(leading_edge + 1) if j % MARK_EVERY == 0 or j == leading_edge]
    lower_columns = list(range(leading_edge, n_contour)) + [0]
    lower = [j for k, j in enumerate(lower_columns) if k % MARK_EVERY == 0 or k == len(lower_columns) - 1]
    return sorted(set(upper + lower))


def write_rib_dxf(path, outline, nodes, label: str, seam_allowance_mm: float = 10.0) -> Path:
    """Write a rib template as DXF, 1:1 in millimetres (module docstring).

    Args:
        path: the file.
        outline: ``(n, 2)`` the rib's outline, x-z in metres, Selig order (`flat_panels.rib_template`).
        nodes: ``(n_contour, 2)`` the skin's nodes on the rib (the grid's contour nodes), x-z in metres.
        label: the rib's name and chord.
        seam_allowance_mm: the allowance, mm (>= 0).
    """
    sew = np.asarray(outline, np.float64) * MM
    keep = np.r_[True, np.linalg.norm(np.diff(sew, axis=0), axis=1) > 1e-9]
    sew = sew[keep]
    cut = offset_outline(sew, seam_allowance_mm)
    normal = _outward_normals(sew)
    attach = np.asarray(nodes, np.float64) * MM
    le = int(np.argmin(attach[:, 0]))
    marks = []
    for j in rib_mark_nodes(attach.shape[0], le):
        n = normal[int(np.argmin(np.linalg.norm(sew - attach[j], axis=1)))]  # the outline's normal there
        marks.append([attach[j] - (10.0 if j == le else 5.0) * n, attach[j]])  # the leading edge: longer
    height = 0.5 * _TEXT
    x0 = attach[le, 0] + 0.3 * (sew[:, 0].max() - attach[le, 0])
    y0 = float(np.mean(sew[:, 1])) + 0.5 * height
    lines = [f"{label}  scale 1:1 mm",
             "SEW (blue): the rib outline, the part: cut a rigid rib on this line",
             f"CUT (red): {seam_allowance_mm:g} mm outside, the seam allowance of a fabric rib, not the part"]
    text = [(x0, y0 - 1.5 * height * k, height, line) for k, line in enumerate(lines)]
    return _write_dxf(path, {"SEW": [sew], "CUT": [cut], "MARK": marks, "text": text})
