"""Design variables: names, starting `Parameters`, bounds and the scaling the optimisers see.

The optimisers work on scaled variables ``u = value / scale`` so that a unit
step means the same to every variable (pressure in units of its starting
value, prestrain in percent, rib scales as they are). `DesignVariables`
maps ``u`` to a `forward_solver.Parameters` and back; ``u`` may be a JAX
value, so derivatives flow from the parameters' to the scaled variables.

``rib_shape`` is a vector variable: its 2 K coefficients
(`forward_solver.rib_shape`) take 2 K places in ``u``, each with the same
bounds; its size comes from the starting `Parameters` (K =
`DEFAULT_RIB_SHAPE_TERMS` from a zero offset when the start has none).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from forward_solver import Parameters

__all__ = ["VARIABLES", "VECTOR_VARIABLES", "DEFAULT_START", "DEFAULT_BOUNDS", "DEFAULT_RIB_SHAPE_TERMS",
           "DesignVariables"]

#: Names an engineer may optimise (fields of `Parameters`; the fabric's
#: stiffnesses are material data, not manufacturing choices).
VARIABLES = ("pressure", "prestrain_span", "prestrain_chord", "rib_thickness_scale", "rib_chord_scale",
             "rib_shape")

#: Variables with several components (`Parameters` array fields).
VECTOR_VARIABLES = ("rib_shape",)

#: Bernstein terms per surface of a rib shape started from no offset (8 coefficients in all).
DEFAULT_RIB_SHAPE_TERMS = 4

#: Start of every parameter that is neither optimised nor given in ``initial``
#: (stiffnesses unset: the scene's fabric).
DEFAULT_START = Parameters(pressure=1e4, prestrain_span=0.005, prestrain_chord=0.005)

#: Bounds used when the caller gives none: pressure in Pa; prestrain from a
#: fabric cut to its mounted size (0) to 5% short; rib scales within +-50%;
#: rib-shape coefficients within +-0.05 (offsets up to about 1% of chord).
DEFAULT_BOUNDS = {
    "pressure": (1e2, 1e6),
    "prestrain_span": (0.0, 0.05),
    "prestrain_chord": (0.0, 0.05),
    "rib_thickness_scale": (0.5, 1.5),
    "rib_chord_scale": (0.5, 1.5),
    "rib_shape": (-0.05, 0.05),
}

_SCALES = {"prestrain_span": 0.01, "prestrain_chord": 0.01, "rib_thickness_scale": 1.0,
           "rib_chord_scale": 1.0, "rib_shape": 0.01}


@dataclass(frozen=True)
class DesignVariables:
    """The optimised parameters and everything held fixed.

    Attributes:
        names: optimised parameter names, in the order of the vector.
        start: the starting `Parameters` (the non-optimised ones stay there).
        bounds: ``(lower, upper)`` of each optimised name (of every component
            of a vector variable).
        sizes: components of each name (1, or 2 K for ``rib_shape``).
    """

    names: tuple
    start: Parameters
    bounds: dict
    sizes: dict = None

    @classmethod
    def build(cls, variables, initial: Parameters | Mapping | None,
              bounds: Mapping | None) -> "DesignVariables":
        """Validate the caller's choices.

        Args:
            variables: names from `VARIABLES` (or one name).
            initial: a `Parameters`, or ``{name: value}`` over
                `DEFAULT_START`, or None.
            bounds: ``{name: (lower, upper)}`` for optimised names; others
                take `DEFAULT_BOUNDS`.

        Raises:
            ValueError: for an unknown or repeated name, a bound that is not an
                increasing finite pair, or a start outside its bounds.
        """
        if isinstance(variables, str):
            variables = (variables,)
        names = tuple(variables)
        if not names:
            raise ValueError(f"variables must name at least one of {VARIABLES}")
        for name in names:
            if name not in VARIABLES:
                raise ValueError(f"unknown design variable {name!r}; choose from {VARIABLES}")
        if len(set(names)) != len(names):
            raise ValueError(f"variables must not repeat a name, got {names}")
        if isinstance(initial, Parameters):
            start = initial
        else:
            initial = dict(initial or {})
            for name in initial:
                if name not in VARIABLES:
                    raise ValueError(f"unknown parameter {name!r} in initial; choose from {VARIABLES}")
            start = DEFAULT_START.replace(**{k: (np.asarray(v, np.float64) if k in VECTOR_VARIABLES
                                                 else float(v)) for k, v in initial.items()})
        if "rib_shape" in names and start.rib_shape is None:
            start = start.replace(rib_shape=np.zeros(2 * DEFAULT_RIB_SHAPE_TERMS))
        start = start.as_floats().check()
        bounds = dict(bounds or {})
        for name in bounds:
            if name not in VARIABLES:
                raise ValueError(f"unknown parameter {name!r} in bounds; choose from {VARIABLES}")
            if name not in names:
                raise ValueError(f"bounds given for {name!r}, which is not among the variables {names}")
        values = start.as_dict()
        chosen = {}
        for name in names:
            lo, hi = (float(b) for b in bounds.get(name, DEFAULT_BOUNDS[name]))
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ValueError(f"bounds of {name} must be a finite (lower, upper) pair with lower < upper, "
                                 f"got {(lo, hi)}")
            if name == "pressure" and lo <= 0:
                raise ValueError(f"the lower pressure bound must be positive (Pa), got {lo}")
            if name.startswith("prestrain") and not (-0.5 < lo and hi < 1.0):
                raise ValueError(f"bounds of {name} must lie in (-0.5, 1.0), got {(lo, hi)}")
            if name in ("rib_thickness_scale", "rib_chord_scale") and lo <= 0:
                raise ValueError(f"the lower bound of {name} must be positive, got {lo}")
            if name in VECTOR_VARIABLES and start.rib_shape_tip is not None:
                raise ValueError("a single bay's rib_shape design gives both ribs one shape; the start "
                                 "must not set rib_shape_tip")
            if not np.all((lo <= np.asarray(values[name])) & (np.asarray(values[name]) <= hi)):
                shown = np.asarray(values[name]).tolist() if name in VECTOR_VARIABLES else repr(values[name])
                hint = ("; a rib shape starts from the unchanged rib (every coefficient 0) unless given, "
                        "so its bounds must include 0" if name in VECTOR_VARIABLES else "")
                raise ValueError(f"the start of {name}, {shown}, lies outside its bounds {(lo, hi)}{hint}")
            chosen[name] = (lo, hi)
        sizes = {n: int(np.size(values[n])) for n in names}
        return cls(names, start, chosen, sizes)

    def scale(self, name: str) -> float:
        """Unit of the scaled variable."""
        if name == "pressure":
            return abs(self.start.pressure)
        return _SCALES[name]

    def _slices(self) -> dict:
        sizes = self.sizes or {n: 1 for n in self.names}
        ends = np.cumsum([sizes[n] for n in self.names])
        return {n: slice(int(e - sizes[n]), int(e)) for n, e in zip(self.names, ends)}

    @property
    def size(self) -> int:
        """Length of the scaled vector."""
        return sum((self.sizes or {n: 1 for n in self.names}).values())

    def to_vector(self, parameters: Parameters) -> np.ndarray:
        """Scaled vector of the optimised names."""
        return np.concatenate([np.reshape(np.asarray(getattr(parameters, n), np.float64), -1) / self.scale(n)
                               for n in self.names])

    def parameters(self, u) -> Parameters:
        """The `Parameters` of the scaled vector ``u`` (a JAX value keeps them traced)."""
        changes = {}
        for n, part in self._slices().items():
            changes[n] = (u[part] if n in VECTOR_VARIABLES else u[part.start]) * self.scale(n)
        return self.start.replace(**changes)

    def values(self, u) -> dict:
        """``{name: value}`` of the optimised names at the scaled vector ``u`` (a list for a vector)."""
        u = np.asarray(u, np.float64)
        return {n: ([float(v) * self.scale(n) for v in u[part]] if n in VECTOR_VARIABLES
                    else float(u[part.start]) * self.scale(n))
                for n, part in self._slices().items()}

    def from_values(self, values: dict) -> np.ndarray:
        """The scaled vector of ``{name: value}`` (as `values` returns it)."""
        return np.concatenate([np.reshape(np.asarray(values[n], np.float64), -1) / self.scale(n)
                               for n in self.names])

    def components(self, parameters: Parameters):
        """``(label, value, lower, upper)`` of every scalar component (``rib_shape[3]`` for a vector)."""
        for n in self.names:
            value = np.reshape(np.asarray(getattr(parameters, n), np.float64), -1)
            lo, hi = self.bounds[n]
            if n in VECTOR_VARIABLES:
                yield from ((f"{n}[{k}]", float(v), lo, hi) for k, v in enumerate(value))
            else:
                yield n, float(value[0]), lo, hi

    def _bound(self, side: int) -> np.ndarray:
        """Scaled lower (``side`` 0) or upper (1) bound of every component."""
        return np.concatenate([np.full(part.stop - part.start, self.bounds[n][side] / self.scale(n))
                               for n, part in self._slices().items()])

    @property
    def lower(self) -> np.ndarray:
        return self._bound(0)

    @property
    def upper(self) -> np.ndarray:
        return self._bound(1)
