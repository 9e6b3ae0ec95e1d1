"""Design variables: names, starting `Parameters`, bounds and the scaling the optimisers see.

The optimisers work on scaled variables ``u = value / scale`` so that a unit
step means the same to every variable (pressure in units of its starting
value, prestrain in percent, rib scales as they are). `DesignVariables`
maps ``u`` to a `forward_solver.Parameters` and back; ``u`` may be a JAX
value, so derivatives flow from the parameters' to the scaled variables.

One set of variables serves a wing of N >= 1 bays: the pressure, prestrains
and rib scales are shared by every bay. ``rib_shape`` is a vector variable
(2 K Bernstein coefficients, `forward_solver.model.rib_shape`, each with the same
bounds; K = `DEFAULT_RIB_SHAPE_TERMS` from a zero offset when the start has
none), laid out one of two ways (`RIB_SHAPE_LAYOUTS`): ``"shared"``, one
shape for every rib (2 K places in ``u``; a single bay's default), or
``"per_rib"``, one shape per rib (``n_ribs`` x 2 K places, root to tip; bay
``k`` lies between rib ``k``'s shape and rib ``k + 1``'s).

``cut_pattern`` is the cut as a field (`forward_solver.model.cut_field`): 2 K
B-spline coefficients added to the (fixed) uniform prestrains, K for the
span fibres then K for the contour fibres (K = `DEFAULT_CUT_PATTERN_TERMS`
from a zero field when the start has none), laid out one of two ways
(`CUT_PATTERN_LAYOUTS`): ``"shared"``, one field for every bay (2 K places),
or ``"per_bay"``, one field per bay (``n_bays`` x 2 K places, root to tip:
each cell's panel is cut on its own). Its bounds
are those of the local prestrain: the basis is a non-negative partition of
unity, so the field lies within its coefficients' range and bounding each
``uniform prestrain + coefficient`` in ``(lower, upper)`` bounds the local
prestrain everywhere, exactly. The uniform prestrains are its constant
part, so a design optimises either them or ``cut_pattern``, not both.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from functools import partial
from typing import Mapping

import jax
import numpy as np

from forward_solver import Parameters
from forward_solver.model.parameters import bay_parameters

from . import defaults

__all__ = ["VARIABLES", "VECTOR_VARIABLES", "RIB_SHAPE_LAYOUTS", "CUT_PATTERN_LAYOUTS", "DEFAULT_START",
           "DEFAULT_BOUNDS", "DEFAULT_RIB_SHAPE_TERMS", "DEFAULT_CUT_PATTERN_TERMS", "SCALES", "DesignVariables",
           "check_field_terms", "concrete_rows", "key_of"]

#: Names an engineer may optimise (fields of `Parameters`; the fabric's
#: stiffnesses are material data, not manufacturing choices).
VARIABLES = defaults.VARIABLES

#: Variables with several components (`Parameters` array fields).
VECTOR_VARIABLES = ("rib_shape", "cut_pattern")

#: How the ``rib_shape`` variable is laid out over the ribs (module docstring).
RIB_SHAPE_LAYOUTS = ("shared", "per_rib")

#: How the ``cut_pattern`` variable is laid out over the bays (module docstring).
CUT_PATTERN_LAYOUTS = ("shared", "per_bay")

#: Bernstein terms per surface of a rib shape started from no offset (8 coefficients in all).
DEFAULT_RIB_SHAPE_TERMS = 4

#: B-spline terms per fibre direction of a cut pattern started from a zero field (12 coefficients in all).
DEFAULT_CUT_PATTERN_TERMS = 6

#: Start of every parameter that is neither optimised nor given in ``initial`` (stiffnesses unset: the
#: scene's fabric): 1e4 Pa and 2% prestrain both ways, the ``optimise-pressure`` command's defaults.
DEFAULT_START = Parameters(pressure=defaults.PRESSURE, prestrain_span=defaults.PRESTRAIN_SPAN,
                           prestrain_chord=defaults.PRESTRAIN_CHORD)

#: Bounds used when the caller gives none: pressure in Pa; prestrain from a
#: fabric cut to its mounted size (0) to 5% short; rib scales within +-50%;
#: rib-shape coefficients within +-0.05 (offsets up to about 1% of chord);
#: the cut pattern's local prestrain from 2% long to 5% short.
DEFAULT_BOUNDS = {
    "pressure": (1e2, 1e6),
    "prestrain_span": (0.0, 0.05),
    "prestrain_chord": (0.0, 0.05),
    "rib_thickness_scale": (0.5, 1.5),
    "rib_chord_scale": (0.5, 1.5),
    "rib_shape": (-0.05, 0.05),
    "cut_pattern": (-0.02, 0.05),
}

#: Unit of each scaled variable but the pressure (whose unit is its start).
SCALES = {"prestrain_span": 0.01, "prestrain_chord": 0.01, "rib_thickness_scale": 1.0,
          "rib_chord_scale": 1.0, "rib_shape": 0.01, "cut_pattern": 0.01}


@partial(jax.jit, static_argnames=("layout",))
def _scaled_pieces(u, scales, layout):
    """``u[a:b] * scale`` (``vector``) or ``u[a] * scale`` for each ``(a, b, vector)`` of ``layout``:
    one program under a transformation, for what were three eager operations per variable."""
    return [(u[a:b] if vector else u[a]) * s for (a, b, vector), s in zip(layout, scales)]


@dataclass(frozen=True)
class DesignVariables:
    """The optimised parameters and everything held fixed.

    Attributes:
        names: optimised parameter names, in the order of the vector.
        start: the starting shared `Parameters` (the non-optimised ones stay
            there); with a shared rib shape its ``rib_shape``.
        bounds: ``(lower, upper)`` of each optimised name (of every component
            of a vector variable).
        sizes: components of each name in the vector (1; 2 K for a shared
            ``rib_shape``, ``n_ribs`` x 2 K for one per rib).
        rib_shapes: ``(n_ribs, 2 K)`` starting shapes of a ``"per_rib"``
            ``rib_shape`` variable, else None.
        cut_patterns: ``(n_bays, 2 K)`` starting fields of a ``"per_bay"``
            ``cut_pattern`` variable, else None.
    """

    names: tuple
    start: Parameters
    bounds: dict
    sizes: dict = None
    rib_shapes: np.ndarray | None = None
    cut_patterns: np.ndarray | None = None

    @classmethod
    def build(cls, variables, initial: Parameters | Mapping | None, bounds: Mapping | None, *,
              n_ribs: int = 2, rib_shape: str = "shared", cut_pattern: str = "shared") -> "DesignVariables":
        """Validate the caller's choices.

        Args:
            variables: names from `VARIABLES` (or one name).
            initial: a `Parameters`, or ``{name: value}`` over
                `DEFAULT_START`, or None. A ``"per_rib"`` rib-shape start is one
                ``(2 K,)`` row for every rib or an ``(n_ribs, 2 K)`` array; a
                ``"per_bay"`` cut-pattern start one row for every bay or an
                ``(n_ribs - 1, 2 K)`` array.
            bounds: ``{name: (lower, upper)}`` for optimised names; others
                take `DEFAULT_BOUNDS`.
            n_ribs: ribs of the wing (2 for one bay).
            rib_shape: the layout of an optimised ``rib_shape``, one of
                `RIB_SHAPE_LAYOUTS`.
            cut_pattern: the layout of an optimised ``cut_pattern``, one of
                `CUT_PATTERN_LAYOUTS`.

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
        both = [n for n in ("prestrain_span", "prestrain_chord") if n in names]
        if "cut_pattern" in names and both:
            raise ValueError(f"cut_pattern already holds the uniform prestrain (its constant part): optimise "
                             f"cut_pattern or {' and '.join(both)}, not both")
        if rib_shape not in RIB_SHAPE_LAYOUTS:
            raise ValueError(f"rib_shape must be one of {RIB_SHAPE_LAYOUTS}, got {rib_shape!r}")
        if cut_pattern not in CUT_PATTERN_LAYOUTS:
            raise ValueError(f"cut_pattern must be one of {CUT_PATTERN_LAYOUTS}, got {cut_pattern!r}")
        if cut_pattern == "per_bay" and "cut_pattern" in names and n_ribs == 2:
            warnings.warn("a cut field per bay on a case of one bay is the shared field: the design "
                          "optimises one field (cut_pattern layout 'shared')", stacklevel=2)
            cut_pattern = "shared"
            if not isinstance(initial, Parameters) and initial is not None and "cut_pattern" in initial:
                rows = np.asarray(initial["cut_pattern"], np.float64)
                initial = {**initial, "cut_pattern": rows.reshape(-1) if rows.ndim == 2 and len(rows) == 1 else rows}
        per_rib = "rib_shape" in names and rib_shape == "per_rib"
        per_bay = "cut_pattern" in names and cut_pattern == "per_bay"
        shape_start = field_start = None
        if isinstance(initial, Parameters):
            start = initial
            if per_rib:
                shape_start, start = start.rib_shape, start.replace(rib_shape=None, rib_shape_tip=None)
            if per_bay:
                field_start, start = start.cut_pattern, start.replace(cut_pattern=None)
        else:
            initial = dict(initial or {})
            for name in initial:
                if name not in VARIABLES:
                    raise ValueError(f"unknown parameter {name!r} in initial; choose from {VARIABLES}")
            if per_rib:
                shape_start = initial.pop("rib_shape", None)
            if per_bay:
                field_start = initial.pop("cut_pattern", None)
            start = DEFAULT_START.replace(**{k: (np.asarray(v, np.float64) if k in VECTOR_VARIABLES
                                                 else float(v)) for k, v in initial.items()})
        if "rib_shape" in names and not per_rib and start.rib_shape is None:
            start = start.replace(rib_shape=np.zeros(2 * DEFAULT_RIB_SHAPE_TERMS))
        if "cut_pattern" in names and not per_bay and start.cut_pattern is None:
            start = start.replace(cut_pattern=np.zeros(2 * DEFAULT_CUT_PATTERN_TERMS))
        start = start.as_floats().check()
        shapes = _rows("rib_shape", shape_start, DEFAULT_RIB_SHAPE_TERMS, n_ribs, "rib") if per_rib else None
        fields = _rows("cut_pattern", field_start, DEFAULT_CUT_PATTERN_TERMS, n_ribs - 1, "bay") if per_bay else None
        bounds = dict(bounds or {})
        for name in bounds:
            if name not in VARIABLES:
                raise ValueError(f"unknown parameter {name!r} in bounds; choose from {VARIABLES}")
            if name not in names:
                raise ValueError(f"bounds given for {name!r}, which is not among the variables {names}")
        values = start.as_dict()
        if per_rib:
            values["rib_shape"] = shapes
        if per_bay:
            values["cut_pattern"] = fields
        chosen = {}
        for name in names:
            lo, hi = (float(b) for b in bounds.get(name, DEFAULT_BOUNDS[name]))
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ValueError(f"bounds of {name} must be a finite (lower, upper) pair with lower < upper, "
                                 f"got {(lo, hi)}")
            if name == "pressure" and lo <= 0:
                raise ValueError(f"the lower pressure bound must be positive (Pa), got {lo}")
            if (name.startswith("prestrain") or name == "cut_pattern") and not (-0.5 < lo and hi < 1.0):
                raise ValueError(f"bounds of {name} must lie in (-0.5, 1.0), got {(lo, hi)}")
            if name in ("rib_thickness_scale", "rib_chord_scale") and lo <= 0:
                raise ValueError(f"the lower bound of {name} must be positive, got {lo}")
            if name in VECTOR_VARIABLES and not per_rib and start.rib_shape_tip is not None:
                raise ValueError("a shared rib_shape design gives every rib one shape; the start "
                                 "must not set rib_shape_tip")
            value = np.asarray(values[name], np.float64)
            if name == "cut_pattern":
                local = value + _uniform(start, value.shape[-1])
                if not np.all(np.isfinite(local) & (lo <= local) & (local <= hi)):
                    raise ValueError(f"the starting cut pattern's local prestrain reaches {local.min():.6g}.."
                                     f"{local.max():.6g} (uniform prestrain plus each coefficient), outside its "
                                     f"bounds {(lo, hi)}: change the bounds or the starting prestrains")
                chosen[name] = (lo, hi)
                continue
            if not np.all(np.isfinite(value) & (lo <= value) & (value <= hi)):
                shown = value.tolist() if name in VECTOR_VARIABLES else repr(values[name])
                hint = ("; a rib shape starts from the unchanged rib (every coefficient 0) unless given, "
                        "so its bounds must include 0" if name in VECTOR_VARIABLES else "")
                raise ValueError(f"the start of {name}, {shown}, lies outside its bounds {(lo, hi)}{hint}")
            chosen[name] = (lo, hi)
        sizes = {n: int(np.size(values[n])) for n in names}
        return cls(names, start, chosen, sizes, shapes, fields)

    def scale(self, name: str) -> float:
        """Unit of the scaled variable."""
        if name == "pressure":
            return abs(self.start.pressure)
        return SCALES[name]

    def slices(self) -> dict:
        """``{name: slice}`` of each name's components in the scaled vector."""
        sizes = self.sizes or {n: 1 for n in self.names}
        ends = np.cumsum([sizes[n] for n in self.names])
        return {n: slice(int(e - sizes[n]), int(e)) for n, e in zip(self.names, ends)}

    @property
    def size(self) -> int:
        """Length of the scaled vector."""
        return sum((self.sizes or {n: 1 for n in self.names}).values())

    def to_vector(self, parameters: Parameters, rib_shapes=None, cut_patterns=None) -> np.ndarray:
        """Scaled vector of the optimised names (``rib_shapes``, ``cut_patterns``: the per-rib shapes and
        per-bay fields, default the start's)."""
        def value(n):
            if n == "rib_shape" and self.rib_shapes is not None:
                return self.rib_shapes if rib_shapes is None else rib_shapes
            if n == "cut_pattern" and self.cut_patterns is not None:
                return self.cut_patterns if cut_patterns is None else cut_patterns
            return getattr(parameters, n)

        return np.concatenate([np.reshape(np.asarray(value(n), np.float64), -1) / self.scale(n)
                               for n in self.names])

    def start_vector(self) -> np.ndarray:
        """The scaled vector of the start."""
        return self.to_vector(self.start)

    def parameters(self, u) -> Parameters:
        """The shared `Parameters` of the scaled vector ``u`` (a JAX value keeps them traced)."""
        names, layout = [], []
        for n, part in self.slices().items():
            if (n == "rib_shape" and self.rib_shapes is not None) or (n == "cut_pattern"
                                                                      and self.cut_patterns is not None):
                continue  # per rib or bay: `rib_shapes_at`, `cut_patterns_at`
            names.append(n)
            layout.append((part.start, part.stop, n in VECTOR_VARIABLES))
        scales = [self.scale(n) for n in names]
        if isinstance(u, jax.core.Tracer):
            values = _scaled_pieces(u, scales, tuple(layout))
        else:
            values = [(u[a:b] if vector else u[a]) * s for (a, b, vector), s in zip(layout, scales)]
        return self.start.replace(**dict(zip(names, values)))

    def rib_shapes_at(self, u):
        """``(n_ribs, 2 K)`` per-rib shapes at ``u`` (JAX values stay traced), or None (not per rib)."""
        if self.rib_shapes is None:
            return None
        return u[self.slices()["rib_shape"]].reshape(self.rib_shapes.shape) * self.scale("rib_shape")

    def cut_patterns_at(self, u):
        """``(n_bays, 2 K)`` per-bay cut fields at ``u`` (JAX values stay traced), or None (not per bay)."""
        if self.cut_patterns is None:
            return None
        return u[self.slices()["cut_pattern"]].reshape(self.cut_patterns.shape) * self.scale("cut_pattern")

    def bay_parameters(self, u, bay: int) -> Parameters:
        """The `Parameters` of bay ``bay`` at ``u``: the shared ones, with its ribs' shapes when per rib
        and its cut field when per bay."""
        return bay_parameters(self.parameters(u), self.rib_shapes_at(u), bay, self.cut_patterns_at(u))

    def bays_parameters(self, u, n_bays: int) -> list:
        """`bay_parameters` of bays ``0 .. n_bays - 1`` at ``u``, the shared ones made once (under a
        transformation, each is a program of its own)."""
        shared, shapes, fields = self.parameters(u), self.rib_shapes_at(u), self.cut_patterns_at(u)
        return [bay_parameters(shared, shapes, k, fields) for k in range(n_bays)]

    def values(self, u) -> dict:
        """``{name: value}`` of the optimised names at ``u`` (a list for a vector; per rib, a list per rib)."""
        u = np.asarray(u, np.float64)
        out = {}
        for n, part in self.slices().items():
            if n in VECTOR_VARIABLES:
                values = u[part] * self.scale(n)
                rows = self.rows(n)
                out[n] = values.reshape(rows.shape).tolist() if rows is not None else [float(v) for v in values]
            else:
                out[n] = float(u[part.start]) * self.scale(n)
        return out

    def from_values(self, values: dict) -> np.ndarray:
        """The scaled vector of ``{name: value}`` (as `values` returns it)."""
        return np.concatenate([np.reshape(np.asarray(values[n], np.float64), -1) / self.scale(n)
                               for n in self.names])

    def rows(self, name: str):
        """The starting ``(n_ribs, 2 K)`` shapes or ``(n_bays, 2 K)`` fields of a per-rib or per-bay
        vector variable ``name``, else None."""
        return {"rib_shape": self.rib_shapes, "cut_pattern": self.cut_patterns}.get(name)

    def components(self, parameters: Parameters, rib_shapes=None, cut_patterns=None):
        """``(label, value, lower, upper)`` of every scalar component (``rib_shape[3]`` for a shared
        vector, ``rib_shape[k][3]`` for rib ``k``'s of ``rib_shapes``, the per-rib shapes;
        ``cut_pattern[3]`` with its local prestrain, the uniform prestrain plus the coefficient, and
        ``cut_pattern[k][3]`` for bay ``k``'s of ``cut_patterns``, the per-bay fields)."""
        for n in self.names:
            lo, hi = self.bounds[n]
            given = {"rib_shape": rib_shapes, "cut_pattern": cut_patterns}.get(n)
            if self.rows(n) is not None:
                for k, row in enumerate(np.asarray(given, np.float64)):
                    if n == "cut_pattern":
                        row = row + _uniform(parameters, row.size)
                    yield from ((f"{n}[{k}][{j}]", float(v), lo, hi) for j, v in enumerate(row))
                continue
            value = np.reshape(np.asarray(getattr(parameters, n), np.float64), -1)
            if n == "cut_pattern":
                value = value + _uniform(parameters, value.size)
            if n in VECTOR_VARIABLES:
                yield from ((f"{n}[{k}]", float(v), lo, hi) for k, v in enumerate(value))
            else:
                yield n, float(value[0]), lo, hi

    def bound(self, side: int) -> np.ndarray:
        """Scaled lower (``side`` 0) or upper (1) bound of every component (a cut pattern's
        coefficients: the local prestrain's bound less the uniform prestrain)."""
        def one(n, part):
            size = part.stop - part.start
            shift = 0.0
            if n == "cut_pattern":  # per coefficient of each field (one, or one per bay)
                rows = self.rows(n)
                width = size if rows is None else rows.shape[1]
                shift = np.tile(_uniform(self.start, width), size // width)
            return (np.full(size, self.bounds[n][side]) - shift) / self.scale(n)

        return np.concatenate([one(n, part) for n, part in self.slices().items()])

    @property
    def lower(self) -> np.ndarray:
        return self.bound(0)

    @property
    def upper(self) -> np.ndarray:
        return self.bound(1)


def key_of(u) -> tuple:
    """A hashable key of a scaled vector (its float values): the design problem's caches and the robust
    terms' are keyed by it."""
    return tuple(float(x) for x in np.asarray(u, dtype=np.float64).reshape(-1))


def concrete_rows(rows) -> np.ndarray | None:
    """Per-rib shapes or per-bay fields (`DesignVariables.rib_shapes_at`, ``cut_patterns_at``) as a
    float64 numpy array; None stays None."""
    return None if rows is None else np.asarray(rows, np.float64)


def _rows(name: str, given, terms: int, count: int, what: str) -> np.ndarray:
    """The ``(count, 2 K)`` starting rows of a per-rib or per-bay vector variable: ``given`` as one row
    for all, or one row each; zeros of ``2 * terms`` when None."""
    rows = np.zeros(2 * terms) if given is None else np.asarray(given, np.float64)
    if rows.ndim == 1:
        rows = np.tile(rows, (count, 1))
    if rows.ndim != 2 or rows.shape[0] != count or rows.shape[1] < 2 or rows.shape[1] % 2:
        raise ValueError(f"the {name} start must be one row of 2K coefficients for every {what} or an "
                         f"({count}, 2K) array, got shape {np.shape(given)}")
    return rows


def _uniform(parameters: Parameters, size: int) -> np.ndarray:
    """The uniform prestrain under each of a cut pattern's ``size`` coefficients (span half, then chord)."""
    half = size // 2
    return np.concatenate([np.full(half, float(parameters.prestrain_span)),
                           np.full(size - half, float(parameters.prestrain_chord))])


def check_field_terms(variables: DesignVariables, n_contour: int) -> None:
    """Refuse a cut field with more terms per fibre direction than the bay's ``n_contour`` contour nodes:
    beyond one term per node a term's B-spline spans no node (`forward_solver.model.cut_field`), so it moves
    nothing and the design's Jacobian is singular in it.

    Raises:
        ValueError: naming the terms, the nodes and what to change.
    """
    if "cut_pattern" not in variables.names:
        return
    width = variables.sizes["cut_pattern"] if variables.cut_patterns is None else variables.cut_patterns.shape[1]
    terms = width // 2
    if terms > n_contour:
        raise ValueError(f"a cut pattern of {terms} terms per fibre direction on {n_contour} contour nodes: at "
                         f"most one term per contour node moves the skin; give a cut pattern of {n_contour} terms "
                         "or fewer per fibre direction, or more contour nodes (n_contour)")
