"""Airfoil coordinate files (``.dat``) in the Selig and Lednicer formats.

Both formats, as used by the UIUC airfoil database, hold one point (x, z) per
line, chord-normalised, after a name line:

* Selig: the points run trailing edge -> upper surface -> leading edge ->
  lower surface -> trailing edge.
* Lednicer: a second header line holds the numbers of upper and lower points
  (e.g. ``61. 61.``); then the upper surface leading edge -> trailing edge, a
  blank line, and the lower surface leading edge -> trailing edge.

The format is detected from the first numeric line after the name: two whole
numbers of at least 2 are point counts (Lednicer); a Selig file starts at the
trailing edge, x close to 1. A file whose first line is already a point has no
name line, and the file's stem names it.

Real files (the UIUC database) carry text around the points, which the reader
skips: more header lines after the name (lines whose first word is not a
number), the MSES domain line (four numbers right after the name, as in the
TASOPT sections), and comments after the last point (from the first line
that is not all numbers). Text between points, and a line of numbers other
than two right after the last point, are refused, naming the line. A chord
slightly off unit length is renormalised with an :class:`AirfoilWarning`;
see :func:`load_airfoil`.
"""

from __future__ import annotations

import errno
import os
import warnings
from pathlib import Path

import numpy as np

from .airfoil import Airfoil
from .checks import CHORD_TOLERANCE, MIN_POINTS, crossing_error, order_error

RENORMALISE_LIMIT = 5e-3
"""Largest chord error (chord units) that :func:`load_airfoil` renormalises: the
trailing edge off x = 1 and the leading edge off x = 0 by at most this. It
covers six-decimal data and files whose last cosine station stops short of
x = 1 (Wortmann's, 1.07e-3 and 2.7e-3); coordinates in percent, in metres or
measured to a tab (VR-8 with tab, 1.01) stay refused."""


class AirfoilWarning(UserWarning):
    """An airfoil file was read with a correction (see :func:`load_airfoil`)."""


class NotAFileError(IsADirectoryError, ValueError):
    """:func:`load_airfoil` was given a directory: bad input (a ValueError) and an IsADirectoryError."""

    def __str__(self) -> str:
        return str(self.strerror)


def _numbers(line: str) -> list[float] | None:
    """The numbers on a line (blank- or comma-separated), or None if any token is not one."""
    try:
        return [float(token) for token in line.replace(",", " ").split()]
    except ValueError:
        return None


def _is_text(line: str) -> bool:
    """Whether a non-blank line is text: its first word is not a number."""
    try:
        float(line.replace(",", " ").split()[0])
    except ValueError:
        return True
    return False


def _is_point(line: str) -> bool:
    """Whether a line holds exactly two numbers."""
    values = _numbers(line)
    return values is not None and len(values) == 2


def _read_points(where: str, lines: list[tuple[int, str]]) -> list[list[tuple[int, float, float]]]:
    """Point lines, as blocks separated by blank lines, each point with its line number."""
    blocks: list[list[tuple[int, float, float]]] = [[]]
    for number, line in lines:
        if not line.strip():
            if blocks[-1]:
                blocks.append([])
            continue
        values = _numbers(line)
        if values is None or len(values) != 2:
            raise ValueError(f"{where}, line {number}: expected two numbers 'x z', got {line.strip()!r}; "
                             f"fix or delete the line")
        if not all(np.isfinite(values)):
            raise ValueError(f"{where}, line {number}: coordinate is not finite ({line.strip()!r}); "
                             f"replace it with the point's value")
        blocks[-1].append((number, values[0], values[1]))
    return [block for block in blocks if block]


