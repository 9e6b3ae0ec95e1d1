"""The shop's marker: every panel of a wing nested on the fabric roll, grain-true.

A roll's length is its warp. Each panel's cut outline (its sewing outline
offset by the seam allowance, `flat_layout.offset_outline`, exactly as its
pattern file draws it) is placed on a roll of the shop's width with its warp
along the roll: a panel whose warp runs along the span (``warp="span"``, its
``y`` axis in `flat_layout.Panel.flat`) is turned by 0 or 180 degrees only; a
fabric whose warp runs along the chord (``warp="chord"``, the panel's
contour, its ``x`` axis) turns every panel by 90 or 270 degrees. A panel is
never mirrored: it is drawn as its outside face is seen, and the marker
shows every panel outside face up.

The marker's frame, millimetres: ``x`` across the roll, from one edge
(``x = 0``) to the other (``x = roll width``), ``y`` along it from its start
(``y = 0``). A placed panel is ``R(rotation) p + translation`` of its pattern
file's points ``p`` (`Piece.place`). Every cut outline lies at least half the
gap from the roll's edges and its start, and at least the gap from every
other cut outline: the nester packs each outline offset outward by half the
gap and `CLEARANCE_MM` (`nesting_outline`). The length used runs from the
roll's start to the far side of the last such outline (where the next marker
may begin); the utilisation is the cut outlines' area over the roll's width
times that length.

The nester: sparrow (Gardeyn and Wauters), a strip-packing search over
irregular polygons (exploration, then compression), through its Python
binding ``spyrrow`` (the ``marker`` extra: ``pip install
"inflatable-wing[marker]"``). Its result is the same for the same inputs when
its search ends on its own (its early termination, `Marker.ended`
"converged"): its random numbers come from a fixed seed and its worker
threads are fixed at `NEST_WORKERS`, not the machine's core count (each
worker samples with its own generator: their number changes the search). A
search stopped by its time limit returns its best marker at that moment,
which depends on the machine's speed (`Marker.ended` "time limit"). The
baseline, and a nester with no dependency: ``nester="shelf"``, the panels'
bounding boxes in shelves across the roll, tallest first (first fit
decreasing height).

NumPy only at import (``spyrrow`` is imported when a sparrow nesting starts).
"""

from __future__ import annotations

import importlib.util
import math
import threading
import time
from dataclasses import dataclass

import numpy as np

from .flat_layout import offset_outline, panel_outline
from .progress import nesting_bar

__all__ = ["CLEARANCE_MM", "MAX_MARKER_SECONDS", "MAX_ROLL_WIDTH_MM", "NEST_WORKERS", "ROTATIONS", "Marker",
           "MarkerRequest", "NesterUnavailable", "Piece", "cut_outline", "default_seconds",
           "convex_hull", "nest_panels", "nesting_outline", "panel_label", "require_nester", "widest_panel"]

#: mm per m: panels are laid out in metres (`flat_layout.Panel.flat`), markers drawn in millimetres.
MM = 1000.0
#: The turns that keep each panel's warp along the roll, degrees counter-clockwise (module docstring).
ROTATIONS = {"span": (0.0, 180.0), "chord": (90.0, 270.0)}
#: mm: beyond half the gap, each nesting outline's margin: sparrow's collision engine (jagua-rs) works in
#: single precision, about 1e-3 mm at 10 m, so that rounding brings no two cut outlines nearer than the gap.
CLEARANCE_MM = 0.05
#: mm: the widest roll accepted. Industrial looms weave up to about 5 m (sailcloth and paraglider cloth
#: come 1.1-1.6 m wide); a width beyond 10 m is more likely given in another unit.
MAX_ROLL_WIDTH_MM = 10_000.0
#: Seconds: the longest time limit accepted for one nesting (a time limit is a cap: the search usually ends
#: on its own before it).
MAX_MARKER_SECONDS = 3600.0
#: sparrow's worker threads (its separator's parallel samplers), fixed so that the marker does not depend
#: on the machine (module docstring): two, the development machine's cores.
NEST_WORKERS = 2
#: The default time limit, s: ``_SECONDS_BASE + _SECONDS_PER_PANEL * panels`` (`default_seconds`): 21 s for
#: a bay's 2 panels, 23 s for the 3-bay wing's 6, 60 s for the 40-cell wing's 80, the issue's goal on 2
#: cores. Measured on the 2-core development machine under a load of 1.5-5 (`benchmarks/marker.py`): the
#: search ended on its own in 5.5-7.5 s on 2 panels, 22-30 s on 6 and 66 s on 80; one stopped by the limit
#: returns its best marker then (`Marker.ended`).
_SECONDS_BASE = 20.0
_SECONDS_PER_PANEL = 0.5
#: Seconds between two looks at a running nesting (its progress, a stop).
_POLL_S = 0.1


