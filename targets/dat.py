"""Airfoil coordinate files (``.dat``) in the Selig and Lednicer formats.

Both formats, as used by the UIUC airfoil database, hold one point (x, z) per
line, chord-normalised, after a name line:

* Selig: the points run trailing edge -> upper surface -> leading edge ->
  lower surface -> trailing edge.
* Lednicer: a second header line holds the numbers of upper and lower points
  (e.g. ``61. 61.``); then the upper surface leading edge -> trailing edge, a
  blank line, and the lower surface leading edge -> trailing edge.

The format is detected from the line after the name: two whole numbers of at
least 2 are point counts (Lednicer); a Selig file starts at the trailing edge,
x close to 1. A file whose first line is already a point has no name line,
and the file's stem names it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .airfoil import MIN_POINTS, Airfoil


def _numbers(line: str) -> list[float] | None:
    """The numbers on a line (blank- or comma-separated), or None if any token is not one."""
    try:
        return [float(token) for token in line.replace(",", " ").split()]
    except ValueError:
        return None


def _read_points(
    where: str, lines: list[tuple[int, str]]
) -> list[list[tuple[int, float, float]]]:
    """Point lines, as blocks separated by blank lines, each point with its line number."""
    blocks: list[list[tuple[int, float, float]]] = [[]]
    for number, line in lines:
        if not line.strip():
            if blocks[-1]:
                blocks.append([])
            continue
        values = _numbers(line)
        if values is None or len(values) != 2:
            raise ValueError(
                f"{where}, line {number}: expected two numbers 'x z', got {line.strip()!r}; "
                f"fix or delete the line"
            )
        if not all(np.isfinite(values)):
            raise ValueError(
                f"{where}, line {number}: coordinate is not finite ({line.strip()!r}); "
                f"replace it with the point's value"
            )
        blocks[-1].append((number, values[0], values[1]))
    return [block for block in blocks if block]


def _lednicer(
    where: str,
    header_line: int,
    counts: tuple[int, int],
    blocks: list[list[tuple[int, float, float]]],
) -> list[tuple[int, float, float]]:
    """Selig-ordered points of a Lednicer file."""
    n_upper, n_lower = counts
    points = [point for block in blocks for point in block]
    if len(blocks) == 2:
        upper, lower = blocks
    elif len(blocks) == 1 and len(points) == n_upper + n_lower:
        upper, lower = points[:n_upper], points[n_upper:]
    elif len(blocks) <= 1:
        last = points[-1][0] if points else header_line
        raise ValueError(
            f"{where}: line {header_line} declares {n_upper} upper and {n_lower} lower surface "
            f"points, but the file holds {len(points)} point(s) in one block ending at line "
            f"{last}; a surface is missing: add it after a blank line"
        )
    else:
        raise ValueError(
            f"{where}: a Lednicer file holds two blocks of points (upper, then lower surface) "
            f"separated by a blank line, but this one has {len(blocks)} blocks (the third "
            f"starts at line {blocks[2][0][0]}); remove the extra blank lines or points"
        )
    for surface, block, declared in (("upper", upper, n_upper), ("lower", lower, n_lower)):
        if len(block) != declared:
            raise ValueError(
                f"{where}: line {header_line} declares {declared} {surface} surface points, but "
                f"the {surface} surface (lines {block[0][0]}-{block[-1][0]}) has {len(block)}; "
                f"correct the count or the points"
            )
        if not block[0][1] < block[-1][1]:
            raise ValueError(
                f"{where}: the {surface} surface (lines {block[0][0]}-{block[-1][0]}) must run "
                f"from the leading edge to the trailing edge (x increasing) in a Lednicer file"
            )
    if (upper[0][1], upper[0][2]) == (lower[0][1], lower[0][2]):
        lower = lower[1:]  # the shared leading-edge point appears once in Selig order
    return upper[::-1] + lower


def load_airfoil(path: str | os.PathLike, name: str | None = None) -> Airfoil:
    """Reads a Selig or Lednicer ``.dat`` file (format detected, see the module docstring).

    Consecutive repeated points (a quirk of some database files) are read
    once; nothing else is changed: the coordinates must already be
    chord-normalised (leading edge at x = 0, trailing edge at x = 1).

    Args:
        path: The file.
        name: Label for the airfoil; default: the file's name line, or its
            stem when it has none.

    Returns:
        The :class:`~targets.Airfoil`, in Selig order.

    Raises:
        ValueError: If the file is malformed; the message names the file and
            the offending line: a line that is not two numbers, a non-finite
            coordinate, a missing surface, wrong Lednicer counts, or a contour
            that :class:`~targets.Airfoil` rejects.
    """
    where = str(path)
    text = Path(path).read_text(encoding="utf-8", errors="replace")
    lines = [(number, line) for number, line in enumerate(text.splitlines(), start=1)]
    content = [(number, line) for number, line in lines if line.strip()]
    if not content:
        raise ValueError(f"{where}: the file is empty; expected a name line and points")

    first_number, first_line = content[0]
    first_values = _numbers(first_line)
    if first_values is not None and len(first_values) == 2:
        label, body = Path(path).stem, lines[first_number - 1 :]
    else:
        label, body = first_line.strip(), lines[first_number:]

    counts = None
    body_content = [(number, line) for number, line in body if line.strip()]
    if body_content:
        header_line, second = body_content[0]
        values = _numbers(second)
        if (
            values is not None
            and len(values) == 2
            and all(np.isfinite(values))
            and all(v >= 2.0 and v == int(v) for v in values)
        ):
            counts = (int(values[0]), int(values[1]))
            body = [(number, line) for number, line in body if number > header_line]

    blocks = _read_points(where, body)
    if counts is not None:
        points = _lednicer(where, header_line, counts, blocks)
    else:
        points = [point for block in blocks for point in block]
        if len(points) < MIN_POINTS:
            raise ValueError(
                f"{where}: found {len(points)} point(s), at least {MIN_POINTS} are needed; "
                f"is the file complete?"
            )
        x = np.array([p[1] for p in points])
        i_le = int(np.argmin(x))
        if i_le == len(points) - 1:
            raise ValueError(
                f"{where}: the points end at the leading edge (line {points[-1][0]}), so the "
                f"lower surface is missing; a Selig file runs trailing edge, upper surface, "
                f"leading edge, lower surface, trailing edge"
            )
        if i_le == 0:
            raise ValueError(
                f"{where}: the points start at the leading edge (line {points[0][0]}); a Selig "
                f"file starts at the trailing edge and runs over the upper surface first, so "
                f"either the upper surface is missing or this is a Lednicer file without its "
                f"count line"
            )

    kept = [points[0]]
    kept += [q for p, q in zip(points[:-1], points[1:]) if (p[1], p[2]) != (q[1], q[2])]
    x = np.array([p[1] for p in kept])
    z = np.array([p[2] for p in kept])
    try:
        return Airfoil(x, z, name=label if name is None else name)
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from err
