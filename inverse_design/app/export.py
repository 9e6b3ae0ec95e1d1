"""Files of a design: the equilibrium as ``.npz``, the skin as OBJ and STL, and the atomic output folder.

`write_npz`, `write_obj` and `write_stl` write one file each. A report is
written atomically (`staged_folder`): into a hidden temporary folder, whose
files are put in place only when all are written. The output folder may
hold other files: only the report's own files are written, replacing only
the files of an earlier report there (those its ``summary.json`` lists:
`written_files`); the earlier report's files that the new one does not
write are removed; nothing else in the folder is touched, and the folder is
never removed (`check_output_folder` refuses a folder holding a file of a
report's name that no report wrote). Temporary folders that a killed writer
left behind are removed (or their moves finished) by the next
`staged_folder` of the same destination (`remove_stale_partials`).

A report records the size and SHA-256 of every file it wrote in its
``summary.json`` (``checksums``: `file_checksums`). A file that changed since
(a ``rib.dat`` edited by hand) is no longer the report's (`changed_files`):
it is never removed, and a new report that would replace it is refused
(``check_output_folder(..., replaces=...)`` up front, `staged_folder` at the
latest); a summary without checksums (an older report's) is trusted as it is.
A run holds `output_lock` on its output folder from start to end, so a second
run into the same folder is refused at once instead of racing the first.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import shutil
import tempfile
import uuid
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from forward_solver import Solution

from . import interrupts
from ..optimise import DesignResult

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows: no flock, stale folders are left alone
    fcntl = None

__all__ = [
    "REPORT_FILES",
    "changed_files",
    "check_output_folder",
    "file_checksums",
    "output_lock",
    "deviation",
    "remove_stale_partials",
    "staged_folder",
    "write_cut_pattern",
    "write_npz",
    "write_obj",
    "write_selig",
    "write_stl",
    "written_files",
]


def deviation(solution: Solution, target, chord: float) -> np.ndarray:
    """Signed normal distance of every node from the target, ``(n_span, n_contour)``, fraction of chord.

    Positive outside the target. ``chord`` (m) scales the nodes to the target's
    chord-normalised frame (the bay's mean chord, as the objectives use). It is
    stored in ``equilibrium.npz`` and drawn by `inverse_design.app.plots.plot_deviation`.
    """
    points = np.asarray(solution.nodes)[..., [0, 2]] / chord
    return np.asarray(target.distance(points), dtype=np.float64)


# ------------------------------------------------------------------ surface files
def _quads(n_span: int, n_contour: int, periodic: bool) -> np.ndarray:
    """``(n_quads, 4)`` zero-based node indices of the grid's cells, counter-clockwise seen from outside."""
    index = np.arange(n_span * n_contour).reshape(n_span, n_contour)
    j = np.arange(n_contour if periodic else n_contour - 1)
    j1 = (j + 1) % n_contour
    # (i, j) -> (i+1, j) -> (i+1, j+1) -> (i, j+1): the normal e1 x e2 points out of the section.
    quads = np.stack([index[:-1][:, j], index[1:][:, j], index[1:][:, j1], index[:-1][:, j1]], axis=-1)
    return quads.reshape(-1, 4)


def write_obj(path, nodes, periodic: bool, name: str = "skin") -> Path:
    """Write the skin as a Wavefront OBJ: one vertex per node, one quad per cell.

    Args:
        path: file to write.
        nodes: ``(n_span, n_contour, 3)`` m.
        periodic: close the contour (a wing section) with a last column of quads.
        name: object name in the file.

    Returns:
        The path. Vertex ``1 + i * n_contour + j`` is node ``(i, j)``; faces
        wind counter-clockwise seen from outside the wing.
    """
    nodes = np.asarray(nodes, dtype=np.float64)
    n_span, n_contour, _ = nodes.shape
    quads = _quads(n_span, n_contour, periodic) + 1
    lines = [
        "# inflatable-wing equilibrium skin; units: metres (x chordwise, y spanwise, z up)",
        f"# grid {n_span} x {n_contour} nodes (span x contour); vertex 1 + i*{n_contour} + j is node (i, j)",
        f"o {name}",
    ]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in nodes.reshape(-1, 3)]
    lines += [f"f {a} {b} {c} {d}" for a, b, c, d in quads]
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path


