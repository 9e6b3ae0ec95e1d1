"""What the shop reads on the cut files, read back with ezdxf: every panel edge labelled with what it is
sewn to, the outside face, a scale bar, text readable at 1:1, and the rib templates' ticks numbered as the
panels' notches on their rib edges.

A tapered wing of two bays (NACA 2412, chords 1.0, 0.85 and 0.7 m, ribs 0.25 m apart, the small 5 x 32
grid), its files written as the report writes them (`patterns.write_bay_patterns`: bay 0 with ribs 0 and
1, bay 1 with rib 2, rib 1 written once), laid out from a prestrain with no solve: the files' marks
depend on the grid and the cut lengths only. On a tapered bay the root and tip edges differ only in
length; here each must say its rib (bay k lies between ribs k and k + 1).
"""

import numpy as np
import pytest

ezdxf = pytest.importorskip("ezdxf")

from ezdxf import bbox  # noqa: E402

from forward_solver import Fabric, Parameters, Wing  # noqa: E402
from inverse_design.app.patterns import write_bay_patterns  # noqa: E402
from inverse_design.flat_panels import mounted_skin  # noqa: E402
from targets import naca  # noqa: E402

N_SPAN, N_CONTOUR = 5, 32
DESIGN = Parameters(pressure=1e3, prestrain_span=0.02, prestrain_chord=0.01)
#: mm: how far a label may lie from the edge it names (its box from the edge's line).
NEAR = 30.0


@pytest.fixture(scope="module")
def wing(tmp_path_factory):
    af = naca("2412")
    scenes = Wing(airfoils=(af, af, af), chords=(1.0, 0.85, 0.7), stations=(0.0, 0.25, 0.5)).scenes(
        Fabric(), n_span=N_SPAN, n_contour=N_CONTOUR)
    out = tmp_path_factory.mktemp("shop")
    names = []
    for k, scene in enumerate(scenes):
        names += write_bay_patterns(out, scene, DESIGN, bay=k, ribs=(k if k == 0 else None, k + 1))[0]
    return out, scenes, [n for n in names if n.endswith(".dxf")]


def _texts(doc):
    """``[(string, height, box (x0, y0, x1, y1))]`` of a drawing's TEXT entities (ezdxf's boxes)."""
    out = []
    for t in doc.modelspace().query("TEXT"):
        e = bbox.extents([t])
        out.append((t.dxf.text, float(t.dxf.height), np.array([e.extmin.x, e.extmin.y, e.extmax.x, e.extmax.y])))
    return out


def _lines(doc, layer):
    return [np.asarray(e.get_points("xy"), np.float64) for e in doc.modelspace().query(f'LWPOLYLINE[layer=="{layer}"]')]


def _dense(points, per=20):
    """Points along a polyline, ``per`` to each segment."""
    p = np.asarray(points, np.float64)
    t = np.linspace(0.0, 1.0, per, endpoint=False)[None, :, None]
    return np.concatenate([(p[:-1, None] + t * (p[1:] - p[:-1])[:, None]).reshape(-1, 2), p[-1:]])


def _to_box(points, box) -> float:
    """The least distance from ``points`` to the rectangle ``box``, mm (0 inside it)."""
    centre, half = 0.5 * (box[:2] + box[2:]), 0.5 * (box[2:] - box[:2])
    return float(np.min(np.linalg.norm(np.maximum(np.abs(points - centre) - half, 0.0), axis=1)))


def _fibres(doc):
    """``(n_span, m, 2)`` the panel's developed grid, mm (GRID: one polyline per column, in panel order)."""
    return np.stack(_lines(doc, "GRID"), axis=1)


def _columns(scene, name):
    j_le = int(np.argmin(np.asarray(scene.bay.contour_root)[:, 0]))
    return np.arange(0, j_le + 1) if name == "upper" else np.r_[np.arange(j_le, N_CONTOUR), 0]


