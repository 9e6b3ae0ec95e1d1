"""A TOML case file (``--config``) read as the command line is: the same keys, types and choices.

A case file's keys are the long option names (`options.OPTIONS`, with ``-``
or ``_``); ``[[rib]]`` tables describe a wing (`read_ribs`; a single bay is
the wing of its two ribs), a ``[tolerances]`` table the manufacturing
tolerances (`read_tolerances`) and a ``[fabric]`` table the fabric
(`read_fabric`: its biaxial ``test`` file, ``warp``, ``shear-stiffness``,
...; a test file's relative path is relative to the case file's folder). A section is a NACA code or a
Selig/Lednicer ``.dat`` file, a relative path being relative to the case
file's folder (`case_path`). `case.Case.from_arguments` merges what
`read_config` returns between the defaults and the command line.

A wing case file: the README's "A whole wing"; a built-in one:
``inverse_design/cases/wing_taper.toml`` (`EXAMPLE_CASE`).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from .options import OPTION_SPECS, PROG, InputError

__all__ = ["EXAMPLE_CASE", "EXAMPLE_FABRIC_TEST", "FABRIC_KEYS", "RIB_KEYS", "case_path", "read_config", "read_fabric",
           "read_ribs", "read_tolerances"]

#: Keys of a ``[fabric]`` table: ``test`` is ``--fabric-test``, the others the options of their names.
FABRIC_KEYS = ("test", "warp", "shear-stiffness", "stiffness-span", "stiffness-chord", "poisson")
#: Keys of a ``[[rib]]`` table: required, then optional.
RIB_KEYS = (("section", "chord", "station"), ("target",))
#: The built-in example: a 3-bay tapered NACA 2412 wing.
EXAMPLE_CASE = Path(__file__).parents[1] / "cases" / "wing_taper.toml"
#: The example biaxial test of a fabric (synthetic: `model.biaxial.synthetic.example_readings`; docs/fabric_test.md).
EXAMPLE_FABRIC_TEST = Path(__file__).parents[1] / "cases" / "fabric_test_example.csv"


def _toml_value(path: str, key: str, value):
    """A case-file value converted and validated as the command line would."""
    dest = key.replace("-", "_")
    spec = OPTION_SPECS.get(dest)
    if spec is None or dest == "config":
        raise InputError(f"{path}: unknown key {key!r}; keys are the long option names of "
                         f"{PROG} --help (e.g. n-span, pressure-bounds)")
    if spec.get("action") == "store_true":
        if not isinstance(value, bool):
            raise InputError(f"{path}: {key} must be true or false, got {value!r}")
        return value
    convert = spec.get("type", str)

    numeric = getattr(convert, "numeric", False)

    def one(item):
        if numeric and (isinstance(item, (bool, str)) or not isinstance(item, (int, float))):
            raise InputError(f"{path}: {key} must be a number, got {_toml_text(item)}{_number_hint(item)}, e.g. "
                             f"{key} = {_example(spec)}")
        if isinstance(item, (bool, dict, list)) or not isinstance(item, (int, float, str)):
            raise InputError(f"{path}: {key} must be a single value, got {_toml_text(item)}")
        try:
            converted = convert(str(item))
        except argparse.ArgumentTypeError as exc:
            raise InputError(f"{path}: {key}: {exc}") from None
        if spec.get("choices") and converted not in spec["choices"]:
            raise InputError(f"{path}: {key} must be one of {', '.join(spec['choices'])}, got {item!r}")
        return converted

    if spec.get("nargs") == 2:
        if not (isinstance(value, list) and len(value) == 2):
            raise InputError(f"{path}: {key} must be a pair [low, high], got {value!r}")
        return tuple(one(v) for v in value)
    if spec.get("nargs") == 3:
        if not (isinstance(value, list) and len(value) == 3):
            raise InputError(f"{path}: {key} must be a list [start, stop, step], got {value!r}")
        return tuple(one(v) for v in value)
    if dest == "variables" and isinstance(value, list):
        if not all(isinstance(v, str) for v in value):
            raise InputError(f"{path}: variables must be a list of names, got {value!r}")
        value = ",".join(value)
    return one(value)


def _toml_text(value) -> str:
    """``value`` as a case file writes it (``true``, the string "17", a table, a list)."""
    if isinstance(value, str):
        return f'the string "{value}"'
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, dict):
        return "a table"
    return repr(value)


def _number_hint(item) -> str:
    """What to change where a case file gives a number as something else."""
    return ": write it without quotes" if isinstance(item, str) else ": give a number"


def _example(spec: dict) -> str:
    """The default of an option as a TOML number (one of a pair or triple), for a message."""
    default = spec.get("default")
    if isinstance(default, (tuple, list)):
        default = default[0]
    return "1" if default is None else f"{default:g}"


def read_config(path) -> dict:
    """Options of a TOML case file, converted and checked like the command line.

    Returns:
        ``{option: value}`` under the options' names (``n_span``), with
        ``wing`` the ``[[rib]]`` tables (`read_ribs`) and ``tolerances`` the
        ``[tolerances]`` table (`read_tolerances`) when the file has them.

    Raises:
        InputError: for an unreadable file, invalid TOML, an unknown key or a
            bad value (the message names the file and the key).
    """
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover - exercised on Python 3.10 only
        import tomli as tomllib
    try:
        text = Path(path).read_text(encoding="utf-8-sig")  # (a byte-order mark, as some editors write, is no key)
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise InputError(f"cannot read the case file {path}: {reason}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path} is not valid TOML: {exc}") from None
    values = {}
    for key, value in data.items():
        dest = key.replace("-", "_")
        if key == "rib" and isinstance(value, list) and all(isinstance(v, dict) for v in value):
            values["wing"] = read_ribs(str(path), value)
            continue
        if key == "rib" and isinstance(value, dict):
            raise InputError(f"{path}: [rib] is one table; list each rib as a [[rib]] table (two brackets), root "
                             "to tip, at least two")
        if key == "tolerances" and isinstance(value, dict):
            values["tolerances"] = read_tolerances(str(path), value)
            continue
        if key == "fabric" and isinstance(value, dict):
            for dest, item in read_fabric(str(path), value).items():
                if dest in values:
                    raise InputError(f"{path}: {dest.replace('_', '-')} is given twice (at the top and in [fabric])")
                values[dest] = item
            continue
        if dest in values:
            raise InputError(f"{path}: {key!r} is given twice (with - and _, or at the top and in [fabric])")
        values[dest] = _toml_value(str(path), key, value)
        if dest == "fabric_test":
            values[dest] = _beside(path, values[dest])
        if dest == "tolerance" and isinstance(values[dest], str):
            raise InputError(f"{path}: tolerance is the optimiser's convergence tolerance, a number; give "
                             "manufacturing tolerances in a [tolerances] table (pressure = \"2%\", ...)")
        if dest in ("target", "rib"):
            values[dest] = case_path(path, values[dest])
    return values


def read_fabric(path: str, table: dict) -> dict:
    """A case file's ``[fabric]`` table: ``test`` (the biaxial test file, relative to the case file's folder:
    ``--fabric-test``) and the fabric's other options under their long names without ``--``
    (`FABRIC_KEYS`), converted and checked as the command line's.

    Raises:
        InputError: for an unknown key or a bad value, naming the file and the key.
    """
    values = {}
    for key, value in table.items():
        name = key.replace("_", "-")
        if name not in FABRIC_KEYS:
            raise InputError(f"{path}: [fabric] has no key {key!r}; its keys are {', '.join(FABRIC_KEYS)}")
        option = "fabric-test" if name == "test" else name
        dest = option.replace("-", "_")
        if dest in values:
            raise InputError(f"{path}: [fabric] {key!r} is given twice (with - and _)")
        values[dest] = _toml_value(path, option, value)
    if "fabric_test" in values:
        values["fabric_test"] = _beside(path, values["fabric_test"])
    return values


def _beside(case_file, spec: str) -> str:
    """A file named in a case file: a relative path is relative to the case file's folder."""
    path = Path(spec)
    return spec if path.is_absolute() else str(Path(case_file).parent / path)


