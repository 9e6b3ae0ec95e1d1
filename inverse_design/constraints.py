"""Constraints an engineer sets on the design (DESIGN section 6).

* Bounds on pressure, prestrain and rib scales (`variables.DesignVariables`).
* A wrinkle-free skin: the smallest fibre tension of any cell, computed
  without the ``tension_only`` clamp (so a wrinkled cell shows a negative
  value), stays at or above ``min_tension`` (N/m, default 0).
* A strong enough fabric: the largest fibre tension stays at or below
  ``max_tension`` (N/m, default the fabric's ``allowable_tension``).

The optimisers enforce the tension constraints by an exterior quadratic
penalty (extra least-squares residuals ``weight * violation / scale``, zero
while the constraint holds); the result then reports which constraints are
active (within `ACTIVE_TOLERANCE` of their limit, or violated).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from forward_solver import forces as fk

__all__ = ["Constraints", "ACTIVE_TOLERANCE", "cell_tensions", "constraint_report"]

#: A constraint is reported active when within this fraction of its scale of
#: its limit (bounds: of the bound interval; tensions: of the tension scale).
ACTIVE_TOLERANCE = 1e-3


@dataclass(frozen=True)
class Constraints:
    """Tension limits on the inflated skin.

    Args:
        min_tension: floor of the fibre tensions, N/m (0: no wrinkles); None
            switches the constraint off.
        max_tension: ceiling of the fibre tensions, N/m; None takes the
            fabric's ``allowable_tension`` (``inf``: none).
        penalty: weight of the penalty residuals relative to the shape error
            (dimensionless; larger enforces harder).
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
        return fabric.allowable_tension if self.max_tension is None else float(self.max_tension)


@partial(jax.jit, static_argnames=("physics",))
def _tensions(x, geometry, params, physics):
    physics = fk.Physics(physics.periodic, tension_only=False)
    ref = fk.prepare(geometry, params, physics)
    fib = fk.fibres(x, ref, params, physics)
    return jnp.concatenate([fib.tension_span.reshape(-1), fib.tension_chord.reshape(-1)])


def cell_tensions(scene, nodes, values: dict):
    """Unclamped fibre tensions of every cell (span then chord), N/m, differentiable.

    Args:
        scene: the `forward_solver.Scene`.
        nodes: ``(n_span, n_contour, 3)`` m (JAX value allowed).
        values: parameter values (JAX values allowed), as for `Equilibrium`.
    """
    params = scene.params(values["pressure"], (values["prestrain_span"], values["prestrain_chord"]),
                          None, values["rib_thickness_scale"], values["rib_chord_scale"])
    geometry = jax.tree_util.tree_map(jnp.asarray, scene.bay.geometry())
    return _tensions(nodes, geometry, params, scene.physics(dynamic=False))


def tension_scale(values: dict, chord: float) -> float:
    """A natural tension, N/m: the hoop tension ``p * chord / 2`` of the pressure."""
    return 0.5 * abs(values["pressure"]) * chord


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


def constraint_report(constraints: Constraints | None, variables, values: dict, tensions: np.ndarray,
                      fabric, scale: float) -> tuple[list[str], dict]:
    """Active constraints at a design and their values.

    Returns:
        ``(active, values)``: names such as ``"pressure>=lower"``,
        ``"min_tension"``, ``"max_tension"``; and a dict of the measured
        minimum and maximum tension (N/m) and each limit.
    """
    active = []
    for name in variables.names:
        lo, hi = variables.bounds[name]
        width = hi - lo
        if values[name] - lo <= ACTIVE_TOLERANCE * width:
            active.append(f"{name}>=lower")
        if hi - values[name] <= ACTIVE_TOLERANCE * width:
            active.append(f"{name}<=upper")
    t_min, t_max = float(np.min(tensions)), float(np.max(tensions))
    report = {"min_tension": t_min, "max_tension": t_max}
    if constraints is not None:
        if constraints.min_tension is not None:
            report["min_tension_floor"] = constraints.min_tension
            if t_min - constraints.min_tension <= ACTIVE_TOLERANCE * scale:
                active.append("min_tension")
        ceiling = constraints.ceiling(fabric)
        report["max_tension_ceiling"] = ceiling
        if math.isfinite(ceiling) and ceiling - t_max <= ACTIVE_TOLERANCE * scale:
            active.append("max_tension")
    return active, report
