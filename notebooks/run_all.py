"""Execute the study notebooks and write them back with their outputs.

The notebooks read the environment variable ``WING_FULL_STUDY``: "1" runs the
full study (what is committed), anything else the small mode (under a minute
each, what the test suite runs). This script sets it for the kernel, runs each
notebook top to bottom in a fresh kernel from this folder, and writes it back
in place with its outputs (unless ``--no-write``).

Usage (from the repository root)::

    python notebooks/run_all.py                  # every notebook, full study, written back
    python notebooks/run_all.py 02               # only notebooks whose name starts with 02
    python notebooks/run_all.py --small 01 03    # small mode (overwrites the committed outputs!)
    python notebooks/run_all.py --small --no-write   # small mode, check only

Timings printed in the notebooks (notebook 2 above all) are only meaningful
when nothing else runs on the machine.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import nbformat
from nbclient import NotebookClient

HERE = Path(__file__).resolve().parent


def notebooks(names: list[str]) -> list[Path]:
    found = sorted(HERE.glob("[0-9][0-9]_*.ipynb"))
    if not names:
        return found
    chosen = [p for p in found if any(p.name.startswith(n) or p.stem == n for n in names)]
    missing = [n for n in names if not any(p.name.startswith(n) or p.stem == n for p in found)]
    if missing:
        raise SystemExit(f"no notebook matches {missing}; have {[p.name for p in found]}")
    return chosen


def strip_noise(nb) -> None:
    """Drop per-run metadata (cell timings, widget state) so reruns diff cleanly."""
    nb.metadata.pop("widgets", None)
    nb.metadata["language_info"] = {"name": "python"}  # no interpreter version churn
    for cell in nb.cells:
        cell.metadata.pop("execution", None)
        cell.metadata.pop("ExecuteTime", None)


def execute(path: Path, full: bool, timeout: int, write: bool) -> float:
    os.environ["WING_FULL_STUDY"] = "1" if full else "0"  # the kernel inherits it
    nb = nbformat.read(path, as_version=4)
    start = time.perf_counter()
    NotebookClient(nb, timeout=timeout, kernel_name="python3",
                   resources={"metadata": {"path": str(HERE)}}).execute()
    seconds = time.perf_counter() - start
    if write:
        strip_noise(nb)
        nbformat.write(nb, path)
    return seconds


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help="notebook name prefixes (default: all)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--full", dest="full", action="store_true", default=True,
                      help="full study (default)")
    mode.add_argument("--small", dest="full", action="store_false", help="small mode")
    parser.add_argument("--no-write", dest="write", action="store_false",
                        help="execute only, leave the files untouched")
    parser.add_argument("--timeout", type=int, default=1800, help="per-cell timeout, s")
    args = parser.parse_args(argv)
    for path in notebooks(args.names):
        print(f"{path.name}: {'full' if args.full else 'small'} mode ...", flush=True)
        seconds = execute(path, args.full, args.timeout, args.write)
        print(f"{path.name}: {seconds:.0f} s{', written' if args.write else ''}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