def _lednicer(where: str, header_line: int, counts: tuple[int, int],
              blocks: list[list[tuple[int, float, float]]]) -> list[tuple[int, float, float]]:
    """Selig-ordered points of a Lednicer file."""
    n_upper, n_lower = counts
    points = [point for block in blocks for point in block]
    if len(blocks) == 2:
        upper, lower = blocks
    elif len(blocks) == 1 and len(points) == n_upper + n_lower:
        upper, lower = points[:n_upper], points[n_upper:]
    elif len(blocks) <= 1:
        last = points[-1][0] if points else header_line
        raise ValueError(f"{where}: line {header_line} declares {n_upper} upper and {n_lower} lower surface "
                         f"points, but the file holds {len(points)} point(s) in one block ending at line "
                         f"{last}; a surface is missing: add it after a blank line")
    else:
        raise ValueError(f"{where}: a Lednicer file holds two blocks of points (upper, then lower surface) "
                         f"separated by a blank line, but this one has {len(blocks)} blocks (the third "
                         f"starts at line {blocks[2][0][0]}); remove the extra blank lines or points")
    for surface, block, declared in (("upper", upper, n_upper), ("lower", lower, n_lower)):
        if len(block) != declared:
            raise ValueError(f"{where}: line {header_line} declares {declared} {surface} surface points, but "
                             f"the {surface} surface (lines {block[0][0]}-{block[-1][0]}) has {len(block)}; "
                             f"correct the count or the points")
        if not block[0][1] < block[-1][1]:
            raise ValueError(f"{where}: the {surface} surface (lines {block[0][0]}-{block[-1][0]}) must run "
                             f"from the leading edge to the trailing edge (x increasing) in a Lednicer file")
    if (upper[0][1], upper[0][2]) == (lower[0][1], lower[0][2]):
        lower = lower[1:]  # the shared leading-edge point appears once in Selig order
    return upper[::-1] + lower


def _check_order(where: str, points: list[tuple[int, float, float]]) -> None:
    """Refuse points that are not in contour order (shuffled or merged), naming the lines where x turns."""
    disorder = order_error(np.array([p[1] for p in points]), lambda i: f"line {points[i][0]}")
    if disorder is not None:
        raise ValueError(f"{where}: {disorder}")


def _renormalised(where: str, label: str, x: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, str | None]:
    """The points mapped to unit chord when the trailing edge is slightly off x = 1.

    The trailing edge is the mid-point of the first and last points and the
    leading edge the minimum-x point, as :class:`~targets.Airfoil` defines
    them. Only a trailing edge off x = 1 (beyond
    :data:`~targets.checks.CHORD_TOLERANCE`) triggers the renormalisation:
    with the trailing edge in place, a minimum-x point a little off x = 0 is
    no chord error (a NACA section bulges ahead of x = 0, a nose not sampled
    at its tip lies behind it).

    Returns:
        ``(x, z, note)``: the points, unchanged or renormalised, and what was
        done for the warning (None when nothing was).

    Raises:
        ValueError: If the chord error exceeds :data:`RENORMALISE_LIMIT`.
    """
    x_te = 0.5 * (x[0] + x[-1])
    x_le = float(np.min(x))
    if abs(x_te - 1.0) <= CHORD_TOLERANCE:
        return x, z, None
    if abs(x_te - 1.0) > RENORMALISE_LIMIT or abs(x_le) > RENORMALISE_LIMIT:
        uneven = abs(x[0] - x[-1]) > RENORMALISE_LIMIT
        raise ValueError(
            f"{where}: airfoil {label!r} is not chord-normalised: its trailing edge (mid-point of "
            f"the first and last points, at x = {x[0]:.6g} and {x[-1]:.6g}) is at "
            f"x = {x_te:.6g} and its leading edge (minimum x) at x = {x_le:.6g}; chord errors up "
            f"to {RENORMALISE_LIMIT:g} are renormalised, this one is larger: divide the "
            f"coordinates by the chord and put the leading edge at x = 0"
            + (
                f" (the two surfaces end {abs(x[0] - x[-1]):.3g} apart in x: is one incomplete?)"
                if uneven
                else ""
            )
        )
    chord = x_te - x_le
    note = (f"{where}: airfoil {label!r} renormalised to unit chord: its trailing edge was at "
            f"x = {x_te:.9g} and its leading edge at x = {x_le:.9g} (chord {chord:.9g}); x shifted by "
            f"{0.0 - x_le:.3g}, x and z scaled by {1.0 / chord:.9g}")
    return (x - x_le) / chord, z / chord, note