def test_every_panel_edge_says_what_it_is_sewn_to(wing):
    out, scenes, _ = wing
    seams = {"upper": ("TE seam: sew to lower panel", "LE seam: sew to lower panel"),
             "lower": ("LE seam: sew to upper panel", "TE seam: sew to upper panel")}
    for k in range(len(scenes)):
        for name in ("upper", "lower"):
            doc = ezdxf.readfile(out / f"pattern_bay_{k}_{name}.dxf")
            grid = _fibres(doc)
            edges = {"root": grid[0], "tip": grid[-1], "first": grid[:, 0], "last": grid[:, -1]}
            opposite = {"root": "tip", "tip": "root", "first": "last", "last": "first"}
            labels = {f"ROOT: sew to rib {k}": "root", f"TIP: sew to rib {k + 1}": "tip",
                      seams[name][0]: "first", seams[name][1]: "last"}
            texts = {s: (h, box) for s, h, box in _texts(doc)}
            for string, edge in labels.items():
                assert string in texts, (k, name, string, sorted(texts))
                box = texts[string][1]
                near, far = _to_box(_dense(edges[edge]), box), _to_box(_dense(edges[opposite[edge]]), box)
                assert near <= NEAR and near < 0.5 * far, (k, name, string, near, far)
            # the rib edges differ (a tapered bay): the longer root edge is the one labelled root
            root, tip = (float(np.sum(np.linalg.norm(np.diff(e, axis=0), axis=1))) for e in (grid[0], grid[-1]))
            assert root > tip


def test_the_panels_are_drawn_as_their_outside_face_is_seen_and_say_so(wing):
    out, scenes, _ = wing
    for k, scene in enumerate(scenes):
        nodes = mounted_skin(scene, DESIGN) * 1000.0  # mm
        for name, up in (("upper", 1.0), ("lower", -1.0)):
            doc = ezdxf.readfile(out / f"pattern_bay_{k}_{name}.dxf")
            flat = _fibres(doc)
            columns = _columns(scene, name)
            # the viewer looks along -z of the drawing: the skin's face seen is the one whose normal is the
            # 3D image of the drawing's +z (the cell's edges mapped, with the drawing's handedness)
            i, c = N_SPAN // 2, len(columns) // 2
            a2, b2 = flat[i, c + 1] - flat[i, c], flat[i + 1, c] - flat[i, c]
            a3, b3 = nodes[i, columns[c + 1]] - nodes[i, columns[c]], nodes[i + 1, columns[c]] - nodes[i, columns[c]]
            seen = np.sign(a2[0] * b2[1] - a2[1] * b2[0]) * np.cross(a3, b3)
            assert up * seen[2] > 0, (k, name)  # the upper panel seen from above, the lower from below
            # the mark: the text and, beside it, a mark that a mirrored cut shows mirrored
            texts = {s: box for s, _, box in _texts(doc)}
            assert "OUTSIDE FACE UP" in texts, (k, name)
            box = texts["OUTSIDE FACE UP"]
            beside = [p for p in _lines(doc, "MARK") if _to_box(p, box) < 15.0 and len(p) > 3
                      and np.ptp(p[:, 0]) > 5.0 and np.ptp(p[:, 1]) > 5.0]
            assert len(beside) == 1, (k, name)
            glyph = beside[0]
            mirrored = glyph * [-1.0, 1.0] + [glyph[:, 0].min() + glyph[:, 0].max(), 0.0]

            def segments(p):
                return {tuple(sorted((tuple(np.round(a, 6)), tuple(np.round(b, 6))))) for a, b in zip(p[:-1], p[1:])}

            assert segments(mirrored) != segments(glyph)


def test_each_drawing_has_a_100_mm_scale_bar(wing):
    out, _, names = wing
    assert {"rib_0.dxf", "rib_1.dxf", "rib_2.dxf"} <= set(names)
    for name in names:
        doc = ezdxf.readfile(out / name)
        (box,) = [box for s, _, box in _texts(doc) if s == "100 mm"]
        bar = min(_lines(doc, "MARK"), key=lambda p: _to_box(p, box))
        base = bar[bar[:, 1] == bar[:, 1].min()]
        assert np.ptp(base[:, 0]) == pytest.approx(100.0, abs=1e-9), name
        ticks = np.unique(np.round(bar[:, 0], 9))
        np.testing.assert_allclose(np.diff(ticks), 10.0, atol=1e-9, err_msg=name)
        assert len(ticks) == 11 and np.ptp(bar[:, 1]) >= 3.0, name


