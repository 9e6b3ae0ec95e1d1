"""Design variables: names, starting `Parameters`, bounds and the scaling the optimisers see.

The optimisers work on scaled variables ``u = value / scale`` so that a unit
step means the same to every variable (pressure in units of its starting
value, prestrain in percent, rib scales as they are). `DesignVariables`
maps ``u`` to a `forward_solver.Parameters` and back; ``u`` may be a JAX
value, so derivatives flow from the parameters' to the scaled variables.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from forward_solver import Parameters

__all__ = ["VARIABLES", "DEFAULT_START", "DEFAULT_BOUNDS", "DesignVariables"]

#: Names an engineer may optimise (fields of `Parameters`; the fabric's
#: stiffnesses are material data, not manufacturing choices).
VARIABLES = ("pressure", "prestrain_span", "prestrain_chord", "rib_thickness_scale", "rib_chord_scale")

#: Start of every parameter that is neither optimised nor given in ``initial``
#: (stiffnesses unset: the scene's fabric).
DEFAULT_START = Parameters(pressure=1e4, prestrain_span=0.005, prestrain_chord=0.005)

#: Bounds used when the caller gives none: pressure in Pa; prestrain from a
#: fabric cut to its mounted size (0) to 5% short; rib scales within +-50%.
DEFAULT_BOUNDS = {
    "pressure": (1e2, 1e6),
    "prestrain_span": (0.0, 0.05),
    "prestrain_chord": (0.0, 0.05),
    "rib_thickness_scale": (0.5, 1.5),
    "rib_chord_scale": (0.5, 1.5),
}

_SCALES = {"prestrain_span": 0.01, "prestrain_chord": 0.01, "rib_thickness_scale": 1.0,
           "rib_chord_scale": 1.0}


@dataclass(frozen=True)
class DesignVariables:
    """The optimised parameters and everything held fixed.

    Attributes:
        names: optimised parameter names, in the order of the vector.
        start: the starting `Parameters` (the non-optimised ones stay there).
        bounds: ``(lower, upper)`` of each optimised name.
    """

    names: tuple
    start: Parameters
    bounds: dict

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
            start = DEFAULT_START.replace(**{k: float(v) for k, v in initial.items()})
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
            if name.startswith("rib") and lo <= 0:
                raise ValueError(f"the lower bound of {name} must be positive, got {lo}")
            if not lo <= values[name] <= hi:
                raise ValueError(f"the start of {name}, {values[name]!r}, lies outside its bounds {(lo, hi)}")
            chosen[name] = (lo, hi)
        return cls(names, start, chosen)

    def scale(self, name: str) -> float:
        """Unit of the scaled variable."""
        if name == "pressure":
            return abs(self.start.pressure)
        return _SCALES[name]

    def to_vector(self, parameters: Parameters) -> np.ndarray:
        """Scaled vector of the optimised names."""
        return np.array([float(getattr(parameters, n)) / self.scale(n) for n in self.names])

    def parameters(self, u) -> Parameters:
        """The `Parameters` of the scaled vector ``u`` (a JAX value keeps them traced)."""
        return self.start.replace(**{n: u[k] * self.scale(n) for k, n in enumerate(self.names)})

    def values(self, u) -> dict:
        """``{name: float}`` of the optimised names at the scaled vector ``u``."""
        return {n: float(u[k]) * self.scale(n) for k, n in enumerate(self.names)}

    @property
    def lower(self) -> np.ndarray:
        return np.array([self.bounds[n][0] / self.scale(n) for n in self.names])

    @property
    def upper(self) -> np.ndarray:
        return np.array([self.bounds[n][1] / self.scale(n) for n in self.names])