def write_stl(path, nodes, periodic: bool) -> Path:
    """Write the skin as a binary STL (two triangles per cell, outward normals), metres."""
    nodes = np.asarray(nodes, dtype=np.float64)
    n_span, n_contour, _ = nodes.shape
    quads = _quads(n_span, n_contour, periodic)
    flat = nodes.reshape(-1, 3)
    triangles = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    corners = flat[triangles]  # (n, 3, 3)
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
    record = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    data = np.zeros(len(triangles), dtype=record)
    data["normal"], data["corners"] = normals, corners
    header = b"inflatable-wing equilibrium skin, units: metres".ljust(80, b" ")
    path = Path(path)
    with open(path, "wb") as f:
        f.write(header)
        f.write(np.uint32(len(triangles)).tobytes())
        f.write(data.tobytes())
    return path


def write_npz(path, solution: Solution, target, scene, result: DesignResult | None = None) -> Path:
    """Write the equilibrium and its parameters as a compressed ``.npz`` (no pickles).

    Arrays: ``nodes`` (n_span, n_contour, 3) m; ``tension_span``,
    ``tension_chord`` (n_span - 1, n_cells) N/m; ``wrinkled`` (same, bool);
    ``fixed`` (n_span, n_contour) bool; ``deviation`` (n_span, n_contour)
    signed normal distance from the target, fraction of chord;
    ``target_xz`` (n, 2) the chord-normalised target; ``mid_bay_section``
    and ``rib_section`` (n_contour, 2) x-z in m; scalars ``pressure`` (Pa),
    ``prestrain`` (span, chord), ``rib_thickness_scale``, ``rib_chord_scale``,
    ``stiffness`` (span, chord) N/m, ``chord`` and ``rib_spacing`` (m);
    ``rib_shape`` (2 K coefficients, empty for an unshaped rib); the cut
    lengths of `rib_design.cut_lengths` (``contour_edge_cut`` (n_span,
    n_edges), ``span_edge_cut`` (n_span - 1, n_contour), m); ``variables``
    (names) and, after an optimisation, ``history_objective`` and
    ``history_values`` (iterate x component; a rib shape takes 2 K columns).
    """
    from ..rib_design import cut_lengths

    bay = scene.bay
    values = solution.parameters
    arrays = dict(
        nodes=np.asarray(solution.nodes), tension_span=np.asarray(solution.tension_span),
        tension_chord=np.asarray(solution.tension_chord), wrinkled=np.asarray(solution.wrinkled, bool),
        fixed=np.asarray(bay.fixed, bool), deviation=deviation(solution, target, bay.chord),
        target_xz=np.stack([np.asarray(target.x), np.asarray(target.z)], axis=-1),
        mid_bay_section=solution.section(0.5), rib_section=solution.section(0.0),
        pressure=np.float64(values.pressure),
        prestrain=np.array(values.prestrain, dtype=np.float64),
        rib_thickness_scale=np.float64(values.rib_thickness_scale),
        rib_chord_scale=np.float64(values.rib_chord_scale),
        stiffness=np.array(values.stiffness, dtype=np.float64),
        chord=np.float64(bay.chord), rib_spacing=np.float64(bay.rib_spacing),
        target_name=np.array(str(target.name)),
        rib_shape=np.zeros(0) if values.rib_shape is None else np.asarray(values.rib_shape, np.float64),
    )
    cuts = cut_lengths(scene, values)
    arrays.update(contour_edge_cut=cuts["contour_edge_cut_m"], span_edge_cut=cuts["span_edge_cut_m"])
    if result is not None:
        names = list(result.variables)
        arrays["variables"] = np.array(names, dtype=str)
        arrays["history_objective"] = np.array([h["objective"] for h in result.history], dtype=np.float64)
        rows = [np.concatenate([np.ravel(h["values"][n]) for n in names]) for h in result.history]
        arrays["history_values"] = np.array(rows, dtype=np.float64).reshape(len(rows), -1)
    return save_npz(path, arrays)


