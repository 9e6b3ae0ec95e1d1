"""The command tests' cases: the small grid, the options of a run in the test's own process, case files.

Every command test runs on the small grid (`SMALL`, 5 x 32), so that the
suite's processes and subprocesses share their compilations; a run in the
test's own process (`cli.main`) also leaves JAX's configuration alone and
prints nothing but errors (`IN_PROCESS`). `case_text` writes a case file:
options, tables (``[tolerances]``) and ``[[rib]]`` tables.
"""

from __future__ import annotations

#: The command tests' grid: 5 span nodes, 32 contour nodes.
SMALL = ("--n-span", "5", "--n-contour", "32")
#: Options of a run in the test's own process: no compilation cache of the command's own, no console.
IN_PROCESS = ("--no-compilation-cache", "--quiet")


def _value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    return repr(value)


def rib_tables(*ribs) -> str:
    """``[[rib]]`` tables of ``(section, chord, station)`` triples, root to tip."""
    return "".join(f'[[rib]]\nsection = "{section}"\nchord = {chord!r}\nstation = {station!r}\n'
                   for section, chord, station in ribs)


def case_text(*ribs, tables: dict | None = None, **options) -> str:
    """A case file: ``options`` (``n_span=5`` as ``n-span = 5``), then ``tables`` (``{name: {key: value}}``),
    then the ``[[rib]]`` tables of ``ribs`` (`rib_tables`)."""
    lines = [f"{name.replace('_', '-')} = {_value(value)}\n" for name, value in options.items()]
    for name, table in (tables or {}).items():
        lines.append(f"\n[{name}]\n" + "".join(f"{key} = {_value(value)}\n" for key, value in table.items()) + "\n")
    return "".join(lines) + rib_tables(*ribs)


#: A bay as a two-rib case file, on the small grid: the same bay as the default options'.
TWO_RIBS = case_text(("naca2412", 1.0, 0.0), ("naca2412", 1.0, 0.25), n_span=5, n_contour=32)
#: A tapered bay (chords 1.0 and 0.9 m) designed for its pressure, on the small grid.
TAPERED_BAY = case_text(("naca2412", 1.0, 0.0), ("naca2412", 0.9, 0.25), variables=["pressure"], n_span=5,
                        n_contour=32)
