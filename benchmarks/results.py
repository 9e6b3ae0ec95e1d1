"""One record per benchmark: ``benchmarks/results/<name>.json``, read by ``performance_doc.py``.

Every benchmark that reports a measurement saves it with `save_result`, and
``python benchmarks/performance_doc.py`` turns every saved file into
``docs/performance.md``, so no number in that page is typed by hand. A file
holds one table::

    {"title": str, "command": str (how to reproduce), "machine": str,
     "date": "YYYY-MM-DD", "columns": [str, ...], "rows": [[cell, ...], ...],
     "notes": [str, ...]}

with cells that are numbers or strings (None is written as null and shown
empty).
"""

from __future__ import annotations

import datetime
import json
import math
import os
import platform
import subprocess
import sys
from pathlib import Path
from typing import Any, Iterable, Sequence

RESULTS = Path(__file__).resolve().parent / "results"


def print_result(path: Path, rows, notes=()) -> None:
    """Print a saved table's rows and notes, then where it was saved."""
    for line in [*rows, *notes, path]:
        print(line)


def fresh_process_json(code: str, cwd: Path) -> dict:
    """Run ``code`` in a fresh Python process (``python -c``, in ``cwd``) and return the JSON object on
    the last line of its standard output (a failing probe raises, with its output)."""
    ran = subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, check=True)
    return json.loads(ran.stdout.strip().splitlines()[-1])


def blas_as_in_the_command():
    """A context in which BLAS runs on one thread, as the ``optimise-pressure`` command runs it
    (`inverse_design.app.cli`). The solver is imported first: ``threadpoolctl`` limits only the BLAS
    libraries already loaded (NumPy's and SciPy's)."""
    from threadpoolctl import threadpool_limits

    import inverse_design.tolerance  # noqa: F401

    return threadpool_limits(limits=1, user_api="blas")


def _processor() -> str:
    """The processor's model name where the system says it, else the architecture."""
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_description() -> str:
    """The machine a measurement ran on: processor, cores, load, OS, Python, JAX and its backend.

    Returns:
        One line, e.g. ``"AMD EPYC 9B14, 2 CPU cores, load 3.1 at the end, Linux, Python 3.11.7,
        jax 0.10.2 (cpu)"``.
    """
    parts = [_processor(), f"{os.cpu_count()} CPU cores"]
    if hasattr(os, "getloadavg"):
        parts.append(f"load {os.getloadavg()[0]:.1f} at the end")
    parts += [platform.system(), f"Python {platform.python_version()}"]
    try:
        import jax
    except ImportError:
        pass
    else:
        parts.append(f"jax {jax.__version__} ({jax.default_backend()})")
    return ", ".join(parts)


def _cell(value: Any) -> Any:
    """A JSON cell: numbers stay numbers (NumPy scalars become Python ones), the rest a string."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if hasattr(value, "item") and getattr(value, "shape", None) == ():
        value = value.item()
    if isinstance(value, (int, float)):
        return value if not isinstance(value, float) or math.isfinite(value) else str(value)
    return str(value)


def save_result(name: str, *, title: str, command: str, columns: Sequence[str],
                rows: Iterable[Sequence[Any]], notes: Sequence[str] = (), machine: str | None = None,
                date: str | None = None, folder: Path | None = None) -> Path:
    """Write one benchmark table to ``<folder>/<name>.json``.

    Args:
        name: the file's stem (letters, digits, ``_`` and ``-``); sections of
            ``docs/performance.md`` are sorted by it.
        title: what was measured, one line.
        command: the shell command that reproduces the table, from the
            repository root.
        columns: the column headings, with units.
        rows: one sequence of cells per row, as many as ``columns``.
        notes: sentences printed under the table (case, reference, caveats).
        machine: where it ran; default `machine_description()`.
        date: ``YYYY-MM-DD``; default today (UTC).
        folder: default ``benchmarks/results``.

    Returns:
        The path written.

    Raises:
        ValueError: a bad name, or a row whose length differs from ``columns``.
    """
    if not name or not all(c.isalnum() or c in "_-" for c in name):
        raise ValueError(f"result name must be letters, digits, '_' or '-', got {name!r}")
    columns = [str(c) for c in columns]
    table = []
    for k, row in enumerate(rows):
        row = [_cell(v) for v in row]
        if len(row) != len(columns):
            raise ValueError(f"row {k} of {name!r} has {len(row)} cells for {len(columns)} columns")
        table.append(row)
    record = {
        "title": title,
        "command": command,
        "machine": machine if machine is not None else machine_description(),
        "date": date if date is not None else datetime.datetime.now(datetime.timezone.utc).date().isoformat(),
        "columns": columns,
        "rows": table,
        "notes": [str(n) for n in notes],
    }
    folder = RESULTS if folder is None else Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.json"
    path.write_text(json.dumps(record, indent=1) + "\n")
    return path