class NesterUnavailable(ImportError):
    """The sparrow nester (``spyrrow``) is not installed."""


def require_nester() -> None:
    """Raise `NesterUnavailable` with what to install when ``spyrrow`` is missing (found, not imported)."""
    if importlib.util.find_spec("spyrrow") is None:
        raise NesterUnavailable('the marker\'s nester spyrrow (sparrow) is not installed: pip install '
                                '"inflatable-wing[marker]" (or pip install spyrrow)')


@dataclass(frozen=True)
class MarkerRequest:
    """What a marker is asked for (checked when built).

    Args:
        roll_width_mm: the roll's width, mm (> 0, at most `MAX_ROLL_WIDTH_MM`).
        gap_mm: the least distance between two cut outlines, mm (>= 0, below the width); each cut outline
            lies at least half of it from the roll's edges.
        warp: ``"span"`` (the fabric's warp along the span: panels turned by 0 or 180 degrees) or
            ``"chord"`` (by 90 or 270 degrees).
        seconds: the nesting's time limit, s (None: `default_seconds` of the panel count).
        seed: the nester's random seed (the same seed, the same marker).
        nester: ``"sparrow"`` (``spyrrow``) or ``"shelf"`` (the bounding boxes in shelves, the baseline).

    Raises:
        ValueError: one line naming the field and what to give.
    """

    roll_width_mm: float
    gap_mm: float = 5.0
    warp: str = "span"
    seconds: float | None = None
    seed: int = 0
    nester: str = "sparrow"

    def __post_init__(self):
        width, gap = float(self.roll_width_mm), float(self.gap_mm)
        if not (math.isfinite(width) and 0 < width <= MAX_ROLL_WIDTH_MM):
            raise ValueError(f"roll_width_mm must be a width in mm above 0 and at most {MAX_ROLL_WIDTH_MM:g}, got "
                             f"{self.roll_width_mm!r}")
        if not (math.isfinite(gap) and 0 <= gap < width):
            raise ValueError(f"gap_mm must be 0 mm or more and less than the roll's width ({width:g} mm), got "
                             f"{self.gap_mm!r}")
        if self.warp not in ROTATIONS:
            raise ValueError(f"warp must be one of {', '.join(ROTATIONS)}, got {self.warp!r}")
        if self.seconds is not None and not (math.isfinite(float(self.seconds))
                                             and 1 <= float(self.seconds) <= MAX_MARKER_SECONDS):
            raise ValueError(f"seconds must be a time limit from 1 to {MAX_MARKER_SECONDS:g} s, or None, got "
                             f"{self.seconds!r}")
        if self.nester not in ("sparrow", "shelf"):
            raise ValueError(f"nester must be 'sparrow' or 'shelf', got {self.nester!r}")


@dataclass(frozen=True, eq=False)
class Piece:
    """One panel on the marker.

    Attributes:
        bay: the panel's bay.
        name: the panel's name (``"upper"``, ``"lower"``, ``"panel"``).
        rotation: degrees counter-clockwise, one of `ROTATIONS` of the marker's warp.
        translation: ``(2,)`` mm, applied after the rotation.
        cut: ``(p, 2)`` the placed cut outline, mm (the marker's frame).
        sew: ``(q, 2)`` the placed sewing outline, mm.
        panel: the `flat_layout.Panel` itself (its pattern file's).
    """

    bay: int
    name: str
    rotation: float
    translation: np.ndarray
    cut: np.ndarray
    sew: np.ndarray
    panel: object = None

    def place(self, points) -> np.ndarray:
        """Points of the panel's pattern file (mm, ``(..., 2)``) where they lie on the marker."""
        return _turn(np.asarray(points, np.float64), self.rotation) + self.translation


