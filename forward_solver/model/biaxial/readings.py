"""A shop's biaxial test of its fabric: the CSV file of readings, read and checked (`read_test`).

One row per reading, with a header naming the columns (any order; other
columns are ignored; lines starting with ``#`` are comments)::

    strain_warp, strain_weft, tension_warp, tension_weft[, load_ratio]

strains as fractions of the unloaded (cut) length (0.02 is 2%), tensions in
N/m (force per unit width of the specimen's arm), along several load-ratio
paths (1:1, 2:1, 1:2, 1:0, 0:1: MSAJ/M-02-1995, EN 17117-1), each path's
loading branch from low to high load. The optional ``load_ratio`` column
names each reading's path (any text, e.g. ``2:1``); without it a reading's
path is the direction of its tensions ``(T_warp, T_weft)`` (readings within
`PATH_ANGLE` degrees of one another share a path; readings at zero load
belong to every path).

A file that cannot be fitted is refused with one line that names the file,
where, and what to change (`TestFileError`): fewer than `MIN_READINGS`
readings, a single load-ratio path, a value that is not a number (NaN
included), strains that look like percent (the largest over 1), a negative
tension, or along a path a tension that falls while its strain grows, or at
all (an unloading branch). NumPy only, like the fit: the command reads and
fits the file as it reads its case, before any solve.
"""

from __future__ import annotations

import csv
import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["COLUMNS", "MIN_READINGS", "PATH_ANGLE", "BiaxialTest", "TestFileError", "read_test", "path_label",
           "readings_from_arrays"]

#: The columns a test file must have, in the order `BiaxialTest` holds them.
COLUMNS = ("strain_warp", "strain_weft", "tension_warp", "tension_weft")
#: The fewest readings a fit takes (its surface has up to 12 coefficients, two equations a reading).
MIN_READINGS = 12
#: Degrees between the tension directions of two readings on different paths (without ``load_ratio``).
PATH_ANGLE = 5.0
#: A tension may fall along a path by this fraction of its direction's largest reading (the scatter
#: of a load cell) before the path counts as falling.
FALL_TOLERANCE = 0.01


class TestFileError(ValueError):
    """A biaxial test file that cannot be fitted: one line naming the file, where, and what to change."""

    __test__ = False  # (not a pytest test class)


@dataclass(frozen=True, eq=False)
class BiaxialTest:
    """The readings of one biaxial test.

    Attributes:
        strain_warp, strain_weft: ``(n,)`` strains, fractions.
        tension_warp, tension_weft: ``(n,)`` tensions, N/m.
        paths: ``(n,)`` each reading's load-ratio path label (``"1:1"``, ``"2:1"``, ...).
        source: the file's name (or a description of where the readings came from).
        digest: the first 16 hex digits of the SHA-256 of the readings (the file's bytes).
        lines: ``(n,)`` each reading's line in the file (1 is the first), for messages.
    """

    strain_warp: np.ndarray
    strain_weft: np.ndarray
    tension_warp: np.ndarray
    tension_weft: np.ndarray
    paths: tuple
    source: str
    digest: str
    lines: tuple

    @property
    def size(self) -> int:
        return int(self.strain_warp.shape[0])

    @property
    def path_labels(self) -> tuple:
        """The distinct paths, in the order the file first gives them."""
        return tuple(dict.fromkeys(p for p in self.paths if p))

    @property
    def warp_range(self) -> tuple:
        """``(least, largest)`` warp strain tested."""
        return float(np.min(self.strain_warp)), float(np.max(self.strain_warp))

    @property
    def weft_range(self) -> tuple:
        return float(np.min(self.strain_weft)), float(np.max(self.strain_weft))

    def path(self, label: str) -> np.ndarray:
        """Indices of the readings of path ``label`` (file order), the readings at zero load included."""
        return np.array([k for k, p in enumerate(self.paths) if p == label or p == ""], int)


