"""Constraints an engineer sets on the design: tension limits over every cell of every bay.

* Bounds on pressure, prestrain and rib scales (`variables.DesignVariables`).
* A wrinkle-free skin: the smallest fibre tension of any cell, computed
  without the ``tension_only`` clamp (so a wrinkled cell shows a negative
  value), stays at or above ``min_tension`` (N/m, default 0).
* A strong enough fabric: the largest fibre tension stays at or below
  ``max_tension`` (N/m, default the fabric's ``allowable_tension``).

The optimiser ``method="slsqp"`` (the default for one bay) handles them as inequality
constraints ``g(u) >= 0`` (`constraint_functions`): the cell tensions are
aggregated smoothly by a Kreisselmeier-Steinhauser (KS) function, a smooth
minimum (maximum) that never lies above (below) the true one, so a design
that satisfies the aggregate satisfies every cell; its conservatism is at
most ``log(n_cells) / KS_SHARPNESS`` tension scales, and in practice the log
of the number of cells near the extreme. ``"least_squares"`` and
``"optax"`` use exterior penalties instead (`penalty_residuals`).

On a wing the cell tensions of all bays are joined before they are
aggregated (one row per limit), with the tension scale ``p c / 2`` of the
widest bay.

Whatever the method, the result is checked against the true extreme
tensions (`constraint_report`): a constraint is *active* when the true
extreme, or the smooth aggregate the optimiser saw, lies within
`ACTIVE_TOLERANCE` of its limit, and *violated* when the true extreme is
beyond it by more than `VIOLATION_TOLERANCE` (both fractions of the tension
scale ``p * chord / 2``), reported per bay (``{name: {bay: amount}}``); a violated
design is not a success.

The tolerance is judged at the design's own pressure: ``p`` is the pressure
of the design being reported (`tension_scale` of its parameters), not the
pressure the optimiser started from (which only scales the optimiser's own
rows), so a design at 1 kPa on a 1 m chord is allowed 0.5 N/m, not the
5 N/m of a 10 kPa start. A floor at or above zero (the default 0: a
wrinkle-free skin) is broken by any cell whose fibre tension is negative,
whatever the tolerance: a design reported wrinkle-free has no wrinkled cell
(`forward_solver.Solution.wrinkled`, tension below zero) in its own tension
map.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from forward_solver import Parameters
from forward_solver import forces as fk

__all__ = ["Constraints", "ACTIVE_TOLERANCE", "VIOLATION_TOLERANCE", "FLOOR_MARGIN", "KS_SHARPNESS",
           "cell_tensions", "fibre_tensions", "tension_inputs", "cell_constraints", "floor_threshold",
           "constraint_functions", "penalty_residuals", "constraint_report", "tension_scale",
           "UNMET_ADVICE"]

#: A constraint is reported active when within this fraction of its scale of
#: its limit (bounds: of the bound interval; tensions: of the tension scale).
ACTIVE_TOLERANCE = 1e-3

#: A tension constraint is violated when the true extreme tension is beyond
#: its limit by more than this fraction of the tension scale (about 0.5 N/m
#: at 1 kPa on a 1 m chord): the optimiser's own feasibility tolerance, far
#: below what a fabric's allowable or a wrinkle test can resolve.
VIOLATION_TOLERANCE = 1e-3

#: The cell rows of a floor at or above zero (`cell_constraints`) ask for this
#: fraction of the tension scale above the floor (0.005 N/m at 1 kPa on a 1 m
#: chord): a Gauss-Newton step is exact only to its linearisation, and a
#: wrinkle-free floor is broken by any negative tension (`floor_threshold`).
FLOOR_MARGIN = 1e-5

#: Sharpness ``rho`` of the KS aggregate, per tension scale.
KS_SHARPNESS = 1000.0


@dataclass(frozen=True)
class Constraints:
    """Tension limits on the inflated skin.

    Args:
        min_tension: floor of the fibre tensions, N/m (0: no wrinkles); None
            switches the constraint off.
        max_tension: ceiling of the fibre tensions, N/m; None takes the
            fabric's ``allowable_tension`` (``inf``: none).
        penalty: weight of the penalty residuals relative to the shape error
            (dimensionless; larger enforces harder), for the penalty methods.
    """

    min_tension: float | None = 0.0
    max_tension: float | None = None
    penalty: float = 1e2

    def __post_init__(self):
        if self.min_tension is not None and not math.isfinite(self.min_tension):
            raise ValueError(f"min_tension must be finite (N/m) or None, got {self.min_tension!r}")
        if self.max_tension is not None and not self.max_tension > 0:
            raise ValueError(f"max_tension must be positive (N/m) or None, got {self.max_tension!r}")
        if not self.penalty > 0:
            raise ValueError(f"penalty must be positive, got {self.penalty!r}")

    def ceiling(self, fabric) -> float:
        """The maximum tension in N/m (the fabric's allowable unless set)."""
        return fabric.allowable_tension if self.max_tension is None else float(self.max_tension)

    def check(self, fabric) -> "Constraints":
        """Raise a ValueError for limits no skin can meet (floor at or above the ceiling)."""
        ceiling = self.ceiling(fabric)
        if self.min_tension is not None and self.min_tension >= ceiling:
            raise ValueError(
                f"inconsistent tension limits: the minimum tension {self.min_tension:g} N/m is not "
                f"below the maximum {ceiling:g} N/m; lower min_tension or raise max_tension")
        return self

    def names(self, fabric) -> tuple:
        """The tension constraints in force, in the order of `constraint_functions`."""
        names = ()
        if self.min_tension is not None:
            names += ("min_tension",)
        if math.isfinite(self.ceiling(fabric)):
            names += ("max_tension",)
        return names


def fibre_tensions(x, geometry, params, physics):
    """Unclamped fibre tensions of every cell (span then chord), N/m, at nodes ``x`` from the force
    kernel's inputs (`tension_inputs`): `cell_tensions`' program, traceable into a larger one."""
    physics = dataclasses.replace(physics, tension_only=False)  # (the fabric's law kept)
    ref = fk.prepare(geometry, params, physics)
    fib = fk.fibres(x, ref, params, physics)
    return jnp.concatenate([fib.tension_span.reshape(-1), fib.tension_chord.reshape(-1)])


_tensions = partial(jax.jit, static_argnames=("physics",))(fibre_tensions)


def cell_tensions(scene, nodes, parameters: Parameters):
    """Unclamped fibre tensions of every cell (span then chord), N/m, differentiable.

    Args:
        scene: the `forward_solver.Scene`.
        nodes: ``(n_span, n_contour, 3)`` m (JAX value allowed).
        parameters: the `forward_solver.Parameters` (JAX values allowed).
    """
    return _tensions(nodes, *tension_inputs(scene, parameters))


def tension_inputs(scene, parameters: Parameters) -> tuple:
    """``(geometry, params, physics)``: the force kernel's inputs of `fibre_tensions` for ``scene`` at
    ``parameters`` (JAX values allowed)."""
    return scene.bay.geometry(), scene.params(parameters), scene.physics(dynamic=False)


def tension_scale(parameters: Parameters, chord: float) -> float:
    """A natural tension, N/m: the hoop tension ``p * chord / 2`` of the pressure."""
    return 0.5 * abs(float(parameters.pressure)) * chord


def floor_threshold(floor: float, scale: float) -> float:
    """The least fibre tension (N/m) that still meets the floor ``floor`` (N/m) at tension scale ``scale``
    (N/m, the design's own ``p c / 2``).

    ``floor - VIOLATION_TOLERANCE * scale``, but never below zero for a floor at or above zero: a
    wrinkled cell (negative tension) never meets a wrinkle-free floor (module docstring).
    """
    threshold = floor - VIOLATION_TOLERANCE * scale
    return max(threshold, 0.0) if floor >= 0.0 else threshold


def _ks_max(t, rho):
    """Smooth maximum ``max(t) + log(sum(exp(rho (t - max t)))) / rho >= max(t)``."""
    top = jax.lax.stop_gradient(jnp.max(t))
    return top + jnp.log(jnp.sum(jnp.exp(rho * (t - top)))) / rho


@partial(jax.jit, static_argnames=("has_floor", "has_ceiling"))
def _smooth_limits(tensions, floor, ceiling, scale, has_floor: bool, has_ceiling: bool):
    # One program (and one more under each derivative) for what were a dozen eager operations, each
    # traced and compiled on its own; the limits and the scale are operands, so new values do not
    # compile again.
    t = jnp.concatenate([jnp.reshape(x, -1) for x in tensions]) / scale
    parts = []
    if has_floor:
        parts.append(-_ks_max(-t, KS_SHARPNESS) - floor / scale)
    if has_ceiling:
        parts.append(ceiling / scale - _ks_max(t, KS_SHARPNESS))
    return jnp.stack(parts) if parts else jnp.zeros(0, t.dtype)


def constraint_functions(constraints: Constraints | None, tensions, fabric, scale: float):
    """Smooth inequality constraints ``g >= 0``, one per name of `Constraints.names` (dimensionless).

    ``min_tension``: ``(KS-min(T) - floor) / scale``; ``max_tension``:
    ``(ceiling - KS-max(T)) / scale`` (module docstring; ``T`` the unclamped
    cell tensions, N/m, an array or a list of them (one per bay); ``scale``
    the tension scale, N/m).
    """
    if constraints is None:
        return jnp.zeros(0)
    if not isinstance(tensions, (list, tuple)):
        tensions = [tensions]
    ceiling = constraints.ceiling(fabric)
    floor = constraints.min_tension
    return _smooth_limits(list(tensions), 0.0 if floor is None else float(floor),
                          ceiling if math.isfinite(ceiling) else 0.0, float(scale),
                          has_floor=floor is not None, has_ceiling=math.isfinite(ceiling))


def cell_constraints(constraints: Constraints | None, tensions, fabric, scale: float):
    """Every cell's constraint rows ``>= 0`` (dimensionless): ``(T - floor) / scale`` for every tension,
    then ``(ceiling - T) / scale``, for the limits of `Constraints.names` in that order (``T`` the
    unclamped cell tensions, N/m), less `FLOOR_MARGIN` on the rows of a floor at or above zero. Their
    least values are the true extremes that `constraint_report` checks (`constraint_functions`
    aggregates them smoothly instead)."""
    if constraints is None:
        return jnp.zeros(0)
    parts = []
    if constraints.min_tension is not None:
        margin = FLOOR_MARGIN if constraints.min_tension >= 0.0 else 0.0
        parts.append((tensions - constraints.min_tension) / scale - margin)
    ceiling = constraints.ceiling(fabric)
    if math.isfinite(ceiling):
        parts.append((ceiling - tensions) / scale)
    return jnp.concatenate(parts) if parts else jnp.zeros(0)


def penalty_residuals(constraints: Constraints | None, tensions, fabric, scale: float):
    """Exterior-penalty residuals (zero while the tension constraints hold)."""
    parts = []
    if constraints is None:
        return jnp.zeros(0)
    weight = math.sqrt(constraints.penalty)
    if constraints.min_tension is not None:
        parts.append(weight * jnp.maximum(constraints.min_tension - tensions, 0.0) / scale)
    ceiling = constraints.ceiling(fabric)
    if math.isfinite(ceiling):
        parts.append(weight * jnp.maximum(tensions - ceiling, 0.0) / scale)
    return jnp.concatenate(parts) if parts else jnp.zeros(0)


#: What a message about unmet limits suggests.
UNMET_ADVICE = (" (no design within the bounds meets the limits, or the optimiser stopped early: widen the "
                "bounds or relax the limits)")


def constraint_report(constraints: Constraints | None, variables, parameters: Parameters, tensions: list,
                      fabric, scale: float, rib_shapes=None, cut_patterns=None
                      ) -> tuple[list[str], dict, dict, list[str]]:
    """Active and violated constraints at a design, and the measured extremes.

    Args:
        constraints: the tension limits, or None.
        variables: the `DesignVariables` (bounds).
        parameters: the design's shared `Parameters`.
        tensions: per bay, its unclamped cell tensions, N/m (`cell_tensions`).
        fabric: the `Fabric` (default ceiling).
        scale: the tension scale, N/m: the design's own (`tension_scale` of ``parameters``; module
            docstring), which the tolerances are fractions of.
        rib_shapes: the design's per-rib shapes, if any (their bounds).
        cut_patterns: the design's per-bay cut fields, if any (their bounds).

    Returns:
        ``(active, violated, values, messages)``: names such as
        ``"pressure>=lower"``, ``"min_tension"``, ``"max_tension"`` at their
        limit (module docstring); ``{name: {bay: amount}}`` of each tension limit
        broken by more than `VIOLATION_TOLERANCE` in some bay (N/m beyond
        it; a floor at or above zero by any negative tension, `floor_threshold`);
        the measured minimum and maximum tension over all bays (N/m)
        with each limit; and one sentence per broken limit and bay.
    """
    active = []
    for name, value, lo, hi in variables.components(parameters, rib_shapes, cut_patterns):
        width = hi - lo
        if value - lo <= ACTIVE_TOLERANCE * width:
            active.append(f"{name}>=lower")
        if hi - value <= ACTIVE_TOLERANCE * width:
            active.append(f"{name}<=upper")
    joined = np.concatenate([np.reshape(t, -1) for t in tensions])
    t_min, t_max = float(np.min(joined)), float(np.max(joined))
    report = {"min_tension": t_min, "max_tension": t_max}
    if constraints is None:
        return active, {}, report, []
    smooth = dict(zip(constraints.names(fabric),
                      np.asarray(constraint_functions(constraints, joined, fabric, scale))))
    floor, ceiling = constraints.min_tension, constraints.ceiling(fabric)
    if floor is not None:
        report["min_tension_floor"] = floor
        if min(abs(t_min - floor) / scale, abs(smooth["min_tension"])) <= ACTIVE_TOLERANCE:
            active.append("min_tension")
    report["max_tension_ceiling"] = ceiling
    if math.isfinite(ceiling) and min(abs(ceiling - t_max) / scale, abs(smooth["max_tension"])) <= ACTIVE_TOLERANCE:
        active.append("max_tension")
    where, messages = {}, []
    one = len(tensions) == 1
    for k, t in enumerate(tensions):
        low, high = float(np.min(t)), float(np.max(t))
        at, its = ("", "the") if one else (f" in bay {k}", "its")
        if floor is not None and low < floor_threshold(floor, scale):
            where.setdefault("min_tension", {})[k] = floor - low
            messages.append(f"min_tension violated{at}: {its} smallest fibre tension is {low:.4g} N/m, "
                            f"{floor - low:.4g} N/m below the floor {floor:.4g} N/m (the skin wrinkles)")
        if math.isfinite(ceiling) and high - ceiling > VIOLATION_TOLERANCE * scale:
            where.setdefault("max_tension", {})[k] = high - ceiling
            messages.append(f"max_tension violated{at}: {its} largest fibre tension is {high:.4g} N/m, "
                            f"{high - ceiling:.4g} N/m above the ceiling {ceiling:.4g} N/m")
    return active, where, report, messages