def save_npz(path, arrays: dict) -> Path:
    """``np.savez_compressed(path, **arrays)``, never cut short by a stop of the command.

    A Ctrl-C or SIGTERM that lands while a member of the zip file is being
    closed leaves its write handle open; closing the zip file then raises
    ValueError ("Can't close the ZIP file while there is an open writing
    handle") in place of the stop, and the run ended with exit 2. The write
    runs as an `interrupts.deferred` section: a stop arriving in it is raised
    when the file is complete.
    """
    path = Path(path)
    with interrupts.deferred(), open(path, "wb") as f:
        np.savez_compressed(f, **arrays)
    interrupts.check()
    return path


# ------------------------------------------------------------------ the folder
def write_selig(path, airfoil, comment: str = "") -> Path:
    """Write a chord-normalised `targets.Airfoil` as a Selig ``.dat`` file (name line, then x z).

    Points run in the airfoil's own (Selig) order: trailing edge, upper
    surface, leading edge, lower surface. `targets.load_airfoil` reads it
    back.
    """
    name = " ".join(str(airfoil.name).split()) or "airfoil"
    lines = [name + (f"  ({comment})" if comment else "")]
    lines += [f"{x: .8f} {z: .8f}" for x, z in zip(np.asarray(airfoil.x), np.asarray(airfoil.z))]
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path


def write_cut_pattern(path, scene, parameters) -> Path:
    """Write the fabric's cut lengths (`rib_design.cut_lengths`) as CSV, one row per contour node.

    Columns: ``j`` (contour node), ``surface`` (upper/lower, Selig order),
    ``x_over_chord`` (at the root rib), ``arc_cut_root_m`` and
    ``arc_cut_mid_m`` (cut length along the contour from the trailing edge
    to the node, at the root rib's row and at mid-bay), ``span_cut_m`` (cut
    length of the span fibre through the node, rib to rib),
    ``span_mounted_m`` (its mounted length), ``span_prestrain`` (the local
    prestrain of that span fibre) and ``contour_prestrain`` (that of the
    contour edge from the node to the next; both the uniform prestrains
    unless a cut pattern, `forward_solver.model.cut_field`, varies them). The
    ``# `` header lines give the prestrains and each row's cut perimeter.
    """
    from ..rib_design import cut_lengths

    cuts = cut_lengths(scene, parameters)
    bay = scene.bay
    contour = cuts["contour_edge_cut_m"]
    mid = bay.n_span // 2
    arc_root = np.concatenate([[0.0], np.cumsum(contour[0])])[: bay.n_contour]
    arc_mid = np.concatenate([[0.0], np.cumsum(contour[mid])])[: bay.n_contour]
    x = np.asarray(bay.contour_root[:, 0])
    j_le = int(np.argmin(x))
    field = ("" if parameters.cut_pattern is None else
             f" plus a cut pattern of {np.size(parameters.cut_pattern) // 2} terms per direction (local "
             "prestrain in the last two columns)")
    lines = [f"# cut lengths of the fabric: reference length = mounted length / (1 + prestrain), "
             f"prestrain span {float(parameters.prestrain_span):.6g}, chord {float(parameters.prestrain_chord):.6g}"
             + field,
             f"# cut perimeter (trailing edge around to trailing edge): root rib "
             f"{cuts['contour_cut_m'][0]:.6f} m, mid-bay {cuts['contour_cut_m'][mid]:.6f} m, tip rib "
             f"{cuts['contour_cut_m'][-1]:.6f} m",
             "j,surface,x_over_chord,arc_cut_root_m,arc_cut_mid_m,span_cut_m,span_mounted_m,span_prestrain,"
             "contour_prestrain"]
    contour_prestrain = cuts["contour_prestrain"]  # a flat panel's last node takes its last edge's
    contour_prestrain = np.concatenate([contour_prestrain, contour_prestrain[-1:]])[: bay.n_contour]
    for j in range(bay.n_contour):
        surface = "upper" if j <= j_le else "lower"
        lines.append(f"{j},{surface},{x[j]:.6f},{arc_root[j]:.6f},{arc_mid[j]:.6f},"
                     f"{cuts['span_cut_m'][j]:.6f},{cuts['span_mounted_m'][j]:.6f},"
                     f"{cuts['span_prestrain'][j]:.6g},{contour_prestrain[j]:.6g}")
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path


