"""Where a cut file's texts and marks go: each where it overlaps none placed before and stays inside the
part, the nearest free place to where it belongs.

A `Text` is a line of text in millimetres; its box is estimated from its
characters (`text_width`: the widths of a wide sans-serif font, rounded up,
so that a text placed by it has room in any CAD program).
A `Layout` holds the boxes placed so far on one part (a panel's sewing
outline): `Layout.place` takes the boxes a text or group may take, in order
of preference, and keeps the first that is free: inside the outline, at least
its margin from it, overlapping no box placed before. Where none is free
(a part too small for its texts) the one that overlaps least is kept. NumPy
only: the report's workers import it without JAX.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np

__all__ = ["Layout", "Text", "grid_offsets", "line_box", "shifted", "text_box", "text_width"]

#: A character's width over the text's height (module docstring): the widths of a wide sans-serif font
#: (DejaVu Sans, which ezdxf and matplotlib draw with; a CAD font is no wider), rounded up.
_NARROW = dict.fromkeys("ijlIJ,.:;'!|", 0.4) | dict.fromkeys("ft-()/[]", 0.5) | {"r": 0.55, " ": 0.45}
_WIDE = dict.fromkeys("sz", 0.7) | {"c": 0.7} | dict.fromkeys("mwMW", 1.25) | dict.fromkeys("DGOQ", 1.0)
#: Below the baseline (descenders) and above the capitals (accents), over the height.
_BELOW, _ABOVE = 0.3, 0.1
#: mm: the least space between two placed boxes.
_CLEAR = 1.0
#: Places tried at once (their corners against the outline's edges: arrays of 4 x this x the edges).
_CHUNK = 256


class Text(NamedTuple):
    """A line of text, mm: at ``(x, y)`` by ``align`` (ezdxf's `TextEntityAlignment` names: ``LEFT``,
    ``CENTER`` and ``RIGHT`` on the baseline, ``MIDDLE_LEFT``, ``MIDDLE_CENTER``, ``MIDDLE_RIGHT``
    about the middle of the capitals), ``height`` the capitals' height, turned by ``rotation`` degrees
    counter-clockwise about ``(x, y)``."""

    x: float
    y: float
    height: float
    string: str
    align: str = "LEFT"
    rotation: float = 0.0


@functools.lru_cache(maxsize=4096)
def text_width(string: str, height: float) -> float:
    """The width of ``string`` at ``height`` (mm), estimated (module docstring; kept for the strings met
    last: a label's places in turn each ask it twice)."""
    return height * sum(_NARROW.get(c) or _WIDE.get(c) or (0.9 if c.isupper() else 0.8) for c in string)


def text_box(text: Text) -> np.ndarray:
    """``(x0, y0, x1, y1)`` the estimated box of a `Text`, descenders included (a turned text's box
    holds its turned box), mm."""
    w, h = text_width(text.string, text.height), text.height
    x0 = -(w if text.align.endswith("RIGHT") else 0.5 * w if text.align.endswith("CENTER") else 0.0)
    y0 = -0.5 * h if text.align.startswith("MIDDLE") else 0.0  # the baseline
    corners = np.array([[x0, y0 - _BELOW * h], [x0 + w, y0 - _BELOW * h], [x0 + w, y0 + (1.0 + _ABOVE) * h],
                        [x0, y0 + (1.0 + _ABOVE) * h]])
    c, s = np.cos(np.radians(text.rotation)), np.sin(np.radians(text.rotation))
    corners = corners @ np.array([[c, s], [-s, c]]) + (text.x, text.y)
    return np.concatenate([corners.min(axis=0), corners.max(axis=0)])


def line_box(points) -> np.ndarray:
    """``(x0, y0, x1, y1)`` the box of a polyline's points, mm."""
    p = np.asarray(points, np.float64)
    return np.concatenate([p.min(axis=0), p.max(axis=0)])


def shifted(items: list, offset) -> list:
    """`Text` lines and polylines moved by ``offset`` (mm)."""
    dx, dy = (float(v) for v in offset)
    return [t._replace(x=t.x + dx, y=t.y + dy) if isinstance(t, Text) else np.asarray(t) + (dx, dy)
            for t in items]


def grid_offsets(outline, origin, step: float | None = None) -> np.ndarray:
    """``(c, 2)`` offsets from ``origin`` to the points of a grid over ``outline``'s box, nearest first
    (the grid's step: ``step`` mm, or about 150 steps across the box's longer side)."""
    p = np.asarray(outline, np.float64)
    low, high = p.min(axis=0), p.max(axis=0)
    step = step or max(float(np.max(high - low)) / 150.0, 2.0)
    xs, ys = np.arange(low[0], high[0] + step, step), np.arange(low[1], high[1] + step, step)
    offsets = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2) - np.asarray(origin, np.float64)
    return offsets[np.argsort(np.hypot(offsets[:, 0], offsets[:, 1]), kind="stable")]