@dataclass(frozen=True, eq=False)
class Marker:
    """A nested marker (module docstring).

    Attributes:
        request: the `MarkerRequest`.
        pieces: one `Piece` per panel, in the panels' order.
        length_mm: the roll's length used, mm.
        panel_area_mm2: the cut outlines' area, mm^2.
        seconds: the nesting's wall time, s.
        seconds_limit: its time limit, s.
        ended: ``"converged"`` (the search ended on its own: the same marker every run), ``"time limit"``
            (stopped at its limit: its best marker then) or ``"shelf"`` (the shelf layout).
    """

    request: MarkerRequest
    pieces: tuple
    length_mm: float
    panel_area_mm2: float
    seconds: float
    seconds_limit: float
    ended: str

    @property
    def utilisation(self) -> float:
        """The cut outlines' area over the roll's area used (width x length)."""
        return self.panel_area_mm2 / (self.request.roll_width_mm * self.length_mm)

    def summary(self) -> dict:
        """``summary.json``'s ``marker``: the roll, the length used, the utilisation, the panels, the time."""
        r = self.request
        return {"roll_width_mm": r.roll_width_mm, "length_mm": self.length_mm, "utilisation": self.utilisation,
                "panels": len(self.pieces), "seconds": self.seconds, "nester": r.nester, "ended": self.ended,
                "panel_area_m2": self.panel_area_mm2 / MM ** 2, "gap_mm": r.gap_mm, "warp": r.warp,
                "seed": r.seed, "seconds_limit": self.seconds_limit,
                "placements": [{"bay": p.bay, "panel": p.name, "rotation_deg": p.rotation,
                            "translation_mm": [float(v) for v in p.translation]} for p in self.pieces]}


def panel_label(panel) -> str:
    """``"bay 3 upper panel"``: a panel's name in messages and on the marker."""
    return f"bay {panel.bay} {panel.name} panel"


def cut_outline(panel, seam_allowance_mm: float) -> np.ndarray:
    """``(p, 2)`` a panel's cut outline, mm, in its pattern file's frame: its sewing outline
    (`flat_layout.panel_outline`) offset by the seam allowance, as `inverse_design.app.cut_files` draws it."""
    sew, _ = panel_outline(panel.flat * MM)
    return offset_outline(sew, seam_allowance_mm)


def nesting_outline(cut, gap_mm: float) -> np.ndarray:
    """The outline the nester packs: the convex hull of the cut outline offset outward by half the gap and
    `CLEARANCE_MM`.

    The hull holds the offset outline, so the gap holds; a panel's outline is nearly convex (its hull is
    1.0% larger on average, 3.2% at most, over the 40-cell wing's 80 panels) and has about a third of its
    points (28 against 98 there), and sparrow's search time grows with the points: on the 40-cell wing it
    ended on its own in 66 s with the hulls, and had not in 90 s with the outlines (1,400 mm shorter
    roll in 13,300: 0.4%).
    """
    return convex_hull(offset_outline(cut, 0.5 * gap_mm + CLEARANCE_MM))


def convex_hull(points) -> np.ndarray:
    """``(h, 2)`` the convex hull of points, counter-clockwise, without collinear points (Andrew's
    monotone chain)."""
    p = np.unique(np.asarray(points, np.float64), axis=0)  # (sorted by x, then y)
    if len(p) < 3:
        return p

    def chain(order):
        kept = []
        for q in order:
            while len(kept) >= 2 and _cross(kept[-2], kept[-1], q) <= 0.0:
                kept.pop()
            kept.append(q)
        return kept[:-1]

    return np.array(chain(p) + chain(p[::-1]))


def _cross(o, a, b) -> float:
    return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))


def _turn(points: np.ndarray, degrees: float) -> np.ndarray:
    """Points turned about the origin by a multiple of 90 degrees, exactly (no rounding of cos and sin)."""
    x, y = points[..., 0], points[..., 1]
    quarter = int(round(degrees / 90.0)) % 4
    turned = (x, y) if quarter == 0 else (-y, x) if quarter == 1 else (-x, -y) if quarter == 2 else (y, -x)
    return np.stack(turned, axis=-1)