#: Names of the files a report writes (`report.write_report`). An
#: output folder may hold other files; `check_output_folder` refuses one that holds a file of these names
#: that no earlier report there wrote (`written_files`), before the long work.
REPORT_FILES = re.compile(r"summary\.json|equilibrium\.npz|wing\.npz|skin\.(obj|stl)|(bay_[0-9]+_)?cut_pattern\.csv|"
                          r"pattern_bay_[0-9]+_(upper|lower|panel)\.(dxf|svg)|rib_[0-9]+\.dxf|"
                          r"rib(_[0-9]+)?\.dat|(bay_[0-9]+_)?mid_bay_section\.png|"
                          r"(bay_[0-9]+_)?aero\.png|(deviation|tensions|history|rib_design|wing_overview|tolerance|cut_pattern_overview)\.png|"
                          r"tolerance_samples\.csv")
#: The summary of a report, whose ``files`` list the files that report wrote.
SUMMARY = "summary.json"
#: The summary's entry ``{name: {"bytes": size, "sha256": hex digest}}`` of the files it lists (`file_checksums`).
CHECKSUMS = "checksums"
#: Name (then 8 hex digits) of a staging folder inside an existing output folder.
_INSIDE = ".report.partial-"
#: The list of moves of a staging folder whose files are being moved into the output folder.
_JOURNAL = ".moves.json"
#: The lock file of a run into an existing output folder, inside it (`output_lock`).
_LOCK_INSIDE = ".report.lock"
#: Characters that the longest name made from the output folder's adds to it: ``.NAME.creating-`` and
#: 8 hex digits beside it (`staged_folder`).
_NAME_EXTRA = len("..creating-") + 8


def file_checksums(folder, names) -> dict:
    """``{name: {"bytes": size, "sha256": hex digest}}`` of the plain files ``names`` in ``folder``.

    A report stores it in its ``summary.json`` (`CHECKSUMS`) for the files it
    wrote, so that the next report into the folder can tell a file edited
    since from its own (`changed_files`).
    """
    folder = Path(folder)
    sums = {}
    for name in names:
        path = folder / name
        if name == SUMMARY or path.is_symlink() or not path.is_file():
            continue
        digest = hashlib.sha256()
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                digest.update(block)
        sums[name] = {"bytes": path.stat().st_size, "sha256": digest.hexdigest()}
    return sums


def _earlier_summary(out: Path) -> dict | None:
    """The earlier report's summary in ``out`` if it is one of this package's (`written_files`), else None."""
    path = out / SUMMARY
    if path.is_symlink() or not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not (isinstance(data, dict) and isinstance(data.get("package"), dict)
            and data["package"].get("name") == "inflatable-wing" and isinstance(data.get("files"), list)):
        return None
    return data


def written_files(out_dir) -> set[str]:
    """The files that the earlier report in ``out_dir`` wrote: the ``files`` of its ``summary.json``.

    Empty if there is no ``summary.json``, or it is not one of this
    package's (not JSON, or no ``package.name`` "inflatable-wing" and
    ``files`` list naming itself). Only plain names in the folder count.
    A listed file that changed since is still listed here (`changed_files`
    tells them apart).
    """
    data = _earlier_summary(Path(out_dir))
    if data is None:
        return set()
    files = {f for f in data["files"] if isinstance(f, str) and f == os.path.basename(f) and f[:1] not in ("", ".")}
    return files if SUMMARY in files else set()


