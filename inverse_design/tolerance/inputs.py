"""The inputs of a tolerance analysis: each source's scatter (`Tolerance`), parsed from what the command and
a case file say (`parse_tolerance`, `parse_tolerances`), and the defaults (docs/tolerances.md).

Production scatters the pressure (one value for the wing), the fabric's
stiffnesses (per lot; each bay's panels are their own lot), the cut lengths
(per bay and fibre direction), the rib stations and the rib outlines (per
rib): `SOURCES`, in `SOURCE_UNITS`, scattering over `SOURCE_SCOPE`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

__all__ = ["DEFAULT_TOLERANCES", "SOURCES", "SOURCE_SCOPE", "SOURCE_UNITS", "Tolerance", "as_tolerances",
           "parse_tolerance", "parse_tolerances"]

#: The tolerance sources, in the order of the parameter vector.
SOURCES = ("pressure", "stiffness_span", "stiffness_chord", "cut_span", "cut_chord", "rib_station", "rib_profile")
#: The unit of each source's value (a ``%`` value is relative to the nominal instead).
SOURCE_UNITS = {"pressure": "Pa", "stiffness_span": "N/m", "stiffness_chord": "N/m", "cut_span": "mm",
                "cut_chord": "mm", "rib_station": "mm", "rib_profile": "mm"}
#: Where each source scatters: one value for the wing, one per bay, one per rib.
SOURCE_SCOPE = {"pressure": "wing", "stiffness_span": "bay", "stiffness_chord": "bay", "cut_span": "bay",
                "cut_chord": "bay", "rib_station": "rib", "rib_profile": "rib"}
#: Default standard deviations (docs/tolerances.md: assumptions to replace with the shop's own figures).
DEFAULT_TOLERANCES = {"pressure": "2%", "stiffness_span": "10%", "stiffness_chord": "10%", "cut_span": "0.5",
                      "cut_chord": "0.5", "rib_station": "1", "rib_profile": "0.5"}


@dataclass(frozen=True)
class Tolerance:
    """One source's scatter.

    Attributes:
        name: one of `SOURCES`.
        value: the standard deviation of a normal distribution (``uniform``:
            the half-width), in `SOURCE_UNITS`, or in percent of the nominal
            (``relative``).
        relative: ``value`` is in percent of the nominal value.
        uniform: uniform on ``[-value, value]`` instead of normal.
    """

    name: str
    value: float
    relative: bool = False
    uniform: bool = False

    @property
    def text(self) -> str:
        """As written on the command line (``2%``, ``uniform:0.5``; 4 significant digits)."""
        return f"{'uniform:' if self.uniform else ''}{self.value:.4g}{'%' if self.relative else ''}"

    def spread(self, nominal: float = 1.0) -> float:
        """The standard deviation (normal) or half-width (uniform) in the source's unit."""
        return self.value * abs(nominal) / 100.0 if self.relative else self.value

    def std(self, nominal: float = 1.0) -> float:
        """The standard deviation in the source's unit."""
        return self.spread(nominal) / (math.sqrt(3.0) if self.uniform else 1.0)

    def scaled(self, factor: float) -> "Tolerance":
        return dataclasses.replace(self, value=self.value * factor)


def parse_tolerance(name: str, spec) -> Tolerance:
    """A `Tolerance` from ``NAME`` and its value: a number (the standard deviation in `SOURCE_UNITS`),
    ``"2%"`` (relative to the nominal), ``"uniform:0.5"`` (uniform on +-0.5), or ``"default"``.

    Raises:
        ValueError: one line naming the source and what to change.
    """
    if name not in SOURCES:
        raise ValueError(f"tolerance {name}: no such source; the tolerances are {', '.join(SOURCES)}")
    text = str(spec).strip() if not isinstance(spec, bool) else "?"
    if text == "default":
        text = DEFAULT_TOLERANCES[name]
    uniform = text.startswith("uniform:")
    body = text[len("uniform:"):].strip() if uniform else text
    relative = body.endswith("%")
    body = body[:-1].strip() if relative else body
    unit = SOURCE_UNITS[name]
    try:
        value = float(body)
    except ValueError:
        raise ValueError(f"tolerance {name}={spec}: expected a standard deviation in {unit} (e.g. "
                         f"{DEFAULT_TOLERANCES[name]}), a percentage of the nominal (2%), uniform:VALUE or "
                         "default") from None
    if not math.isfinite(value) or value < 0:
        raise ValueError(f"tolerance {name}={spec}: a tolerance is a spread, 0 or more ({unit}); give a "
                         "non-negative value")
    if relative and name.startswith("rib_"):
        raise ValueError(f"tolerance {name}={spec}: {name} is a length in mm (a rib has no nominal "
                         f"{name.split('_')[1]} to take a percentage of); give it in mm, e.g. "
                         f"{DEFAULT_TOLERANCES[name]}")
    if relative and name.startswith("stiffness") and value >= 100:  # (a standard deviation or a half-width)
        raise ValueError(f"tolerance {name}={spec}: a stiffness scatter of 100% or more gives fabric of "
                         "zero or negative stiffness; give less than 100%")
    return Tolerance(name, value, relative, uniform)


def parse_tolerances(values) -> dict:
    """``{name: Tolerance}`` from ``{name: spec}`` or ``["NAME=VALUE", ...]`` (later entries win);
    the entry ``defaults`` (``True`` in a mapping) sets every source at `DEFAULT_TOLERANCES` before
    the others, wherever it stands.

    Raises:
        ValueError: for an unknown name or a bad value (one line).
    """
    pairs = []
    items = values.items() if isinstance(values, dict) else values
    for item in items:
        if isinstance(item, str):
            if item.strip() == "defaults":
                pairs.append(("defaults", True))
                continue
            if "=" not in item:
                raise ValueError(f"tolerance {item!r}: give NAME=VALUE (e.g. pressure=2%) or defaults")
            name, _, value = item.partition("=")
            pairs.append((name.strip(), value.strip()))
        else:
            pairs.append(tuple(item))
    out = {}
    for name, value in pairs:  # the defaults first, wherever they are named
        if name == "defaults":
            if value is not True:
                raise ValueError(f"tolerance defaults must be true (every source at its default), got {value!r}")
            out.update({n: parse_tolerance(n, DEFAULT_TOLERANCES[n]) for n in SOURCES})
    for name, value in pairs:
        if name != "defaults":
            out[name] = parse_tolerance(name, value)
    return out


def as_tolerances(tolerances) -> dict:
    """``{name: Tolerance}`` as given, or parsed (`parse_tolerances`)."""
    if isinstance(tolerances, dict) and all(isinstance(t, Tolerance) for t in tolerances.values()):
        return dict(tolerances)
    return parse_tolerances(tolerances)
