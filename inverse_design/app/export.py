"""Files of a design: the equilibrium as ``.npz``, the skin as OBJ and STL, and the atomic output folder.

`write_npz`, `write_obj` and `write_stl` write one file each. The output
folder is written atomically (`staged_folder`): into a hidden temporary
folder next to the destination, renamed into place when complete. An
earlier folder of the same name is replaced only then, and only if it is
empty or holds a ``summary.json`` (so a mistyped ``out_dir`` never deletes
unrelated files; `check_output_folder`). Temporary folders that a killed
writer left behind are removed by the next `staged_folder` of the same
destination (`remove_stale_partials`).
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
import uuid
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from forward_solver import Solution

from ..optimise import DesignResult

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows: no flock, stale folders are left alone
    fcntl = None

__all__ = [
    "check_output_folder",
    "deviation",
    "remove_stale_partials",
    "staged_folder",
    "write_cut_pattern",
    "write_npz",
    "write_obj",
    "write_selig",
    "write_stl",
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
    path = Path(path)
    with open(path, "wb") as f:
        np.savez_compressed(f, **arrays)
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
    length of the span fibre through the node, rib to rib) and
    ``span_mounted_m`` (its mounted length). The ``# `` header lines give
    the prestrains and each row's cut perimeter.
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
    lines = [f"# cut lengths of the fabric: reference length = mounted length / (1 + prestrain), "
             f"prestrain span {float(parameters.prestrain_span):.6g}, chord {float(parameters.prestrain_chord):.6g}",
             f"# cut perimeter (trailing edge around to trailing edge): root rib "
             f"{cuts['contour_cut_m'][0]:.6f} m, mid-bay {cuts['contour_cut_m'][mid]:.6f} m, tip rib "
             f"{cuts['contour_cut_m'][-1]:.6f} m",
             "j,surface,x_over_chord,arc_cut_root_m,arc_cut_mid_m,span_cut_m,span_mounted_m"]
    for j in range(bay.n_contour):
        surface = "upper" if j <= j_le else "lower"
        lines.append(f"{j},{surface},{x[j]:.6f},{arc_root[j]:.6f},{arc_mid[j]:.6f},"
                     f"{cuts['span_cut_m'][j]:.6f},{cuts['span_mounted_m'][j]:.6f}")
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path


def check_output_folder(out_dir) -> Path:
    """The absolute output path, after checking that `write_report` may write (and replace) it.

    Raises:
        ValueError: if ``out_dir`` is a file, or a non-empty folder that holds
            no ``summary.json`` of an earlier report (it is never replaced), or
            its nearest existing parent is not a writable folder.
    """
    out = Path(os.path.abspath(os.fspath(out_dir)))
    if out.exists() or out.is_symlink():
        if not out.is_dir():
            raise ValueError(f"the output folder {out} exists and is not a folder; choose another path")
        if any(out.iterdir()) and not (out / "summary.json").is_file():
            raise ValueError(f"refusing to replace {out}: it is not empty and holds no summary.json of "
                             f"an earlier report; choose another output folder or empty this one")
    parent = out.parent
    while not parent.exists():
        parent = parent.parent
    try:  # a real probe: permission bits do not tell everything (read-only mounts, /proc)
        os.rmdir(tempfile.mkdtemp(prefix=f".{out.name}.probe-", dir=parent))
    except OSError as exc:
        raise ValueError(f"cannot create the output folder {out}: {parent} is not a writable folder "
                         f"({exc.strerror or exc})") from None
    return out


def _partial_pattern(out: Path) -> re.Pattern:
    """Names of the temporary folders of ``out``: ``.NAME.partial-`` and 8 hex digits (`staged_folder`)."""
    return re.compile(re.escape(f".{out.name}.partial-") + "[0-9a-f]{8}")


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
    """Remove the temporary folders that killed writers of ``out_dir`` left beside it.

    Only folders named exactly as `staged_folder` names those of this
    ``out_dir`` (``.NAME.partial-`` and 8 hex digits) whose writer is gone:
    a writer holds a lock on its folder until it ends, so a folder still being
    written (by another run to the same ``out_dir``) is left alone, and so is
    every folder where locks are not available (Windows, some network file
    systems).

    Returns:
        The folders removed.
    """
    out = Path(os.path.abspath(os.fspath(out_dir)))
    if not out.parent.is_dir():
        return []
    pattern, removed = _partial_pattern(out), []
    for entry in sorted(out.parent.iterdir()):
        if not pattern.fullmatch(entry.name) or entry.is_symlink() or not entry.is_dir():
            continue
        fd = _try_lock(entry)
        if fd is None:
            continue
        try:
            shutil.rmtree(entry, ignore_errors=True)
        finally:
            os.close(fd)
        removed.append(entry)
    return removed


@contextmanager
def staged_folder(out_dir):
    """Write a folder atomically: yield a temporary folder, rename it to ``out_dir`` on success.

    The temporary folder (``.NAME.partial-`` and 8 hex digits) sits next to
    ``out_dir``, so the final rename stays on one file system. An existing
    ``out_dir`` (checked by `check_output_folder`) is moved aside and deleted
    only after the new folder is in place. On any exception, KeyboardInterrupt
    included, the temporary folder is removed and ``out_dir`` is left as it
    was. A temporary folder that a killed process (SIGKILL, power loss) left
    behind is removed here by the next writer of the same ``out_dir``
    (`remove_stale_partials`); the writer locks its own until it ends.
    """
    out = check_output_folder(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_partials(out)
    tag = uuid.uuid4().hex[:8]
    # Created under a name outside the pattern and renamed once locked, so that a concurrent
    # `remove_stale_partials` never sees it unlocked.
    creating = out.parent / f".{out.name}.creating-{tag}"
    creating.mkdir()  # (not mkdtemp: the folder keeps the user's umask permissions)
    lock = _try_lock(creating)
    staging = out.parent / f".{out.name}.partial-{tag}"
    try:
        os.rename(creating, staging)
    except BaseException:
        shutil.rmtree(creating, ignore_errors=True)
        if lock is not None:
            os.close(lock)
        raise
    try:
        yield staging
        old = None
        if out.exists() or out.is_symlink():
            old = out.parent / f".{out.name}.old-{uuid.uuid4().hex[:8]}"
            os.rename(out, old)
        try:
            os.rename(staging, out)
        except BaseException:
            if old is not None:
                os.rename(old, out)
            raise
        if old is not None:
            if old.is_dir() and not old.is_symlink():
                shutil.rmtree(old, ignore_errors=True)
            else:
                old.unlink()
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    finally:
        if lock is not None:
            os.close(lock)