def read_tolerances(path: str, table: dict) -> list[str]:
    """A case file's ``[tolerances]`` table as ``NAME=VALUE`` items (``defaults = true``: every source at
    its default first); the names and values are checked with the command line's before any solve
    (`inverse_design.tolerance.parse_tolerances`).

    Raises:
        InputError: for a value that is neither a number nor a string.
    """
    items = []
    for name, value in table.items():
        if name == "defaults":
            if value is not True:
                raise InputError(f"{path}: [tolerances] defaults must be true (every source at its default), "
                                 f"got {value!r}")
            items.insert(0, "defaults")
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float, str)):
            raise InputError(f"{path}: [tolerances] {name} must be a number (the standard deviation) or a string "
                             f"such as \"2%\" or \"uniform:0.5\", got {value!r}")
        items.append(f"{name}={value}")
    return items


def case_path(case_file, spec: str) -> str:
    """A section of a case file (a NACA code or a .dat path) with a relative path made relative to the
    case file's folder (not the current one); NACA codes and absolute paths are returned as they are.

    A spec is a path when it ends in ``.dat`` or names a file in the case file's folder.
    """
    path = Path(spec)
    if path.is_absolute():
        return spec
    beside = Path(case_file).parent / path
    if path.suffix.lower() == ".dat" or beside.exists():
        return str(beside)
    return spec