def path_label(t_warp: float, t_weft: float) -> str:
    """A path's label from the direction of its tensions: ``"1:1"``, ``"2:1"``, ``"1:0"``, ``"1:2.5"``."""
    high = max(t_warp, t_weft)
    if high <= 0:
        return ""
    if t_weft <= 1e-6 * high:
        return "1:0"
    if t_warp <= 1e-6 * high:
        return "0:1"
    ratio = t_warp / t_weft
    return f"{ratio:.2g}:1" if ratio >= 1 else f"1:{1.0 / ratio:.2g}"


def _percent(strain: float) -> str:
    return f"{100.0 * strain:.3g}%"


def read_test(path) -> BiaxialTest:
    """The readings of a biaxial test file (module docstring), checked.

    Raises:
        TestFileError: one line (module docstring).
    """
    path = Path(path)
    name = str(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise TestFileError(f"{name}: cannot read the biaxial test: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise TestFileError(f"{name}: not a text file; give the readings as CSV ({', '.join(COLUMNS)})") from None
    rows = [(k + 1, line) for k, line in enumerate(text.splitlines()) if line.strip() and
            not line.lstrip().startswith("#")]
    if not rows:
        raise TestFileError(f"{name}: no readings; the file needs a header ({', '.join(COLUMNS)}) and one row "
                            "per reading")
    header_line, header = rows[0]
    names = [h.strip().lower() for h in next(csv.reader([header]))]
    missing = [c for c in COLUMNS if c not in names]
    if missing:
        raise TestFileError(f"{name}: line {header_line}: no column {', '.join(missing)}; the header must name "
                            f"{', '.join(COLUMNS)} (and optionally load_ratio), got {', '.join(names)}")
    index = {c: names.index(c) for c in (*COLUMNS, "load_ratio") if c in names}
    values, labels, lines = [], [], []
    for line, row in rows[1:]:
        cells = next(csv.reader([row]))
        if len(cells) < len(names):
            raise TestFileError(f"{name}: line {line}: {len(cells)} values for the header's {len(names)} "
                                f"columns ({', '.join(names)})")
        reading = []
        for column in COLUMNS:
            cell = cells[index[column]].strip()
            try:
                value = float(cell)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                raise TestFileError(f"{name}: line {line}: {column} is {cell or 'empty'!r}, not a number; every "
                                    "reading needs its four numbers")
            reading.append(value)
        values.append(reading)
        labels.append(cells[index["load_ratio"]].strip() if "load_ratio" in index else None)
        lines.append(line)
    array = np.array(values, np.float64).reshape(-1, 4)
    return readings_from_arrays(*array.T, paths=None if "load_ratio" not in index else labels, source=name,
                            digest=hashlib.sha256(raw).hexdigest()[:16], lines=lines)


def readings_from_arrays(strain_warp, strain_weft, tension_warp, tension_weft, paths=None, source: str = "readings",
                     digest: str | None = None, lines=None) -> BiaxialTest:
    """A `BiaxialTest` of readings given as arrays, checked as `read_test` checks a file.

    Args:
        strain_warp, strain_weft: ``(n,)`` strains, fractions.
        tension_warp, tension_weft: ``(n,)`` tensions, N/m.
        paths: ``(n,)`` path labels, or None to take each reading's path from its tensions' direction.
        source: what the messages call the readings.
        digest: the readings' digest (default: of the arrays).
        lines: ``(n,)`` the readings' lines, for messages (default 1, 2, ...).

    Raises:
        TestFileError: one line (module docstring).
    """
    columns = [np.asarray(c, np.float64).reshape(-1) for c in (strain_warp, strain_weft, tension_warp, tension_weft)]
    n = columns[0].shape[0]
    lines = tuple(range(1, n + 1)) if lines is None else tuple(lines)
    for column, values in zip(COLUMNS, columns):
        bad = ~np.isfinite(values)
        if bad.any():
            k = int(np.argmax(bad))
            raise TestFileError(f"{source}: line {lines[k]}: {column} is {values[k]!r}, not a number; every reading "
                                "needs its four numbers")
    if n < MIN_READINGS:
        raise TestFileError(f"{source}: {n} readings; a fit needs at least {MIN_READINGS} (several load-ratio paths, "
                            "each from low to high load): add readings")
    largest = max(float(np.max(np.abs(columns[0]))), float(np.max(np.abs(columns[1]))))
    if largest > 1.0:
        raise TestFileError(f"{source}: the largest strain is {largest:g}, over 1: the strains look like percent; "
                            f"give them as fractions ({largest / 100:g} for {largest:g}%)")
    tensions = columns[2:]
    top = [max(float(np.max(t)), 0.0) for t in tensions]
    for column, t, high in zip(COLUMNS[2:], tensions, top):
        if np.min(t) < -FALL_TOLERANCE * max(top):
            k = int(np.argmin(t))
            raise TestFileError(f"{source}: line {lines[k]}: {column} is {t[k]:g} N/m; a fabric carries no "
                                "compression: tensions are 0 or more (a column's sign or units?)")
    labels = _paths(tensions[0], tensions[1], paths)
    test = BiaxialTest(*columns, paths=labels, source=source, lines=lines,
                       digest=digest or hashlib.sha256(np.stack(columns).tobytes()).hexdigest()[:16])
    if len(test.path_labels) < 2:
        only = test.path_labels[0] if test.path_labels else "no load"
        raise TestFileError(f"{source}: every reading lies on one load-ratio path ({only}); one path cannot tell the "
                            "warp's response from the weft's: add paths such as 1:1, 2:1, 1:2, 1:0 and 0:1")
    for label in test.path_labels:
        _check_path(test, label, top)
    return test


def _paths(t_warp, t_weft, given) -> tuple:
    """Each reading's path ("" at zero load): the given labels, or the readings grouped by their tensions'
    direction (sorted, a gap over `PATH_ANGLE` degrees starts a new path), each group labelled by its
    summed tensions (`path_label`)."""
    loaded = (t_warp > 0) | (t_weft > 0)
    if given is not None:
        return tuple(str(p) if on else "" for p, on in zip(given, loaded))
    angle = np.degrees(np.arctan2(t_weft, t_warp))
    order = np.sort(angle[loaded])
    edges = order[1:][np.diff(order) > PATH_ANGLE]  # (the first angle of every group but the first)
    group = np.searchsorted(edges, angle, side="right")
    names = {g: path_label(float(np.sum(t_warp[loaded & (group == g)])), float(np.sum(t_weft[loaded & (group == g)])))
             for g in set(group[loaded].tolist())}
    return tuple(names[g] if on else "" for g, on in zip(group.tolist(), loaded))


def _check_path(test: BiaxialTest, label: str, top: list) -> None:
    """Refuse a path along which a tension falls (while its strain grows, or at all: unloading)."""
    members = [k for k, p in enumerate(test.paths) if p == label]
    strains = (test.strain_warp, test.strain_weft)
    tensions = (test.tension_warp, test.tension_weft)
    for a, b in zip(members[:-1], members[1:]):
        for d, direction in enumerate(("warp", "weft")):
            fall = tensions[d][a] - tensions[d][b]
            if fall <= FALL_TOLERANCE * top[d]:
                continue
            grows = strains[d][b] > strains[d][a]
            what = (f"while strain_{direction} grows from {_percent(strains[d][a])} to {_percent(strains[d][b])}"
                    if grows else "(an unloading branch)")
            raise TestFileError(f"{test.source}: path {label}, lines {test.lines[a]}-{test.lines[b]}: tension_{direction} "
                                f"falls from {tensions[d][a]:.4g} to {tensions[d][b]:.4g} N/m {what}; give the "
                                "loading branch of each path only, its tensions rising with the load")
