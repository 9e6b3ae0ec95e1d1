"""`Parameters`: the traced, differentiable inputs of one solve, as one typed pytree.

Everything an engineer designs or sweeps (pressure, prestrains, stiffnesses,
rib scales and shapes, the cut pattern) travels to the force kernel as one
`Parameters` value, a JAX pytree: ``jax.grad`` of a function of
`solve_equilibrium`'s result with respect to it returns a `Parameters` of
derivatives, and new values never recompile. What is not a design parameter
(Poisson's ratio, areal density, viscosity, damping, gravity) belongs to the
`Fabric` and the `Scene`; `Scene.params` merges both into the kernel's
`forces.KernelInputs` at the last step.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np

__all__ = ["Parameters", "PARAMETER_NAMES", "SHAPE_NAMES", "FIELD_NAMES",
           "as_parameters", "bay_parameters", "ParameterViews"]

Scalar = Any  # a Python float, a numpy or JAX scalar, or a JAX tracer

#: Field names of `Parameters`, in order (the names a design may vary).
PARAMETER_NAMES = (
    "pressure",
    "prestrain_span",
    "prestrain_chord",
    "stiffness_span",
    "stiffness_chord",
    "rib_thickness_scale",
    "rib_chord_scale",
)

#: Array-valued fields of `Parameters`: the rib-shape coefficients
#: (`forward_solver.model.rib_shape`), None when the ribs keep their sections.
SHAPE_NAMES = ("rib_shape", "rib_shape_tip")

#: Array-valued fields of `Parameters` that are not rib shapes: the cut
#: pattern's coefficients (`forward_solver.model.cut_field`), None for a uniform cut.
FIELD_NAMES = ("cut_pattern",)

_ARRAY_NAMES = SHAPE_NAMES + FIELD_NAMES

@dataclass(frozen=True, eq=False)
class Parameters:
    """Design parameters of one solve (a JAX pytree of scalars).

    Args:
        pressure: internal overpressure, Pa (> 0).
        prestrain_span: span-fibre prestrain (0.005 is 0.5%: the fabric is
            cut 0.5% shorter than the mounted geometry), in (-0.5, 1).
        prestrain_chord: chord-fibre prestrain, likewise.
        stiffness_span: tensile stiffness E11 of eq. (10), N/m; None takes the
            scene's fabric value when the solve resolves it.
        stiffness_chord: E22, N/m; None likewise.
        rib_thickness_scale: multiplies the rib thickness about its camber
            line (> 0).
        rib_chord_scale: multiplies the rib chord (> 0).
        rib_shape: None, or ``(2 K,)`` Bernstein coefficients of the rib
            contour's outward offset (K for the upper surface, then K for the
            lower; chord-normalised; `forward_solver.model.rib_shape`), applied to
            both ribs of the bay unless ``rib_shape_tip`` is given.
        rib_shape_tip: None (the tip rib takes ``rib_shape``), or the tip
            rib's own ``(2 K,)`` coefficients (a wing's bays, per-rib shapes).
        cut_pattern: None (a uniform cut), or ``(2 K,)`` B-spline
            coefficients of the prestrain added along the contour (K for the
            span fibres, then K for the contour fibres;
            `forward_solver.model.cut_field`): the local prestrain is
            ``prestrain_span + sum_k a_k N_k(s)`` (likewise chord), so zero
            coefficients are the uniform cut and a constant ``a`` the uniform
            prestrain ``prestrain_span + a``.

    Construction does not validate, because JAX rebuilds pytrees with
    placeholder leaves; `check` does, and every solver calls it.
    """

    pressure: Scalar
    prestrain_span: Scalar = 0.0
    prestrain_chord: Scalar = 0.0
    stiffness_span: Scalar = None
    stiffness_chord: Scalar = None
    rib_thickness_scale: Scalar = 1.0
    rib_chord_scale: Scalar = 1.0
    rib_shape: Any = None
    rib_shape_tip: Any = None
    cut_pattern: Any = None

    def __eq__(self, other) -> bool:
        if not isinstance(other, Parameters):
            return NotImplemented
        return all(_same(getattr(self, n), getattr(other, n)) for n in PARAMETER_NAMES + _ARRAY_NAMES)

    __hash__ = None  # mutable-valued (arrays): not hashable

    @property
    def prestrain(self) -> tuple:
        """``(span, chord)`` prestrain."""
        return (self.prestrain_span, self.prestrain_chord)

    @property
    def stiffness(self) -> tuple:
        """``(span, chord)`` tensile stiffness, N/m."""
        return (self.stiffness_span, self.stiffness_chord)

    def replace(self, **changes) -> "Parameters":
        """A copy with some fields changed (unknown names raise TypeError)."""
        return dataclasses.replace(self, **changes)

    def resolved(self, fabric) -> "Parameters":
        """A copy with unset stiffnesses taken from ``fabric`` (a `Fabric`)."""
        return self.replace(
            stiffness_span=fabric.stiffness_span if self.stiffness_span is None else self.stiffness_span,
            stiffness_chord=fabric.stiffness_chord if self.stiffness_chord is None else self.stiffness_chord,
        )

    def as_dict(self) -> dict:
        """``{name: value}`` for every field (the rib shapes and cut pattern as they are: None or arrays)."""
        return {name: getattr(self, name) for name in PARAMETER_NAMES + _ARRAY_NAMES}

    def as_floats(self) -> "Parameters":
        """A copy with every set scalar a Python float and every array field a float64 numpy array."""
        values = {k: (None if v is None else float(np.asarray(v)))
                  for k, v in self.as_dict().items() if k in PARAMETER_NAMES}
        shapes = {k: (None if getattr(self, k) is None else np.asarray(getattr(self, k), np.float64))
                  for k in _ARRAY_NAMES}
        return Parameters(**values, **shapes)

    @property
    def rib_shapes(self) -> tuple:
        """``(root, tip)`` rib-shape coefficients (the tip takes the root's unless set; None: unchanged)."""
        return (self.rib_shape, self.rib_shape if self.rib_shape_tip is None else self.rib_shape_tip)

    def is_traced(self) -> bool:
        """Whether any value is a JAX tracer (the solve is being transformed)."""
        return any(isinstance(v, jax.core.Tracer) for v in jax.tree_util.tree_leaves(self))

    def same_problem(self, other) -> bool:
        """Whether ``other`` (concrete `Parameters`) poses the same equilibrium: equal values, where an
        unset rib shape or cut pattern equals all-zero coefficients (the unshaped rib, the uniform cut)."""
        if not isinstance(other, Parameters):
            return False

        def value(v, like):
            return np.zeros(np.shape(like)) if v is None and like is not None else v

        return all(_same(value(a, b), value(b, a)) if n in _ARRAY_NAMES else _same(a, b)
                   for n in PARAMETER_NAMES + _ARRAY_NAMES
                   for a, b in [(getattr(self, n), getattr(other, n))])

    def check(self) -> "Parameters":
        """Raise a ValueError, saying what to change, for a non-physical concrete value.

        Tracers pass: their values are checked when the solve sees them concrete.
        """
        for name in PARAMETER_NAMES:
            value = _concrete(getattr(self, name))
            if value is None:
                continue
            if name == "pressure" and not (math.isfinite(value) and value > 0):
                raise ValueError(f"pressure must be a positive internal overpressure in Pa, got {value!r}")
            if name.startswith("prestrain") and not (math.isfinite(value) and -0.5 < value < 1.0):
                raise ValueError(
                    f"{name} must lie in (-0.5, 1.0) (a fraction, 0.005 is 0.5%), got {value!r}")
            if name.startswith("stiffness") and not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive tensile stiffness in N/m, got {value!r}")
            if name.startswith("rib") and not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive multiplier, got {value!r}")
        sizes = set()
        for name in SHAPE_NAMES:
            value = getattr(self, name)
            if value is None:
                continue
            sizes.add(_coefficient_count(name, value, "the upper surface", "the lower"))
            if not isinstance(value, jax.core.Tracer) and not np.all(np.isfinite(np.asarray(value))):
                raise ValueError(f"{name} must be finite, got {np.asarray(value)!r}")
        if self.rib_shape_tip is not None and self.rib_shape is None:
            raise ValueError("rib_shape_tip needs rib_shape (the root rib's coefficients) as well")
        if len(sizes) > 1:
            raise ValueError(f"rib_shape and rib_shape_tip must have the same number of coefficients, "
                             f"got {sorted(sizes)}")
        self._check_cut_pattern()
        return self

    def _check_cut_pattern(self) -> None:
        """The cut pattern's shape, and its local prestrain within (-0.5, 1) (convex hull of its coefficients)."""
        value = self.cut_pattern
        if value is None:
            return
        half = _coefficient_count("cut_pattern", value, "the span fibres", "the contour fibres") // 2
        if isinstance(value, jax.core.Tracer):
            return
        value = np.asarray(value, np.float64)
        if not np.all(np.isfinite(value)):
            raise ValueError(f"cut_pattern must be finite, got {value!r}")
        for name, part in (("prestrain_span", value[:half]), ("prestrain_chord", value[half:])):
            base = _concrete(getattr(self, name))
            if base is None:
                continue
            local = base + part
            if not np.all((-0.5 < local) & (local < 1.0)):
                raise ValueError(f"the cut pattern's local {name} (uniform {base:.6g} plus its coefficients) "
                                 f"reaches {float(local.min()):.6g}..{float(local.max()):.6g}; it must lie in "
                                 "(-0.5, 1.0)")


jax.tree_util.register_dataclass(Parameters, data_fields=list(PARAMETER_NAMES + _ARRAY_NAMES),
                                 meta_fields=[])


def _coefficient_count(name: str, value, first: str, second: str) -> int:
    """The 2 K of a coefficient array (K for ``first``, then K for ``second``), or a ValueError naming ``name``."""
    shape = np.shape(value)
    if len(shape) != 1 or shape[0] < 2 or shape[0] % 2:
        raise ValueError(f"{name} must be a 1-D array of 2 K coefficients (K >= 1 for {first}, then K for "
                         f"{second}), got shape {shape}")
    return shape[0]


def _same(a, b) -> bool:
    """Equality of two field values (None, scalars or arrays)."""
    if a is None or b is None:
        return a is None and b is None
    return bool(np.array_equal(np.asarray(a), np.asarray(b)))


class ParameterViews:
    """Read-only shortcuts to the ``parameters`` (a `Parameters`) of a record that carries one: its
    ``pressure``, ``prestrain`` ``(span, chord)``, rib scales, ``rib_shape`` and ``cut_pattern``."""

    parameters: Parameters


for _name in ("pressure", "prestrain", "rib_thickness_scale", "rib_chord_scale", "rib_shape", "cut_pattern"):
    setattr(ParameterViews, _name, property(lambda self, name=_name: getattr(self.parameters, name),
                                            doc=f"``parameters.{_name}`` (`Parameters`)."))
del _name


def _concrete(value) -> float | None:
    """The float of a concrete scalar; None for None or a JAX tracer."""
    if value is None or isinstance(value, jax.core.Tracer):
        return None
    array = np.asarray(value)
    if array.shape != ():
        raise ValueError(f"parameters are scalars, got a value of shape {array.shape}")
    return float(array)


def _pair(value, name: str) -> tuple:
    """``(span, chord)`` from a pair or one number for both."""
    if isinstance(value, (tuple, list)) or (hasattr(value, "shape") and np.ndim(value) == 1):
        if len(value) != 2:
            raise ValueError(f"{name} must be a (span, chord) pair or one number, got {value!r}")
        return value[0], value[1]
    return value, value


def as_parameters(parameters=None, prestrain=None, *, pressure=None) -> Parameters:
    """The one place loose values become `Parameters` (the public solvers' boundary).

    Either ``parameters`` is a `Parameters` and nothing else is given, or
    ``parameters`` (or ``pressure``) is the pressure in Pa and ``prestrain``
    ``(span, chord)`` or one number; every other field takes its default
    (stiffnesses and rib scales travel in a `Parameters`).

    Raises:
        ValueError: for both forms at once, or no pressure.
    """
    if isinstance(parameters, Parameters):
        given = [k for k, v in {"prestrain": prestrain, "pressure": pressure}.items() if v is not None]
        if given:
            raise ValueError(f"give either a Parameters or loose values, not both (also got {given}); "
                             "use parameters.replace(...) to change a field")
        return parameters
    if parameters is not None and pressure is not None:
        raise ValueError("the pressure was given twice (positionally and as pressure=)")
    pressure = parameters if pressure is None else pressure
    if pressure is None:
        raise ValueError("give the pressure (Pa) or a forward_solver.Parameters")
    ps, pc = _pair(0.0 if prestrain is None else prestrain, "prestrain")
    return Parameters(pressure=pressure, prestrain_span=ps, prestrain_chord=pc)


def bay_parameters(parameters: Parameters, shapes, k: int, fields=None) -> Parameters:
    """Bay ``k``'s `Parameters`: the shared ones, with its two ribs' rows of ``shapes`` (per-rib
    shapes, ``(n_ribs, 2 K)``) and its row of ``fields`` (per-bay cut fields, ``(n_bays, 2 K)``);
    either may be None. JAX values stay traced (the design loop's `DesignVariables.bay_parameters`)."""
    if shapes is not None:
        parameters = parameters.replace(rib_shape=shapes[k], rib_shape_tip=shapes[k + 1])
    if fields is not None:
        parameters = parameters.replace(cut_pattern=fields[k])
    return parameters
