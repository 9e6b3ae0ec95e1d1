"""What the shop reads on a cut file: edge labels, notch numbers, the outside-face mark and a scale bar.

A panel (`inverse_design.flat_layout.Panel`, drawn by `cut_files`) is sewn
along its four edges: its root rib edge to rib ``k`` and its tip rib edge to
rib ``k + 1`` (a wing's bay ``k`` lies between ribs ``k`` and ``k + 1``), and
its two seams, at the trailing and leading edges, to the bay's other panel.
`panel_marks` writes each edge's label inside the panel beside that edge,
numbers the notches of both rib edges, draws the warp arrow, the panel's
label, the outside-face mark and a scale bar; `rib_marks` numbers a rib
template's attachment ticks and writes its title, notes and scale bar.

The numbers: the marked contour nodes of a rib (`rib_mark_nodes`) are
numbered 1, 2, ... in Selig order, from the trailing edge over the upper
surface, the leading edge and the lower surface (`rib_mark_numbers`); the
template's tick at a node and every panel notch at that node on a rib edge
carry the same number, so tick 5 of rib 1 meets notch 5 of the tip edge of
bay 0 and of the root edge of bay 1.

The outside face: a panel is drawn as its outside face is seen
(`flat_panels.bay_panels`), so the fabric is laid outside face up under the
drawing; its texts read true, and the F beside "OUTSIDE FACE UP" reads
backwards on a panel cut mirrored.

Sizes in millimetres, at 1:1: every text is at least `TEXT_HEIGHT` (8 mm,
the capitals' height) high, and the scale bar is `SCALE_BAR` (100 mm) long
with a tick every 10 mm, so that a print can be checked with a ruler. Texts
and marks are placed by `mark_layout` (where they overlap nothing placed
before). NumPy only: the report's workers import this module without JAX.
"""

from __future__ import annotations

import numpy as np

from .mark_layout import Layout, Text, grid_offsets, line_box, shifted, text_box, text_width

__all__ = ["MARK_EVERY", "NOTCH_IN", "SCALE_BAR", "TEXT_HEIGHT", "TITLE_HEIGHT", "face_mark", "panel_marks",
           "rib_mark_nodes", "rib_mark_numbers", "rib_marks", "scale_bar"]

#: Alignment marks at every this many grid nodes along the ribs and the seams.
MARK_EVERY = 4
#: mm: a notch's length inside the sewing line.
NOTCH_IN = 3.0
#: mm: the height of numbers and notes, the least of any text (readable at 1:1).
TEXT_HEIGHT = 8.0
#: mm: the height of labels (the panel's, its edges', the outside face's, a rib's title).
TITLE_HEIGHT = 10.0
#: mm: the scale bar's length.
SCALE_BAR = 100.0
#: mm: the space between a mark and the text beside it.
_GAP = 2.0
#: Where an edge's label may go: fractions of the edge's length, and further inward (mm): the middle
#: first, then sliding along the edge.
_ALONG = [(0.5 + side * f, extra) for f in np.arange(0.0, 0.41, 0.05) for side in (1, -1) for extra in (0.0, 6.0)]


def rib_mark_nodes(n_contour: int, leading_edge: int | None) -> list[int]:
    """The contour nodes of a rib that carry attachment marks: those the panels' rib edges mark (every
    `MARK_EVERY`-th panel column from each panel's first, and each panel's last), so the notches meet.
    ``leading_edge`` None: one panel of every column (a flat test panel)."""
    if leading_edge is None:
        return [j for j in range(n_contour) if j % MARK_EVERY == 0 or j == n_contour - 1]
    upper = [j for j in range(leading_edge + 1) if j % MARK_EVERY == 0 or j == leading_edge]
    lower_columns = list(range(leading_edge, n_contour)) + [0]
    lower = [j for k, j in enumerate(lower_columns) if k % MARK_EVERY == 0 or k == len(lower_columns) - 1]
    return sorted(set(upper + lower))


def rib_mark_numbers(n_contour: int, leading_edge: int | None) -> dict[int, int]:
    """``{contour node: number}`` of a rib's marked nodes, 1, 2, ... in Selig order (module docstring)."""
    return {j: number for number, j in enumerate(rib_mark_nodes(n_contour, leading_edge), start=1)}