def read_ribs(path: str, tables) -> list[dict]:
    """Check the ``[[rib]]`` tables of a case file; return them as ``[{section, chord, station, target}]``.

    The sections (and targets) are the tables' specs, a relative ``.dat`` path
    made relative to the case file (`case_path`); `case.Case.from_arguments`
    loads each once.

    Raises:
        InputError: one line naming the file, the rib (0 is the root) and what to change.
    """
    required, optional = RIB_KEYS
    if not isinstance(tables, list) or len(tables) < 2:
        n = len(tables) if isinstance(tables, list) else 0
        raise InputError(f"{path}: a wing needs at least two [[rib]] tables (root and tip), got {n}; add ribs")
    ribs = []
    for k, table in enumerate(tables):
        where = f"{path}: rib {k}"
        unknown = sorted(set(table) - set(required) - set(optional))
        if unknown:
            raise InputError(f"{where}: unknown key(s) {unknown}; a [[rib]] table has {', '.join(required)} "
                             f"and optionally {', '.join(optional)}")
        missing = [key for key in required if key not in table]
        if missing:
            raise InputError(f"{where}: missing {', '.join(missing)}; every [[rib]] needs section (a NACA code "
                             "or a .dat file), chord (m) and station (m, span position)")
        rib = {}
        for key in ("chord", "station"):
            value = table[key]
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise InputError(f"{where}: {key} must be a finite number in m, got {_toml_text(value)}"
                                 f"{_number_hint(value) if isinstance(value, (str, bool)) else ''}")
            rib[key] = float(value)
        if not rib["chord"] > 0:
            raise InputError(f"{where}: chord must be a positive length in m, got {rib['chord']!r}")
        if k and not rib["station"] > ribs[-1]["station"]:
            raise InputError(f"{where}: station {rib['station']:g} m does not lie beyond rib {k - 1}'s "
                             f"({ribs[-1]['station']:g} m); list the ribs root to tip with increasing stations")
        for key in ("section", "target"):
            if key not in table:
                continue
            if not isinstance(table[key], str):
                raise InputError(f"{where}: {key} must be a NACA code such as \"naca2412\" or a .dat path, "
                                 f"got {table[key]!r}")
            rib[key] = case_path(path, table[key])  # a relative .dat path: beside the case file
        ribs.append(rib)
    return ribs
