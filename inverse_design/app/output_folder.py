"""The output folder as a transaction: checked, locked, staged, journalled, put in place.

The folder may hold other files: a report writes only its own, replacing
only the files of an earlier report there (those its ``summary.json`` lists:
`written_files`) and removing that report's files it does not write;
nothing else is touched, and the folder itself is never removed. It is
checked once, before the long work (`check_output_folder`), then written
atomically (`staged_folder`): into a hidden temporary folder whose files
move in, from a journal of their moves, only when all are written, the
ownership rules applied again as they do. Temporary folders that a killed
writer left behind are removed, or their moves finished, by the next writer
(`remove_stale_partials`). A report records the size and SHA-256 of every
file it wrote (``checksums``: `file_checksums`); a file that changed since
(a ``rib.dat`` edited by hand) is no longer the report's (`changed_files`):
it is never removed, and a report that would replace it is refused. A run
holds `output_lock` on its folder from start to end, so a second run into it
is refused at once instead of racing the first.
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

from . import interrupts

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows: no flock, stale folders are left alone
    fcntl = None

__all__ = ["REPORT_FILES", "changed_files", "check_output_folder", "file_checksums", "output_lock",
           "remove_stale_partials", "staged_folder", "written_files"]


#: Names of the files a report writes (`folder.write_report`). An
#: output folder may hold other files; `check_output_folder` refuses one that holds a file of these names
#: that no earlier report there wrote (`written_files`), before the long work.
REPORT_FILES = re.compile(r"summary\.json|equilibrium\.npz|wing\.npz|skin\.(obj|stl)|(bay_[0-9]+_)?cut_pattern\.csv|"
                          r"pattern_bay_[0-9]+_(upper|lower|panel)\.(dxf|svg)|rib_[0-9]+\.dxf|"
                          r"rib(_[0-9]+)?\.dat|(bay_[0-9]+_)?mid_bay_section\.png|"
                          r"(bay_[0-9]+_)?aero\.png|(deviation|tensions|history|rib_design|wing_overview|tolerance|cut_pattern_overview)\.png|"
                          r"tolerance_samples\.csv|marker\.(dxf|svg|png)")
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
    """The absolute output path, after checking that a report (`folder.write_report`) may write into it.

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
def staged_folder(out):
    """Write a report's files atomically into ``out`` (the folder `check_output_folder` returned): yield a
    temporary folder, put its files in place on success.

    A new ``out`` is the temporary folder (``.NAME.partial-`` and 8 hex
    digits, beside it) renamed. Into an existing one the temporary folder
    (``.report.partial-`` and 8 hex digits, inside it) has its files moved one
    by one, each replacing only its namesake of an earlier report; the
    earlier report's files that this one does not write are removed, unless
    they changed since (`changed_files`: kept), and ``summary.json`` comes
    last; a changed file that this report would replace is refused
    (ValueError, nothing moved). On any exception before that,
    KeyboardInterrupt included, the temporary folder is removed and ``out``
    is left as it was; a stop (`interrupts`) that arrives while the files
    move is held until they are in place. The writer locks its temporary
    folder until it ends (`remove_stale_partials` leaves it alone).
    """
    out = Path(os.path.abspath(os.fspath(out)))
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