def _across(outline, warp: str) -> float:
    """An outline's width across the roll (mm), turned as the warp asks."""
    return float(np.ptp(_turn(np.asarray(outline), ROTATIONS[warp][0])[:, 0]))


def widest_panel(panels, request: MarkerRequest, seam_allowance_mm: float = 10.0) -> tuple:
    """``(panel, width needed, mm)`` of the panel that needs the most of the roll's width: its cut outline
    across the roll, turned as the warp asks, with half the gap and `CLEARANCE_MM` on each side."""
    widths = [_across(nesting_outline(cut_outline(p, seam_allowance_mm), request.gap_mm), request.warp)
              for p in panels]
    k = int(np.argmax(widths))
    return panels[k], widths[k]


def default_seconds(panels: int) -> float:
    """The default time limit of a nesting of ``panels`` panels, s (`_SECONDS_BASE`), at most
    `MAX_MARKER_SECONDS`."""
    return float(min(_SECONDS_BASE + _SECONDS_PER_PANEL * max(int(panels), 1), MAX_MARKER_SECONDS))


def nest_panels(panels, request: MarkerRequest, *, seam_allowance_mm: float = 10.0, progress: bool = False,
                callback=None) -> Marker:
    """Nest every panel's cut outline on the roll (module docstring).

    Args:
        panels: the `flat_layout.Panel` objects (`flat_panels.bay_panels` of each bay).
        request: the `MarkerRequest` (roll width, gap, warp, time limit, seed, nester).
        seam_allowance_mm: the patterns' seam allowance, mm (>= 0): the cut outlines are theirs.
        progress: show a progress bar on stderr (`inverse_design.progress.nesting_bar`).
        callback: ``callback()`` called about every 0.1 s while the nester runs (a stop raised there ends
            the wait; the nester's thread runs on to its time limit).

    Returns:
        The `Marker`.

    Raises:
        ValueError: no panels, or a panel wider than the roll (named, with the width it needs).
        NesterUnavailable: ``nester="sparrow"`` without ``spyrrow``.
    """
    panels = list(panels)
    if not panels:
        raise ValueError("no panels to nest")
    if request.nester == "sparrow":
        require_nester()
    widest, needs = widest_panel(panels, request, seam_allowance_mm)
    if needs > request.roll_width_mm:
        raise ValueError(f"the {panel_label(widest)} needs {needs:.1f} mm across the roll (its cut outline with "
                         f"{request.gap_mm:g} mm of gap), more than the roll's {request.roll_width_mm:g} mm: give a "
                         "wider roll or a smaller gap")
    cuts = [cut_outline(p, seam_allowance_mm) for p in panels]
    # each nesting outline turned as the warp asks first (the nester then turns it by 0 or 180 degrees only),
    # its box's centre at the origin (the nester's single precision is finest there)
    first = ROTATIONS[request.warp][0]
    shapes, centres = [], []
    for cut in cuts:
        shape = _turn(nesting_outline(cut, request.gap_mm), first)
        centre = 0.5 * (shape.min(axis=0) + shape.max(axis=0))
        shapes.append(shape - centre)
        centres.append(centre)
    limit = float(request.seconds if request.seconds is not None else default_seconds(len(panels)))
    start = time.perf_counter()
    if request.nester == "shelf":
        turns, moves, ended = _shelf(shapes, request.roll_width_mm)
    else:
        turns, moves, ended = _sparrow(shapes, request, limit, progress, callback)
    seconds = time.perf_counter() - start
    pieces, far = [], 0.0
    for panel, cut, shape, centre, turn, move in zip(panels, cuts, shapes, centres, turns, moves):
        # placed = R(turn) (R(first) p - centre) + move = R(first + turn) p + (move - R(turn) centre)
        rotation = (first + turn) % 360.0
        translation = np.asarray(move, np.float64) - _turn(centre, turn)
        far = max(far, float(np.max((_turn(shape, turn) + move)[:, 1])))
        sew = panel_outline(panel.flat * MM)[0]
        pieces.append(Piece(panel.bay, panel.name, rotation, translation,
                            _turn(cut, rotation) + translation, _turn(sew, rotation) + translation, panel))
    area = float(sum(_area(cut) for cut in cuts))
    return Marker(request, tuple(pieces), far, area, seconds, limit, ended)