def _beside(point, direction, string: str, height: float, gap: float, rotation: float = 0.0) -> Text:
    """``string`` centred on the line from ``point`` along the unit ``direction``, turned by ``rotation``
    degrees, its (estimated) box ``gap`` away from ``point``: a box of half-sides ``w / 2`` along the
    text and ``1.4 h / 2`` across it (descenders too) reaches their projections on ``direction``."""
    d = np.asarray(direction, np.float64)
    c, s = np.cos(np.radians(rotation)), np.sin(np.radians(rotation))
    reach = 0.5 * (text_width(string, height) * abs(c * d[0] + s * d[1]) + 1.4 * height * abs(-s * d[0] + c * d[1]))
    centre = np.asarray(point, np.float64) + (gap + reach) * d
    return Text(float(centre[0]), float(centre[1]), height, string, "MIDDLE_CENTER", rotation)


def scale_bar(x: float, y: float, length: float = SCALE_BAR) -> list:
    """A scale bar from ``(x, y)`` along +x, mm: ``[polyline, Text]``, one polyline for the bar with a
    tick up every 10 mm (3 mm; the ends and the middle 6 mm), and its length after it."""
    points = []
    ticks = round(length / 10.0)
    for k in range(ticks + 1):
        tick = 6.0 if k in (0, ticks // 2, ticks) else 3.0
        x_k = x + min(10.0 * k, length)
        points += [(x_k, y), (x_k, y + tick), (x_k, y)]
    text = Text(x + length + 2.0 * _GAP, y, TEXT_HEIGHT, f"{length:g} mm")
    return [np.asarray(points, np.float64), text]


def face_mark(x: float, y: float) -> list:
    """The outside-face mark, mm, its lower left corner at ``(x, y)``: ``[polyline, Text]``, an F drawn
    as one polyline (it reads backwards on a panel cut mirrored) and "OUTSIDE FACE UP" beside it."""
    h = 2.0 * TITLE_HEIGHT
    w = 0.6 * h
    glyph = np.array([(x + w, y + h), (x, y + h), (x, y + 0.5 * h), (x + 0.8 * w, y + 0.5 * h), (x, y + 0.5 * h),
                      (x, y)])
    return [glyph, Text(x + w + 3.0 * _GAP, y + 0.5 * (h - TITLE_HEIGHT), TITLE_HEIGHT, "OUTSIDE FACE UP")]


def _along(points, fraction: float, centre) -> tuple[np.ndarray, np.ndarray]:
    """The point at ``fraction`` of a polyline's length and the unit normal there towards ``centre``."""
    p = np.asarray(points, np.float64)
    length = np.linalg.norm(np.diff(p, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(length)])
    s = fraction * arc[-1]
    e = min(int(np.searchsorted(arc, s, side="right")) - 1, len(length) - 1)
    point = p[e] + (s - arc[e]) / length[e] * (p[e + 1] - p[e])
    tangent = (p[e + 1] - p[e]) / length[e]
    normal = np.array([-tangent[1], tangent[0]])
    return point, normal if np.dot(normal, np.asarray(centre) - point) >= 0 else -normal


def _seam_names(name: str) -> tuple[str, str]:
    """The labels of a panel's first and last columns' edges: the seams and the panel they are sewn to."""
    if name == "upper":
        return "TE seam: sew to lower panel", "LE seam: sew to lower panel"
    if name == "lower":
        return "LE seam: sew to upper panel", "TE seam: sew to upper panel"
    return "SIDE: first contour node", "SIDE: last contour node"


def _edge_label(layout: Layout, points, string: str, gap: float, centre, turned: bool = False) -> Text:
    """An edge's label inside the panel beside the edge, at its middle or, where that is taken, near it;
    ``turned``: along the edge, reading upward, where it fits (a seam), else level."""
    places = {}  # fraction -> (point, inward normal): each fraction serves four options

    def option(along: bool, fraction: float, extra: float) -> Text:
        if fraction not in places:
            places[fraction] = _along(points, fraction, centre)
        point, inward = places[fraction]
        rotation = 0.0
        if along:  # the edge's direction that points up the span: read from the root
            u = (-inward[1], inward[0]) if inward[0] >= 0 else (inward[1], -inward[0])
            rotation = float(np.degrees(np.arctan2(u[1], u[0])))
        return _beside(point, inward, string, TITLE_HEIGHT, gap + extra, rotation)

    # The places in order of preference, built a few at a time (most labels take one of the first): the
    # first free one is kept, as `Layout.place` keeps it; where none is, the one that clashes least.
    preferred = [(along, fraction, extra) for along in ((True, False) if turned else (False,))
                 for fraction, extra in _ALONG]
    options, boxes = [], []
    for end in (1, 17, len(preferred)):
        new = [option(*p) for p in preferred[len(options):end]]
        new_boxes = [text_box(t) for t in new]
        free = layout.free(np.array(new_boxes)) if new else np.zeros(0, bool)
        options, boxes = options + new, boxes + new_boxes
        if free.any():
            k = len(options) - len(new) + int(np.argmax(free))
            layout.add(boxes[k])
            return options[k]
    return options[layout.place(np.array(boxes))]


def _group(layout: Layout, items: list, outline) -> list:
    """Texts and polylines built where they belong, moved together to the nearest free place."""
    boxes = np.array([text_box(t) if isinstance(t, Text) else line_box(t) for t in items])
    box = np.concatenate([boxes[:, :2].min(axis=0), boxes[:, 2:].max(axis=0)])
    offsets = np.vstack([[0.0, 0.0], grid_offsets(outline, 0.5 * (box[:2] + box[2:]))])
    return shifted(items, offsets[layout.place(box[None] + offsets[:, [0, 1, 0, 1]])])


def panel_marks(panel, flat, sew, grid, normal, seam_allowance_mm: float) -> tuple[list, list[Text]]:
    """The marks and texts a panel's drawing carries for the shop (module docstring), mm.

    Placed in turn, each where it overlaps nothing before (`mark_layout.Layout`): the rib edges' notch
    numbers and the warp arrow where they belong; each edge's label beside its edge; the warp's text,
    the panel's label, the outside-face mark and the scale bar beside the arrow.

    Args:
        panel: the `flat_layout.Panel` (its bay, name, columns, leading edge).
        flat: ``(n_span, m, 2)`` its developed grid, mm.
        sew: ``(p, 2)`` its sewing outline, mm (`flat_layout.panel_outline`).
        grid: ``(p, 2)`` the ``[i, k]`` grid node of each outline point.
        normal: ``(p, 2)`` the outline's unit outward normal at each point.
        seam_allowance_mm: the seam allowance, mm (the label says it).

    Returns:
        ``(lines, texts)``: open polylines (the warp arrow, the F, the scale bar) and `Text` lines.
    """
    n, m = flat.shape[:2]
    centre = np.mean(flat.reshape(-1, 2), axis=0)
    layout = Layout(sew, NOTCH_IN + _GAP)
    n_contour = int(np.max(panel.columns)) + 1  # (the upper panel's numbers need none of the lower's nodes)
    numbers = rib_mark_numbers(n_contour, panel.leading_edge)
    texts = []
    for q, (i, k) in enumerate(grid):  # the rib edges' notches, numbered as the ribs' ticks
        j = int(panel.columns[k])
        if i in (0, n - 1) and (k % MARK_EVERY == 0 or k == m - 1) and j in numbers:
            options = [_beside(sew[q], -normal[q], str(numbers[j]), TEXT_HEIGHT, NOTCH_IN + _GAP + stagger)
                       for stagger in (0.0, 1.5 * TEXT_HEIGHT, 3.0 * TEXT_HEIGHT)]  # (crowded: further in)
            texts.append(options[layout.place(np.array([text_box(t) for t in options]), margin=0.0)])
    # the warp (the roll's length): along the span fibres, an arrow midway between the two middle ones
    # from a quarter to three quarters of the span; along the contour rows (warp "chord"), midway
    # between the two middle rows over the middle half of the contour
    if panel.warp == "span":
        k = max(m // 2 - 1, 0)
        between = 0.5 * (flat[:, k] + flat[:, min(k + 1, m - 1)])
        tail, head = between[n // 4], between[(3 * (n - 1)) // 4 + (n == 2)]
    else:
        i = max(n // 2 - 1, 0)
        between = 0.5 * (flat[i] + flat[min(i + 1, n - 1)])
        tail, head = between[m // 4], between[(3 * (m - 1)) // 4 + (m == 2)]
    d = (head - tail) / np.linalg.norm(head - tail)
    side = np.array([-d[1], d[0]])
    arrow = [np.array([tail, head]), np.array([head, head - 6.0 * d + 3.0 * side]),
             np.array([head, head - 6.0 * d - 3.0 * side])]
    for t in np.linspace(0.0, 1.0, int(np.linalg.norm(head - tail) // 4.0) + 2):  # (small boxes along it: one
        point = tail + t * (head - tail)                                              # box of a slanted arrow
        layout.add(np.concatenate([point - 3.0, point + 3.0]))                        # would take too much)
    # each edge's label beside its edge (along which it can move)
    first, last = _seam_names(panel.name)
    clear = NOTCH_IN + 2.0 * _GAP + 1.4 * TEXT_HEIGHT  # (the rib edges' labels: past the notch numbers)
    for points, string, gap, seam in ((flat[0], f"ROOT: sew to rib {panel.bay}", clear, False),
                                      (flat[-1], f"TIP: sew to rib {panel.bay + 1}", clear, False),
                                      (flat[:, 0], first, NOTCH_IN + _GAP, True),
                                      (flat[:, -1], last, NOTCH_IN + _GAP, True)):
        texts.append(_edge_label(layout, points, string, gap, centre, turned=seam))
    # beside the arrow: the warp's text; left of it the panel's label, the outside face under it; right of
    # it the scale bar
    middle = 0.5 * (tail + head)
    texts += _group(layout, [Text(float(max(tail[0], head[0])) + 4.0, float(middle[1]), TEXT_HEIGHT, "WARP")], sew)
    right = float(min(tail[0], head[0])) - 5.0 * _GAP
    texts += _group(layout, [
        Text(right, float(middle[1]) + 2.0 * _GAP, TITLE_HEIGHT, f"bay {panel.bay} {panel.name} panel", "RIGHT"),
        Text(right, float(middle[1]) - 2.0 * _GAP - TEXT_HEIGHT, TEXT_HEIGHT,
             f"scale 1:1 mm, seam allowance {seam_allowance_mm:g} mm", "RIGHT")], sew)
    face = face_mark(0.0, 0.0)
    wide = max(text_box(t)[2] for t in face[1:])
    face = _group(layout, shifted(face, (right - wide, float(middle[1]) - 5.0 * TITLE_HEIGHT)), sew)
    bar = _group(layout, scale_bar(float(max(tail[0], head[0])) + 5.0 * _GAP, float(middle[1]) - 3.0 * TEXT_HEIGHT),
                 sew)
    return arrow + [face[0], bar[0]], texts + face[1:] + bar[1:]


def rib_marks(sew, cut, attach, normal_at, seam_allowance_mm: float, title: str,
              notes: list[str]) -> tuple[list, list[Text]]:
    """The numbers of a rib template's ticks outside its cut line, its title inside the outline, and its
    notes and scale bar under it (module docstring).

    Args:
        sew: ``(p, 2)`` the rib outline, mm, Selig order.
        cut: ``(q, 2)`` the cut line, mm.
        attach: ``(n_contour, 2)`` the skin's nodes on the rib, mm.
        normal_at: ``normal_at(j)``, the outline's unit outward normal at node ``j``.
        seam_allowance_mm: the allowance, mm (the cut line's distance).
        title: the short label inside the outline (``"rib 1"``).
        notes: the lines under the outline.

    Returns:
        ``(lines, texts)``: the scale bar, and `Text` lines.
    """
    # outside the cut line, which a sharp trailing edge rounds within sqrt(2) of the allowance
    beyond = np.sqrt(2.0) * seam_allowance_mm + _GAP
    leading_edge = int(np.argmin(attach[:, 0]))
    texts = [_beside(attach[j], normal_at(j), str(number), TEXT_HEIGHT, beyond)
             for j, number in rib_mark_numbers(attach.shape[0], leading_edge).items()]
    # the title between the surfaces at 30% of the chord, where a section is near its thickest
    low, high = float(np.min(sew[:, 0])), float(np.max(sew[:, 0]))
    x = low + 0.3 * (high - low)
    nose = int(np.argmin(sew[:, 0]))
    z = [float(np.interp(x, *(s[np.argsort(s[:, 0])].T))) for s in (sew[: nose + 1], sew[nose:])]
    if abs(z[0] - z[1]) > 2.0 * TITLE_HEIGHT:
        texts.append(Text(x, 0.5 * (z[0] + z[1]), TITLE_HEIGHT, title, "MIDDLE_CENTER"))
    else:  # (too thin for it: with the notes)
        notes = [title, *notes]
    # the notes, then the scale bar, under the numbers and the cut line
    bottom = min(float(np.min(cut[:, 1])), min(float(text_box(t)[1]) for t in texts))
    step = 1.6 * TEXT_HEIGHT
    top = bottom - 2.0 * _GAP - TEXT_HEIGHT
    texts += [Text(low, top - step * k, TEXT_HEIGHT, line) for k, line in enumerate(notes)]
    bar = scale_bar(low, top - step * len(notes) - 2.0 * TEXT_HEIGHT)
    return [bar[0]], texts + [bar[1]]