def changed_files(out_dir) -> list[str]:
    """The files of the earlier report in ``out_dir`` that changed since it wrote them.

    A file listed in the earlier ``summary.json`` whose size or SHA-256
    differs from the summary's ``checksums`` (`file_checksums`): someone
    edited or replaced it, so it is no longer the report's to remove or
    replace. A file the summary has no checksum for (a report written before
    they were recorded) counts as unchanged; a file that is gone is not listed.
    """
    out = Path(os.path.abspath(os.fspath(out_dir)))
    data = _earlier_summary(out) if out.is_dir() else None
    sums = data.get(CHECKSUMS) if data is not None else None
    if not isinstance(sums, dict):
        return []
    changed = []
    for name in sorted(written_files(out)):
        record = sums.get(name)
        if not (isinstance(record, dict) and (out / name).is_file() and not (out / name).is_symlink()):
            continue
        now = file_checksums(out, [name]).get(name, {})
        if (record.get("bytes"), record.get("sha256")) != (now.get("bytes"), now.get("sha256")):
            changed.append(name)
    return changed


def _not_ours(out: Path, names, owned: set[str]) -> list[str]:
    """The ``names`` present in ``out`` that no earlier report wrote (a link or a folder never is ours)."""
    return sorted(n for n in names if (out / n).exists() or (out / n).is_symlink()
                  if n not in owned or (out / n).is_symlink() or not (out / n).is_file())


def _refuse(out: Path, clash: list[str]) -> ValueError:
    return ValueError(f"refusing to overwrite {out / clash[0]}"
                      + (f" (and {len(clash) - 1} more: {', '.join(clash[1:])})" if len(clash) > 1 else "")
                      + f": no earlier report wrote it (the {SUMMARY} there does not list it); "
                      f"move it away or choose another output folder")


def _refuse_changed(out: Path, changed: list[str]) -> ValueError:
    return ValueError(f"refusing to overwrite {out / changed[0]}"
                      + (f" (and {len(changed) - 1} more: {', '.join(changed[1:])})" if len(changed) > 1 else "")
                      + f": it changed since the earlier report wrote it (its size or SHA-256 differs from "
                      f"the record in {SUMMARY}); move it away (or rename it) to keep it, or choose another "
                      "output folder")


def _is_dir(path: Path) -> bool:
    """Whether ``path`` is a folder; False for a path the system cannot even look up (a name too long)."""
    try:
        return path.is_dir()
    except OSError:
        return False