def _area(points: np.ndarray) -> float:
    """A closed polygon's area (shoelace), in its unit squared."""
    x, y = points[:, 0], points[:, 1]
    return 0.5 * abs(float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)))


def _shelf(shapes: list, width: float) -> tuple:
    """The shelf layout of the shapes' boxes (centred at the origin): ``(turns, moves, "shelf")``.

    First fit decreasing height: the boxes, tallest first, each on the lowest shelf with room left across
    the roll, else on a new shelf above, as tall as its first box.
    """
    half = np.array([0.5 * np.ptp(s, axis=0) for s in shapes])  # half-sides (across, along)
    order = sorted(range(len(shapes)), key=lambda k: (-half[k, 1], k))
    shelves = []  # [bottom, height, used width]
    moves = [None] * len(shapes)
    for k in order:
        w, h = 2.0 * half[k]
        shelf = next((s for s in shelves if s[2] + w <= width), None)
        if shelf is None:
            bottom = shelves[-1][0] + shelves[-1][1] if shelves else 0.0
            shelf = [bottom, h, 0.0]
            shelves.append(shelf)
        moves[k] = np.array([shelf[2] + half[k, 0], shelf[0] + half[k, 1]])
        shelf[2] += w
    return [0.0] * len(shapes), moves, "shelf"


def _sparrow(shapes: list, request: MarkerRequest, limit: float, progress: bool, callback) -> tuple:
    """The shapes (centred at the origin, warp along ``y``) nested by sparrow: ``(turns, moves, ended)``.

    sparrow's strip runs along its ``x`` (its length, minimised) with a fixed height (its ``y``): the
    shapes go in with ``x`` and ``y`` swapped, a mirror of the plane, which takes a turn of 0 or 180
    degrees to itself, and come out swapped back.
    """
    import spyrrow

    items = [spyrrow.Item(str(k), [(float(y), float(x)) for x, y in s], 1, [0.0, 180.0])
             for k, s in enumerate(shapes)]
    instance = spyrrow.StripPackingInstance("marker", float(request.roll_width_mm), items)
    # The limit split between sparrow's two phases, each ending on its own by its count of failed attempts
    # (early termination) well before: the exploration took a sixth of the whole on the 40-cell wing.
    exploration = max(1, int(round(limit / 3.0)))
    config = spyrrow.StripPackingConfig(early_termination=True, exploration_time=exploration,
                                        compression_time=max(1, int(round(limit)) - exploration),
                                        total_computation_time=None, num_workers=NEST_WORKERS, seed=int(request.seed))
    queue = spyrrow.ProgressQueue()
    outcome = {}

    def solve():
        try:
            outcome["solution"] = instance.solve(config, queue)
        except BaseException as exc:  # noqa: BLE001 - raised again in the caller's thread
            outcome["error"] = exc

    thread = threading.Thread(target=solve, name="marker-nesting", daemon=True)
    start = time.perf_counter()
    with nesting_bar(progress, limit, len(shapes)) as bar:
        thread.start()
        while thread.is_alive():
            thread.join(_POLL_S)
            reports = queue.drain()
            bar.update(min(time.perf_counter() - start, limit) - bar.n)
            if reports:
                bar.set_postfix_str(f"{reports[-1][0].phase_name()}, length {reports[-1][1].width / MM:.3f} m",
                                    refresh=False)
            if callback is not None:
                callback()
    if "error" in outcome:
        raise outcome["error"]
    elapsed = time.perf_counter() - start
    solution = outcome["solution"]
    turns, moves = [0.0] * len(shapes), [None] * len(shapes)
    for placed in solution.placed_items:
        k = int(placed.id)
        turn = float(placed.rotation) % 360.0
        turns[k] = 180.0 if abs(turn - 180.0) < 1.0 else 0.0
        moves[k] = np.array([placed.translation[1], placed.translation[0]], np.float64)
    if any(m is None for m in moves):
        raise RuntimeError(f"the nester placed {sum(m is not None for m in moves)} of {len(shapes)} panels")
    # (a phase that reached its time limit: the run took about the whole limit)
    ended = "time limit" if elapsed >= limit - 1.0 else "converged"
    return turns, moves, ended