def test_every_text_is_readable_at_full_size(wing):
    out, _, names = wing
    for name in names:
        doc = ezdxf.readfile(out / name)
        texts = _texts(doc)
        assert texts and all(h >= 8.0 for _, h, _ in texts), (name, sorted({h for _, h, _ in texts}))
        assert {t.dxf.layer for t in doc.modelspace().query("TEXT")} == {"MARK"}, name
        boxes = np.array([box for _, _, box in texts])
        apart = ((boxes[:, None, 2] <= boxes[None, :, 0]) | (boxes[None, :, 2] <= boxes[:, None, 0])
                 | (boxes[:, None, 3] <= boxes[None, :, 1]) | (boxes[None, :, 3] <= boxes[:, None, 1]))
        np.fill_diagonal(apart, True)
        assert apart.all(), (name, [(texts[a][0], texts[b][0]) for a, b in zip(*np.nonzero(~apart))][:4])


def _number_at(texts, point, reach=40.0) -> int:
    """The number written nearest ``point`` (a TEXT of digits), within ``reach`` mm."""
    numbers = [(s, box) for s, _, box in texts if s.isdigit()]
    s, box = min(numbers, key=lambda item: _to_box(point[None], item[1]))
    assert _to_box(point[None], box) <= reach
    return int(s)


def _rib_ticks(doc) -> list[int]:
    """The numbers of a rib template's ticks in Selig order (along the outline from the trailing edge)."""
    outline = _lines(doc, "SEW")[0]
    texts = _texts(doc)
    ends = [t[-1] for t in _lines(doc, "MARK") if len(t) == 2]  # (a tick ends at its node on the outline)
    # each tick's place along the outline (Selig order): the segment its node lies on, and where on it
    place = []
    for e in ends:
        gaps = [_segment_distance(e, a, b) for a, b in zip(outline[:-1], outline[1:])]
        q = int(np.argmin(gaps))
        assert gaps[q] < 0.1  # mm: on the outline (the nodes lie on the section within 0.05 mm)
        place.append(q + np.linalg.norm(e - outline[q]) / np.linalg.norm(outline[q + 1] - outline[q]))
    return [_number_at(texts, ends[q]) for q in np.argsort(place, kind="stable")]


def _edge_notches(doc, row) -> list[int]:
    """The numbers of a panel's notches on one rib edge (``row`` 0 or -1), in the panel's column order."""
    grid = _fibres(doc)[row]
    texts = _texts(doc)
    notches = [p for p in _lines(doc, "MARK") if len(p) == 2]
    numbers = []
    for point in grid:
        through = [p for p in notches if _segment_distance(point, p[0], p[1]) < 1e-6]
        if through:
            numbers.append(_number_at(texts, point))
    return numbers


def _segment_distance(point, a, b) -> float:
    t = np.clip(np.dot(point - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
    return float(np.linalg.norm(point - (a + t * (b - a))))


def test_the_rib_ticks_carry_the_numbers_of_the_panel_notches_sewn_to_them(wing):
    out, scenes, _ = wing
    ticks = {r: _rib_ticks(ezdxf.readfile(out / f"rib_{r}.dxf")) for r in range(len(scenes) + 1)}
    for r, numbers in ticks.items():
        assert numbers == list(range(1, len(numbers) + 1)) and len(numbers) > 4, (r, numbers)
    for k in range(len(scenes)):
        for row, rib in ((0, k), (-1, k + 1)):
            upper = _edge_notches(ezdxf.readfile(out / f"pattern_bay_{k}_upper.dxf"), row)
            lower = _edge_notches(ezdxf.readfile(out / f"pattern_bay_{k}_lower.dxf"), row)
            # upper: trailing edge to leading edge; lower: leading edge round to the trailing edge
            assert upper[-1] == lower[0] and lower[-1] == upper[0], (k, row, upper, lower)
            assert upper + lower[1:-1] == ticks[rib], (k, row, rib, upper, lower, ticks[rib])