class Layout:
    """The boxes placed on one part so far (module docstring).

    Args:
        outline: ``(p, 2)`` the part's closed outline, mm.
        margin: the least distance of a box from the outline, mm.
    """

    def __init__(self, outline, margin: float):
        self.start = np.asarray(outline, np.float64)
        self.end = np.roll(self.start, -1, axis=0)
        self.margin = float(margin)
        self.boxes = np.empty((0, 4))

    def add(self, box) -> None:
        """Take ``box`` ``(x0, y0, x1, y1)`` as placed (a mark that does not move)."""
        self.boxes = np.vstack([self.boxes, np.asarray(box, np.float64).reshape(-1, 4)])

    def _overlap(self, boxes) -> np.ndarray:
        """``(c,)`` the area each of ``boxes`` ``(c, 4)`` overlaps the placed boxes (with `_CLEAR`), mm^2."""
        if not self.boxes.size:
            return np.zeros(len(boxes))
        p, q = self.boxes[None], boxes[:, None]
        width = np.minimum(q[..., 2], p[..., 2] + _CLEAR) - np.maximum(q[..., 0], p[..., 0] - _CLEAR)
        height = np.minimum(q[..., 3], p[..., 3] + _CLEAR) - np.maximum(q[..., 1], p[..., 1] - _CLEAR)
        return np.sum(np.clip(width, 0.0, None) * np.clip(height, 0.0, None), axis=1)

    def _outside(self, boxes, margin: float) -> np.ndarray:
        """``(c,)`` how many corners of each of ``boxes`` ``(c, 4)`` lie outside the outline or nearer it
        than ``margin`` (mm)."""
        points = boxes[:, [[0, 1], [2, 1], [2, 3], [0, 3]]].reshape(-1, 2)
        a, b = self.start, self.end
        # inside: an odd number of the outline's edges crossed by a ray along +x
        straddle = (a[None, :, 1] > points[:, None, 1]) != (b[None, :, 1] > points[:, None, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            cross_x = a[None, :, 0] + (points[:, None, 1] - a[None, :, 1]) * (b - a)[None, :, 0] / (b - a)[None, :, 1]
        inside = np.sum(straddle & (points[:, None, 0] < cross_x), axis=1) % 2 == 1
        # clear of the outline: a box's least distance from a (near) convex outline is at a corner
        ab = b - a
        t = np.clip(np.einsum("pkd,kd->pk", points[:, None] - a, ab) / np.sum(ab * ab, axis=1), 0.0, 1.0)
        distance = np.min(np.linalg.norm(points[:, None] - (a + t[..., None] * ab), axis=-1), axis=1)
        return np.sum(~(inside & (distance >= margin)).reshape(-1, 4), axis=1)

    def free(self, boxes, margin: float | None = None) -> np.ndarray:
        """``(c,)`` whether each of ``boxes`` ``(c, 4)`` is free (module docstring; ``margin``, mm: None,
        the layout's). The overlaps first: only the boxes clear of the others are tested against the
        outline."""
        boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
        ok = self._overlap(boxes) == 0.0
        ok[ok] = self._outside(boxes[ok], self.margin if margin is None else margin) == 0
        return ok

    def place(self, boxes, margin: float | None = None) -> int:
        """The index of the first of ``boxes`` ``(c, 4)``, in order of preference, that is free (where
        none is, the one that clashes least: its overlap with the placed boxes plus its area for each
        corner outside or too near the outline); that box is placed. ``margin``: this box's least
        distance from the outline, mm (None: the layout's)."""
        boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
        margin = self.margin if margin is None else margin
        first, size = 0, 1
        while first < len(boxes):  # in order, the preferred first: the first free one ends the search
            ok = self.free(boxes[first:first + size], margin)
            if ok.any():
                k = first + int(np.argmax(ok))
                break
            first, size = first + size, min(16 * size, _CHUNK)
        else:
            clash = np.concatenate([
                self._overlap(chunk) + self._outside(chunk, margin) * (chunk[:, 2] - chunk[:, 0]) * (
                    chunk[:, 3] - chunk[:, 1]) for chunk in np.split(boxes, range(_CHUNK, len(boxes), _CHUNK))])
            k = int(np.argmin(clash))  # (the first of the least)
        self.add(boxes[k])
        return k