def load_airfoil(path: str | os.PathLike, name: str | None = None) -> Airfoil:
    """Reads a Selig or Lednicer ``.dat`` file (format and skipped text: the module docstring).

    Consecutive repeated points (a quirk of some database files) are read
    once. A chord off unit length by no more than :data:`RENORMALISE_LIMIT`
    is mapped onto unit chord (x from the minimum-x point to the trailing
    edge becomes 0 to 1, z scaled alike, so thickness and camber ratios are
    kept; :func:`_renormalised`) and an :class:`AirfoilWarning` says by how
    much.

    Args:
        path: The file.
        name: Label for the airfoil; default: the file's name line, or its
            stem when it has none.

    Returns:
        The :class:`~targets.Airfoil`, in Selig order.

    Warns:
        AirfoilWarning: When the chord was renormalised, with the trailing
            and leading edge found, the shift and the scale factor.

    Raises:
        ValueError: If the file is malformed; the message names the file and
            the offending line: a line that is not two numbers (text between
            points included), a non-finite coordinate, a missing surface,
            wrong Lednicer counts, points not in contour order, a chord error
            above the limit, or a contour that :class:`~targets.Airfoil`
            rejects. A directory raises :class:`NotAFileError`, both a
            ValueError and an IsADirectoryError.
    """
    where = str(path)
    if Path(path).is_dir():
        raise NotAFileError(errno.EISDIR, f"{where} is a directory; load_airfoil needs an airfoil file "
                            f"(Selig or Lednicer .dat): give the file's path", where)
    text = Path(path).read_text(encoding="utf-8", errors="replace")
    lines = [(number, line) for number, line in enumerate(text.splitlines(), start=1)]
    content = [(number, line) for number, line in lines if line.strip()]
    if not content:
        raise ValueError(f"{where}: the file is empty; expected a name line and points")

    first_number, first_line = content[0]
    first_values = _numbers(first_line)
    named = first_values is None or len(first_values) != 2
    if named:
        label, body = first_line.strip(), lines[first_number:]
    else:
        label, body = Path(path).stem, lines[first_number - 1 :]

    numeric = [number for number, line in body if line.strip() and not _is_text(line)]
    if numeric:
        # The data run from the first numeric line to the last point (two numbers): text
        # before them is header, after them comment (whatever its words), and text in
        # between stays for _read_points to refuse. A line of numbers right after the last
        # point is a damaged point, not a comment: it stays too.
        pairs = [number for number, line in body if _is_point(line)]
        end = pairs[-1] if pairs else numeric[-1]
        after = [(number, line) for number, line in body if number > end and line.strip()]
        if after and _numbers(after[0][1]) is not None:
            end = after[0][0]
        body = [(number, line) for number, line in body if numeric[0] <= number <= end]
    body_content = [(number, line) for number, line in body if line.strip()]
    if named and body_content and body_content[0][0] == first_number + 1:
        domain = _numbers(body_content[0][1])
        if domain is not None and len(domain) == 4:  # MSES: x_inlet x_outlet z_bottom z_top
            body = [(number, line) for number, line in body if number > first_number + 1]
            body_content = body_content[1:]

    counts = None
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
        _check_order(where, points)
    else:
        points = [point for block in blocks for point in block]
        if len(points) < MIN_POINTS:
            raise ValueError(f"{where}: found {len(points)} point(s), at least {MIN_POINTS} are needed; "
                             f"is the file complete?")
        x = np.array([p[1] for p in points])
        _check_order(where, points)
        i_le = int(np.argmin(x))
        if i_le == len(points) - 1:
            raise ValueError(f"{where}: the points end at the leading edge (line {points[-1][0]}), so the "
                             f"lower surface is missing; a Selig file runs trailing edge, upper surface, "
                             f"leading edge, lower surface, trailing edge")
        if i_le == 0:
            raise ValueError(f"{where}: the points start at the leading edge (line {points[0][0]}); a Selig "
                             f"file starts at the trailing edge and runs over the upper surface first, so "
                             f"either the upper surface is missing or this is a Lednicer file without its "
                             f"count line")

    kept = [points[0]]
    kept += [q for p, q in zip(points[:-1], points[1:]) if (p[1], p[2]) != (q[1], q[2])]
    x = np.array([p[1] for p in kept])
    z = np.array([p[2] for p in kept])
    label = label if name is None else name
    x, z, note = _renormalised(where, label, x, z)
    crossed = crossing_error(x, z, lambda i: str(kept[i][0]), "lines")
    if crossed is not None:
        raise ValueError(f"{where}: airfoil {label!r}: {crossed}")
    try:
        airfoil = Airfoil(x, z, name=label)
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from err
    if note is not None:
        warnings.warn(note, AirfoilWarning, stacklevel=2)
    return airfoil
