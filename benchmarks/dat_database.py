"""Load every ``.dat`` file of a folder with :func:`targets.load_airfoil` and tabulate the outcome.

Meant for the UIUC airfoil database as AeroSandbox ships it::

    pip download --no-deps -d /tmp/asb aerosandbox
    cd /tmp/asb && unzip -q aerosandbox-*.whl 'aerosandbox/geometry/airfoil/airfoil_database/*'
    python benchmarks/dat_database.py /tmp/asb/aerosandbox/geometry/airfoil/airfoil_database

Each file ends in one of three outcomes: loaded, loaded with a warning (e.g.
a renormalised chord), or refused (``ValueError``). Refusals and warnings are
grouped by message class: the message without the file name, with numbers,
quoted text and line numbers replaced by placeholders. A loaded airfoil then
passes a sanity check or not: its thickness and camber evaluate at 201
cosine-spaced stations without an exception and its maximum thickness lies
in (0, 0.5) chord.

The outcome counts and the message classes are saved as
``benchmarks/results/dat_database.json`` for ``benchmarks/performance_doc.py``.

Usage: python benchmarks/dat_database.py FOLDER [--examples N] [--list CLASS_SUBSTRING]
"""

from __future__ import annotations

import argparse
import re
import sys
import time
import warnings
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.results import save_result  # noqa: E402
from targets import load_airfoil  # noqa: E402


def message_class(message: str, path: Path | None) -> str:
    """The message with the file name, quoted text and numbers replaced by placeholders."""
    text = message if path is None else message.replace(str(path), "FILE")
    text = re.sub(r"'(\\.|[^'\\])*'|\"(\\.|[^\"\\])*\"", "'...'", text)
    text = re.sub(r"\(lines? [^)]*\)", "(line N)", text)
    text = re.sub(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?", "N", text)
    return text


def sanity_error(airfoil) -> str | None:
    """Why a loaded airfoil fails the basic checks, or None when it passes."""
    try:
        le = float(airfoil.leading_edge[0])
        te = float(min(airfoil.x[0], airfoil.x[-1]))
        stations = le + (te - le) * 0.5 * (1.0 - np.cos(np.linspace(0.0, np.pi, 201)))
        thickness = airfoil.thickness(stations)
        airfoil.camber(stations)
        peak = airfoil.max_thickness
    except ValueError as err:
        return message_class(str(err), None)
    if not np.all(np.isfinite(thickness)):
        return "thickness not finite"
    if not 0.0 < peak < 0.5:
        return f"max thickness {peak:.3g} outside (0, 0.5)"
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, help="folder holding the .dat files")
    parser.add_argument("--examples", type=int, default=2, help="file names shown per class")
    parser.add_argument("--list", default=None, help="print every file whose class contains this")
    args = parser.parse_args()

    files = sorted(args.folder.glob("*.dat"))
    if not files:
        raise SystemExit(f"no .dat files in {args.folder}")
    outcome: Counter[str] = Counter()
    refused: dict[str, list[str]] = defaultdict(list)
    warned: dict[str, list[str]] = defaultdict(list)
    insane: dict[str, list[str]] = defaultdict(list)
    start = time.perf_counter()
    for path in files:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                airfoil = load_airfoil(path)
            except ValueError as err:
                outcome["refused"] += 1
                refused[message_class(str(err), path)].append(path.name)
                continue
            except Exception as err:  # noqa: BLE001 - a crash is a finding, not a refusal
                outcome["crashed"] += 1
                refused[f"CRASH {type(err).__name__}: {err}"].append(path.name)
                continue
        if caught:
            outcome["loaded with warning"] += 1
            for record in caught:
                kind = f"{record.category.__name__}: {message_class(str(record.message), path)}"
                warned[kind].append(path.name)
        else:
            outcome["loaded"] += 1
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            problem = sanity_error(airfoil)
        if problem is not None:
            insane[problem].append(path.name)
    elapsed = time.perf_counter() - start

    def table(title: str, groups: dict[str, list[str]]) -> None:
        print(f"\n{title}")
        for text, names in sorted(groups.items(), key=lambda item: -len(item[1])):
            shown = ", ".join(names[: args.examples])
            print(f"{len(names):6d}  {text}\n        e.g. {shown}")
            if args.list is not None and args.list in text:
                print("        all: " + " ".join(names))

    print(f"{len(files)} files in {args.folder} ({elapsed:.1f} s)")
    print(f"{'outcome':<24}{'files':>6}")
    for key in ("loaded", "loaded with warning", "refused", "crashed"):
        print(f"{key:<24}{outcome[key]:6d}")
    n_insane = sum(len(names) for names in insane.values())
    print(f"{'loaded, failing sanity':<24}{n_insane:6d}")
    table("Refusals by message class", refused)
    table("Warnings by message class", warned)
    table("Loaded but failing the sanity check", insane)
    rows = [[key, outcome[key], ""] for key in ("loaded", "loaded with warning", "refused", "crashed")]
    rows.append(["loaded, failing sanity", n_insane, ""])
    for title, groups in (("refused", refused), ("warned", warned), ("failing sanity", insane)):
        rows += [[f"{title}: {text}", len(names), ", ".join(names[: args.examples])]
                 for text, names in sorted(groups.items(), key=lambda item: -len(item[1]))]
    save_result("dat_database", title="Every .dat file of an airfoil database through load_airfoil",
                command=f"python benchmarks/dat_database.py {args.folder}", columns=["outcome", "files", "e.g."],
                rows=rows, notes=[f"{len(files)} files in {args.folder}; the module docstring says how to get "
                                  "the UIUC database that AeroSandbox ships and what the sanity check is."])


if __name__ == "__main__":
    main()