def _check_name(out_dir) -> Path:
    """The absolute output path, after refusing an empty name and names too long for the file system."""
    text = os.fspath(out_dir)
    if (text.decode(errors="replace") if isinstance(text, bytes) else text) == "":
        raise ValueError("the output folder is an empty name (an unset shell variable?), which would put the "
                         "report's files in the current folder: give a folder name, or . for the current folder")
    out = Path(os.path.abspath(text))
    ancestor = out.parent
    while not _is_dir(ancestor) and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    try:
        limit = os.pathconf(ancestor, "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):
        limit = 255
    missing = out.relative_to(ancestor).parts
    for k, part in enumerate(missing):
        size = len(os.fsencode(part)) + (_NAME_EXTRA if k == len(missing) - 1 else 0)
        if size > limit:
            shown = part if len(part) <= 40 else part[:37] + "..."
            extra = (f" plus the {_NAME_EXTRA} characters of the temporary folder .NAME.creating-XXXXXXXX "
                     "made beside it" if k == len(missing) - 1 else "")
            raise ValueError(f"the output folder name {shown!r} is too long for this file system: "
                             f"{len(os.fsencode(part))} bytes{extra}, more than the {limit} bytes a name may have "
                             f"in {ancestor}; choose a shorter name")
    return out


def check_output_folder(out_dir, replaces=None) -> Path:
    """The absolute output path, after checking that `write_report` may write into it.

    The folder may hold other files (they are never touched); it must not
    hold a file of a report's name (`REPORT_FILES`) that no earlier report
    there wrote (`written_files`).

    Args:
        out_dir: the output folder.
        replaces: None, or a predicate on a file name: whether the new report
            may write a file of that name. An earlier report's file that
            changed since (`changed_files`) and that the new report may write
            is refused now, before the long work (without ``replaces``,
            `staged_folder` refuses it when it would replace it).

    Raises:
        ValueError: if ``out_dir`` is empty, or a name in it is too long for
            the file system, or it is a file, or holds such a file, or is
            not a writable folder (or, when it does not exist, its nearest
            existing parent is not).
    """
    out = _check_name(out_dir)
    try:
        if out.exists() or out.is_symlink():
            if not out.is_dir():
                raise ValueError(f"the output folder {out} exists and is not a folder; choose another path")
            clash = _not_ours(out, [p.name for p in out.iterdir() if REPORT_FILES.fullmatch(p.name)],
                              written_files(out))
            if clash:
                raise _refuse(out, clash)
            if replaces is not None:
                changed = [name for name in changed_files(out) if replaces(name)]
                if changed:
                    raise _refuse_changed(out, changed)
            parent = out
        else:
            parent = out.parent
            while not parent.exists():
                parent = parent.parent
    except OSError as exc:
        raise ValueError(f"cannot use the output folder {out}: {exc.strerror or exc}; choose another path") from None
    try:  # a real probe: permission bits do not tell everything (read-only mounts, /proc)
        os.rmdir(tempfile.mkdtemp(prefix=f".{out.name}.probe-", dir=parent))
    except OSError as exc:
        raise ValueError(f"cannot create the output folder {out}: {parent} is not a writable folder "
                         f"({exc.strerror or exc})") from None
    return out


@contextmanager
def output_lock(out_dir):
    """Hold an exclusive lock on the output folder ``out_dir`` while the block runs (a whole run).

    The lock is an ``fcntl.flock`` on a lock file: ``.report.lock`` inside an
    existing folder, ``.NAME.lock`` beside a new one (in its nearest existing
    parent, named after the missing part of the path); the file holds the
    holder's process id and is removed when the block ends. A second run into
    the same folder meanwhile is refused at once. Where a lock cannot be
    taken (no ``fcntl``, a file system without locks, a folder that cannot
    be written: `check_output_folder` says so) the block runs without one.
    A killed run (SIGKILL) leaves its lock file but not the lock: the next
    run takes it, and removes the file when it ends.

    Raises:
        ValueError: if another process holds the lock, naming it; or for
            an empty or too long name (`check_output_folder`).
    """
    out = _check_name(out_dir)
    if _is_dir(out):
        path = out / _LOCK_INSIDE
    else:
        ancestor = out.parent
        while not _is_dir(ancestor) and ancestor != ancestor.parent:
            ancestor = ancestor.parent
        path = ancestor / ("." + ".".join(out.relative_to(ancestor).parts) + ".lock")
    fd, holder = None, ""
    if fcntl is not None:
        try:
            fd, holder = _take_lock(path)
        except OSError:  # (cannot create it there: the folder checks say why)
            fd = None
    if holder:
        raise ValueError(f"another run is writing the output folder {out} ({holder} holds the lock {path}); "
                         "wait for it to end, or choose another output folder")
    try:
        with interrupts.undo_if_abandoned(lambda: fd is not None and os.unlink(path)):  # (a stopped run's)
            yield out
    finally:
        if fd is not None:
            try:
                os.unlink(path)
            except OSError:
                pass
            os.close(fd)


def _take_lock(path: Path) -> tuple[int | None, str]:
    """``(descriptor, "")``: an open descriptor of the lock file ``path`` under an exclusive ``flock``;
    or ``(None, holder)`` if another process holds it. Raises OSError where the file cannot be made or
    locks are not available."""
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                os.close(fd)
                raise
            try:
                holder = os.read(fd, 64).decode(errors="replace").strip()
            except OSError:
                holder = ""
            os.close(fd)
            return None, f"process {holder}" if holder.isdigit() else "another process"
        try:  # still the file at ``path``? (its holder removes it as it releases the lock)
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            os.ftruncate(fd, 0)
            os.write(fd, str(os.getpid()).encode())
            return fd, ""
        os.close(fd)


def _partial_pattern(out: Path, inside: bool = False) -> re.Pattern:
    """Names of the staging folders of ``out`` (`staged_folder`): ``.NAME.partial-`` and 8 hex digits
    beside it, or ``.report.partial-`` and 8 hex digits inside it."""
    return re.compile(re.escape(_INSIDE if inside else f".{out.name}.partial-") + "[0-9a-f]{8}")


def _try_lock(folder: Path) -> int | None:
    """An open descriptor of ``folder`` holding an exclusive ``flock``, or None if it cannot be locked.

    None when another process holds the lock, when the file system refuses
    locks, or without ``fcntl``. The lock lasts until the descriptor is
    closed, or the process dies (a SIGKILL included), and follows the folder
    through a rename.
    """
    if fcntl is None:
        return None
    try:
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return None
    return fd


def remove_stale_partials(out_dir) -> list[Path]:
    """Finish or remove the staging folders that killed writers of ``out_dir`` left.

    Only folders named exactly as `staged_folder` names those of this
    ``out_dir`` (beside it, or inside it) whose writer is gone: a writer holds
    a lock on its folder until it ends, so a folder still being written (by
    another run to the same ``out_dir``) is left alone, and so is every
    folder where locks are not available (Windows, some network file
    systems). A folder killed while its files were being moved into
    ``out_dir`` (it holds their list) is finished: its remaining files are
    moved in; any other is removed.

    Returns:
        The folders finished or removed.
    """
    out = Path(os.path.abspath(os.fspath(out_dir)))
    places = [(out.parent, False)] + ([(out, True)] if out.is_dir() and not out.is_symlink() else [])
    removed = []
    for place, inside in places:
        if not place.is_dir():
            continue
        pattern = _partial_pattern(out, inside)
        for entry in sorted(place.iterdir()):
            if not pattern.fullmatch(entry.name) or entry.is_symlink() or not entry.is_dir():
                continue
            fd = _try_lock(entry)
            if fd is None:
                continue
            try:
                moves = _read_moves(entry)
                if moves is not None and out.is_dir():
                    _move_in(entry, out, *moves)
                shutil.rmtree(entry, ignore_errors=True)
            finally:
                os.close(fd)
            removed.append(entry)
    return removed


def _read_moves(staging: Path):
    """``(names, stale)`` of a staging folder's move list, or None if it has none (or it is unreadable)."""
    try:
        moves = json.loads((staging / _JOURNAL).read_text(encoding="utf-8"))
        names, stale = moves["files"], moves["remove"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    ok = all(isinstance(n, str) and n == os.path.basename(n) and n[:1] not in ("", ".") for n in names + stale)
    return (names, stale) if ok else None


def _move_in(staging: Path, out: Path, names: list[str], stale: list[str]) -> None:
    """Move the files ``names`` of ``staging`` into ``out`` (each replacing its namesake: a file of an
    earlier report), remove the earlier report's files ``stale``; the summary last, so that until then
    the earlier summary lists every report file in ``out``. Repeating it finishes an interrupted one."""
    for name in sorted(names, key=lambda n: n == SUMMARY):
        if name == SUMMARY:
            for old in stale:
                path = out / old
                if path.is_file() and not path.is_symlink():
                    path.unlink()
        source = staging / name
        if source.is_file():
            os.replace(source, out / name)


def _commit(staging: Path, out: Path) -> None:
    """Put the finished ``staging`` folder's files in place (`staged_folder`)."""
    if not (out.exists() or out.is_symlink()):
        try:
            os.rename(staging, out)  # a new folder: one atomic rename
            return
        except OSError:
            if not out.is_dir():  # (else another run created it meanwhile: merge into it)
                raise
    names = sorted(p.name for p in staging.iterdir())
    owned = written_files(out)
    clash = _not_ours(out, names, owned)
    if clash:
        raise _refuse(out, clash)
    changed = changed_files(out)  # (edited since the earlier report: kept, never replaced)
    replaced = [n for n in changed if n in names]
    if replaced:
        raise _refuse_changed(out, replaced)
    stale = sorted(n for n in owned - set(names) - set(changed) if (out / n).is_file() and not (out / n).is_symlink())
    (staging / _JOURNAL).write_text(json.dumps({"files": names, "remove": stale}))
    _move_in(staging, out, names, stale)
    shutil.rmtree(staging, ignore_errors=True)


def _discard(staging: Path) -> None:
    """Remove the staging folder of a run that another thread abandoned while it may still write into
    it: renamed first (its writer's later paths then fail), then removed."""
    trash = staging.with_name(staging.name.replace(".partial-", ".discarded-"))
    os.rename(staging, trash)
    shutil.rmtree(trash, ignore_errors=True)


@contextmanager
def staged_folder(out_dir):
    """Write a report's files atomically: yield a temporary folder, put its files in place on success.

    A new ``out_dir`` is the temporary folder (``.NAME.partial-`` and 8 hex
    digits, beside it) renamed. Into an existing one (checked by
    `check_output_folder`), the temporary folder (``.report.partial-`` and 8
    hex digits, inside it) has its files moved one by one, each replacing
    only its namesake of an earlier report; the earlier report's files that
    this one does not write (listed in its ``summary.json``, e.g. ``rib.dat``
    of a rib-shape run) are removed, unless they changed since
    (`changed_files`: kept), and ``summary.json`` comes last; a changed file
    that this report would replace is refused (ValueError, nothing moved). Every
    other file in ``out_dir`` is left as it is; ``out_dir`` itself is never
    removed. On any exception before that, KeyboardInterrupt included, the
    temporary folder is removed and ``out_dir`` is left as it was; a stop
    (`interrupts`) that arrives while the files move is held until they are
    in place. A temporary folder that a killed process (SIGKILL, power loss)
    left behind is removed, or its moves finished, by the next writer of the
    same ``out_dir`` (`remove_stale_partials`); the writer locks its own
    until it ends.
    """
    out = check_output_folder(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_partials(out)
    inside = out.is_dir() and not out.is_symlink()
    place, prefix = (out, _INSIDE) if inside else (out.parent, f".{out.name}.partial-")
    tag = uuid.uuid4().hex[:8]
    # Created under a name outside the pattern and renamed once locked, so that a concurrent
    # `remove_stale_partials` never sees it unlocked.
    creating = place / f"{prefix.replace('.partial-', '.creating-')}{tag}"
    creating.mkdir()  # (not mkdtemp: the folder keeps the user's umask permissions)
    lock = _try_lock(creating)
    staging = place / f"{prefix}{tag}"
    try:
        os.rename(creating, staging)
    except BaseException:
        shutil.rmtree(creating, ignore_errors=True)
        if lock is not None:
            os.close(lock)
        raise
    try:
        with interrupts.undo_if_abandoned(lambda: _discard(staging)):  # (a stopped run's: `interrupts`)
            yield staging
        with interrupts.deferred():  # a stop recorded until now is raised here, before anything moves
            _commit(staging, out)
    except BaseException:
        if _read_moves(staging) is None:  # (with its list of moves, the next writer finishes it)
            shutil.rmtree(staging, ignore_errors=True)
        raise
    finally:
        if lock is not None:
            os.close(lock)
