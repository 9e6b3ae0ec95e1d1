"""`optimise_wing`: one set of manufacturing parameters for a whole wing (issue 12, item 2).

A wing (`forward_solver.wing.Wing`) is N bays between N + 1 rigid ribs; all
bays share one inflation pressure and one fabric cut (prestrain), and one
rib thickness (and chord) scale; each rib may have its own rib shape
(below). `optimise_wing` chooses them with scipy's SLSQP
(`methods.slsqp`, the loop of `optimise_pressure`, with its evaluation cap
and stall detection), the gradients by reverse mode (``jax.vjp``) through
`forward_solver.solve_wing`: every bay relaxed in one ``jit(vmap)`` call and
differentiated by the implicit function theorem (batched matrix-free
adjoint, `forward_solver.krylov`), one adjoint solve of the whole wing per
output (objective, and each aggregated tension constraint).

The target of each span row (what the skin should be, DESIGN section 6)
--------------------------------------------------------------------------
Each rib ``k`` has a target section (``targets[k]``, default the rib's own
airfoil). Bay ``k`` runs from rib ``k`` (chord ``c_r``, target ``A_r``) to
rib ``k + 1`` (``c_t``, ``A_t``). At the span row ``eta`` (fraction of the rib
spacing) the target is the ruled surface between the two target sections at
their chords, the surface the bay's mounted skin follows
(`forward_solver.forces.nominal_nodes`), chord-normalised by the local chord
``c(eta) = (1 - eta) c_r + eta c_t``::

    T(eta) = ((1 - eta) c_r A_r + eta c_t A_t) / c(eta)

with ``A_r`` and ``A_t`` resampled at the same cosine stations
(`targets.Airfoil.resample`, `BLEND_POINTS` points). Where both ribs carry
the same target section ``T(eta) = A_r`` exactly, and the target airfoil is
used as it is (its analytic surface). The skin's row ``eta`` is likewise
divided by ``c(eta)`` (`objectives.section_points`), and its signed normal
distance from ``T(eta)`` (`objectives.target_distance`, differentiable) is
the error, in fractions of the local chord.

The objective
-------------
Per bay, the objective of `objectives.objective_value` over the rows of
`objectives.station_etas`: ``"mid_bay"`` (the mid-bay row), ``"average"``
(every grid row, rib to rib; the default) or ``"worst"`` (a smooth maximum
over the rows' mean squares, `objectives.WORST_SHARPNESS`). The wing's
objective is the sum of the bays' mean squares weighted by **bay planform
area** ``(c_r + c_t) / 2 * (y_t - y_r)`` over the wing's area (`bay_weights`):
a bay twice as large counts twice. Its square root is reported as the wing's
``rms_error``.

Constraints
-----------
The tension limits of `constraints.Constraints` (a wrinkle-free skin:
``min_tension >= 0``; a ceiling, default the fabric's allowable) over every
cell of every bay, as SLSQP inequality constraints: the unclamped cell
tensions of all bays are joined and aggregated by one Kreisselmeier-
Steinhauser function per limit (`constraints.constraint_functions`), with the
tension scale ``p c_max / 2`` of the widest bay. The result is checked
against the true extremes of each bay: a limit broken by more than
`constraints.VIOLATION_TOLERANCE` tension scales is *violated*, named with
its bay and amount, and the design is not a success.

Failures
--------
A bay whose solve does not converge has NaN nodes (`solve_wing`); the
problem never passes them to the optimiser: a warm-started solve that fails
is retried from the mounted shapes, and a cold failure raises
`WingConvergenceError` (a `forward_solver.ConvergenceError` naming the bay
and its result code): at the start it propagates; later it stops the
optimisation at the best iterate whose solves converged, with
``success=False`` and the failure in the message.

Per-rib rib shapes
------------------
The shared variables (pressure, prestrains, rib thickness and chord scales)
are one `Parameters` for every bay. ``"rib_shape"`` is per rib: each rib
``k`` has its own 2 K Bernstein coefficients (`forward_solver.rib_shape`),
one block per rib after the shared values in the design vector
(`WingVariables`); bay ``k`` is mounted between rib ``k``'s shape (its
``rib_shape``) and rib ``k + 1``'s (its ``rib_shape_tip``), both batched by
`solve_wing` (``rib_shapes=``) and differentiated by the same adjoint. Each
shaped rib keeps the manufacturability limits of `rib_design.RibLimits`
(minimum local thickness against its own starting section, curvature bound)
as SLSQP rows with exact forward-mode Jacobians (no solve), reported per rib.

All JAX work runs inside ``jax.enable_x64(True)`` (thread-local).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from forward_solver import ConvergenceError, Fabric, Parameters, Scene
from forward_solver.adjoint import GRADIENT_RTOL
from forward_solver.parameters import ParameterViews
from forward_solver.solution import Result
from forward_solver.wing import Wing, WingSolution, solve_wing

from .constraints import (VIOLATION_TOLERANCE, Constraints, cell_tensions, constraint_functions,
                          constraint_report)
from .methods import slsqp
from .objectives import WORST_SHARPNESS, check_objective, section_points, station_etas, target_distance
from .problem import DesignProblem, key_of, with_rib_rows
from .rib_design import RibGeometry, RibLimits, rib_report
from .variables import (_SCALES, DEFAULT_BOUNDS, DEFAULT_RIB_SHAPE_TERMS, DEFAULT_START, VARIABLES,
                        DesignVariables)

__all__ = ["BLEND_POINTS", "WING_VARIABLES", "PER_RIB_VARIABLES", "WingConvergenceError", "WingProblem",
           "WingDesignResult", "WingVariables", "bay_weights", "row_targets", "optimise_wing"]

#: Per-rib design variables (one block of coefficients per rib).
PER_RIB_VARIABLES = ("rib_shape",)
#: Design variables of a wing: the shared ones (one value for every bay), then the per-rib ones.
WING_VARIABLES = tuple(n for n in VARIABLES if n not in PER_RIB_VARIABLES) + PER_RIB_VARIABLES
#: Points of each target section when two different sections are blended along a bay.
BLEND_POINTS = 401


class WingConvergenceError(ConvergenceError):
    """A bay of the wing did not converge; ``.bay`` is its index, ``.solution`` its `Solution`."""

    def __init__(self, wing_solution: WingSolution, bay: int):
        solution = wing_solution.bay_solution(bay)
        super().__init__(solution)
        failed = wing_solution.failed_bays()
        y0 = sum(b.rib_spacing for b in wing_solution.bays[:bay])
        values = wing_solution.parameters
        self.bay = bay
        self.failed = failed
        self.args = (f"bay {bay} (ribs {bay} and {bay + 1}, y = {y0:.4g} to "
                     f"{y0 + wing_solution.bays[bay].rib_spacing:.4g} m; {len(failed)} of "
                     f"{len(wing_solution.bays)} bays failed) at pressure {float(values.pressure):.6g} Pa, "
                     f"prestrain ({float(values.prestrain_span):.6g}, {float(values.prestrain_chord):.6g}): "
                     f"{self.args[0]}",)


@dataclass(frozen=True)
class WingVariables:
    """The design vector of a wing: the shared values, then one block of rib-shape coefficients per rib.

    Attributes:
        shared: the `DesignVariables` of the values every bay shares.
        n_ribs: ribs of the wing.
        rib_shape_start: ``(n_ribs, 2 K)`` starting coefficients, or None when
            the rib shapes are not optimised (then every rib keeps
            ``shared.start.rib_shape``, None: its section).
        rib_shape_bounds: ``(lower, upper)`` of every coefficient.
    """

    shared: DesignVariables
    n_ribs: int
    rib_shape_start: np.ndarray | None = None
    rib_shape_bounds: tuple = DEFAULT_BOUNDS["rib_shape"]

    @classmethod
    def build(cls, variables, initial, bounds, n_ribs: int) -> "WingVariables":
        """Validate the names, starts and bounds.

        Args:
            variables: names from `WING_VARIABLES`.
            initial: a `Parameters` or ``{name: value}`` (`DesignVariables.build`); a
                ``rib_shape`` start is one ``(2 K,)`` row for every rib or an
                ``(n_ribs, 2 K)`` array (default zeros, K = `DEFAULT_RIB_SHAPE_TERMS`).
            bounds: ``{name: (lower, upper)}``; ``rib_shape``'s hold for every coefficient.
            n_ribs: ribs of the wing.

        Raises:
            ValueError: for an unknown name, a bad start or bound.
        """
        names = (variables,) if isinstance(variables, str) else tuple(variables)
        for name in names:
            if name not in WING_VARIABLES:
                raise ValueError(f"unknown design variable {name!r}; choose from {WING_VARIABLES}")
        bounds = dict(bounds or {})
        shaped = "rib_shape" in names
        shape_bounds = tuple(float(b) for b in bounds.pop("rib_shape", DEFAULT_BOUNDS["rib_shape"]))
        if isinstance(initial, Parameters):
            shape_start, initial = initial.rib_shape, initial.replace(rib_shape=None, rib_shape_tip=None)
        else:
            initial = dict(initial or {})
            shape_start = initial.pop("rib_shape", None)
        shared_names = tuple(n for n in names if n != "rib_shape")
        if not shared_names:
            raise ValueError("a wing design needs at least one shared variable (the pressure is the usual one) "
                             "besides the rib shapes")
        shared = DesignVariables.build(shared_names, initial, bounds)
        if not shaped:
            if shape_start is not None:  # a fixed shape for every rib
                shared = dataclasses.replace(shared, start=shared.start.replace(
                    rib_shape=np.asarray(shape_start, np.float64)).check())
            return cls(shared, n_ribs)
        lo, hi = shape_bounds
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ValueError(f"bounds of rib_shape must be a finite (lower, upper) pair with lower < upper, "
                             f"got {shape_bounds}")
        start = np.zeros(2 * DEFAULT_RIB_SHAPE_TERMS) if shape_start is None else np.asarray(shape_start, float)
        if start.ndim == 1:
            start = np.tile(start, (n_ribs, 1))
        if start.ndim != 2 or start.shape[0] != n_ribs or start.shape[1] < 2 or start.shape[1] % 2:
            raise ValueError(f"the rib_shape start must be one row of 2K coefficients for every rib or an "
                             f"({n_ribs}, 2K) array, got shape {np.shape(shape_start)}")
        if not np.all(np.isfinite(start)) or np.any(start < lo) or np.any(start > hi):
            raise ValueError(f"the rib_shape start must be finite and inside its bounds {shape_bounds}")
        return cls(shared, n_ribs, start, (lo, hi))

    @property
    def names(self) -> tuple:
        return self.shared.names + (() if self.rib_shape_start is None else ("rib_shape",))

    @property
    def bounds(self) -> dict:
        extra = {} if self.rib_shape_start is None else {"rib_shape": self.rib_shape_bounds}
        return {**self.shared.bounds, **extra}

    @property
    def _n_shared(self) -> int:
        return self.shared.size

    @property
    def _n_shape(self) -> int:
        return 0 if self.rib_shape_start is None else self.rib_shape_start.size

    @property
    def lower(self) -> np.ndarray:
        return np.concatenate([self.shared.lower, np.full(self._n_shape, self.rib_shape_bounds[0] / _SCALES["rib_shape"])])

    @property
    def upper(self) -> np.ndarray:
        return np.concatenate([self.shared.upper, np.full(self._n_shape, self.rib_shape_bounds[1] / _SCALES["rib_shape"])])

    def scale(self, name: str) -> float:
        return _SCALES["rib_shape"] if name == "rib_shape" else self.shared.scale(name)

    def start_vector(self) -> np.ndarray:
        """The scaled vector of the start."""
        shape = [] if self.rib_shape_start is None else [self.rib_shape_start.reshape(-1) / _SCALES["rib_shape"]]
        return np.concatenate([self.shared.to_vector(self.shared.start), *shape])

    def parameters(self, u) -> Parameters:
        """The shared `Parameters` at the scaled vector ``u`` (JAX values stay traced)."""
        return self.shared.parameters(u[: self._n_shared])

    def rib_shapes(self, u):
        """``(n_ribs, 2 K)`` rib-shape coefficients at ``u`` (JAX values stay traced), or None."""
        if self.rib_shape_start is None:
            return None
        return u[self._n_shared:].reshape(self.rib_shape_start.shape) * _SCALES["rib_shape"]

    def bay_parameters(self, u, bay: int) -> Parameters:
        """The `Parameters` of bay ``bay`` at ``u``: the shared ones with its ribs' shapes."""
        parameters, shapes = self.parameters(u), self.rib_shapes(u)
        if shapes is None:
            return parameters
        return parameters.replace(rib_shape=shapes[bay], rib_shape_tip=shapes[bay + 1])

    def values(self, u) -> dict:
        """``{name: value}`` at ``u``; ``rib_shape`` as one list of coefficients per rib."""
        u = np.asarray(u, np.float64)
        values = self.shared.values(u[: self._n_shared])
        if self.rib_shape_start is not None:
            values["rib_shape"] = np.asarray(self.rib_shapes(u)).tolist()
        return values

    def from_values(self, values: dict) -> np.ndarray:
        """The scaled vector of ``values`` (as `values` returns them)."""
        shared = self.shared.from_values({n: values[n] for n in self.shared.names})
        if self.rib_shape_start is None:
            return shared
        return np.concatenate([shared, np.asarray(values["rib_shape"], np.float64).reshape(-1) / _SCALES["rib_shape"]])


def bay_weights(wing: Wing) -> np.ndarray:
    """``(n_bays,)`` weights of the bays in the wing's objective: planform area over the wing's, summing to 1."""
    chords, stations = np.asarray(wing.chords, float), np.asarray(wing.stations, float)
    area = 0.5 * (chords[:-1] + chords[1:]) * np.diff(stations)
    return area / np.sum(area)


def _same_section(a, b) -> bool:
    return a is b or (np.array_equal(np.asarray(a.x), np.asarray(b.x))
                      and np.array_equal(np.asarray(a.z), np.asarray(b.z)))


def row_targets(root, tip, chord_root: float, chord_tip: float, etas) -> list:
    """The target `targets.Airfoil` of each span row ``eta`` of a bay (module docstring).

    Args:
        root, tip: the target sections of the bay's ribs (chord-normalised).
        chord_root, chord_tip: the rib chords, m.
        etas: span rows, fractions of the rib spacing.

    Returns:
        One `targets.Airfoil` per ``eta``, chord-normalised by the local chord:
        ``root`` itself for every row when both sections are the same, else
        the blend of the two at their chords (``root`` at 0, ``tip`` at 1).
    """
    from targets import Airfoil

    if _same_section(root, tip):
        return [root] * len(etas)
    a, b = root.resample(BLEND_POINTS), tip.resample(BLEND_POINTS)
    rows = []
    for eta in etas:
        if eta == 0.0:
            rows.append(root)
        elif eta == 1.0:
            rows.append(tip)
        else:
            wr, wt = (1.0 - eta) * chord_root, eta * chord_tip
            local = wr + wt
            rows.append(Airfoil((wr * a.x + wt * b.x) / local, (wr * a.z + wt * b.z) / local,
                                name=f"{root.name}-{tip.name} at {eta:.3g} b"))
    return rows


def _bay_distances(nodes, rows: list, etas, chords) -> jnp.ndarray:
    """``(n_rows, n_contour)`` signed distances of the bay's rows from their targets, local chords."""
    points = jnp.stack([section_points(nodes, float(e), float(c)) for e, c in zip(etas, chords)])
    if all(r is rows[0] for r in rows):
        return target_distance(rows[0], points)
    return jnp.stack([target_distance(r, points[i]) for i, r in enumerate(rows)])


def _mean_square(d, objective: str):
    """The bay's objective from its row distances, chord^2 (as `objectives.objective_value`)."""
    if objective != "worst":
        return jnp.mean(d * d)
    rows = jnp.mean(d * d, axis=1)
    top = jnp.maximum(jax.lax.stop_gradient(jnp.max(rows)), np.finfo(np.float64).tiny)
    return top * (1.0 + jnp.log(jnp.sum(jnp.exp(WORST_SHARPNESS * (rows / top - 1.0)))) / WORST_SHARPNESS)


def _errors(d: np.ndarray, objective: str) -> tuple[float, float]:
    """``(rms, max)`` over the objective's rows (the worst row for "worst"), fractions of chord."""
    d = np.asarray(d, np.float64)
    if objective == "worst":
        d = d[np.argmax(np.mean(d**2, axis=1))]
    return float(np.sqrt(np.mean(d**2))), float(np.max(np.abs(d)))


class WingProblem:
    """Objective, constraints, derivatives and iterate history of a wing design.

    Duck-types `problem.DesignProblem` where `methods.slsqp` needs it
    (``evaluate``, ``cached``, ``constraints``, ``variables``, ``best_iterate``).
    Its constraint vector is the tension rows (`constraints.Constraints.names`,
    over all bays), then, with rib shapes and ``rib_limits``, every rib's
    `rib_design.RibGeometry.functions` rows, root to tip.
    """

    best_iterate = DesignProblem.best_iterate  # uses only ``history`` and ``variables.from_values``

    def __init__(self, wing: Wing, fabric: Fabric, targets: list, variables: WingVariables, objective: str,
                 constraints: Constraints | None, *, n_span: int, n_contour: int, rtol: float,
                 max_steps: int, rib_limits: RibLimits | None = None):
        self.wing, self.fabric, self.targets = wing, fabric, targets
        self.variables, self.objective, self.constraints = variables, objective, constraints
        self.grid = dict(n_span=n_span, n_contour=n_contour)
        self.rtol, self.max_steps = rtol, max_steps
        self.bays = wing.bays(n_span, n_contour)
        self.scenes = [Scene(bay, fabric) for bay in self.bays]  # (tension_only, as solve_wing's default)
        self.weights = bay_weights(wing)
        self.etas = station_etas(objective, n_span)
        self.local_chords = [[(1 - e) * b.chord_root + e * b.chord_tip for e in self.etas] for b in self.bays]
        self.rows = [row_targets(targets[k], targets[k + 1], b.chord_root, b.chord_tip, self.etas)
                     for k, b in enumerate(self.bays)]
        self.chord = max(b.chord for b in self.bays)
        self.tension_scale = 0.5 * abs(float(variables.shared.start.pressure)) * self.chord
        self.rib_geometries = None
        if variables.rib_shape_start is not None and rib_limits is not None:
            # Each rib against its own starting section (the wing's rib airfoils).
            self.rib_geometries = [RibGeometry(af, rib_limits) for af in wing.airfoils]

            def rib_rows(u):
                parameters, shapes = variables.parameters(u), variables.rib_shapes(u)
                return jnp.concatenate([g.functions(parameters.replace(rib_shape=shapes[k]))
                                        for k, g in enumerate(self.rib_geometries)])

            self._rib_rows = jax.jit(lambda u: (rib_rows(u), jax.jacfwd(rib_rows)(u)))
        self.previous: WingSolution | None = None
        self.solves = 0
        self.history: list[dict] = []
        self.on_record = None
        self._cache: dict = {}
        self._solved: dict = {}

    # ------------------------------------------------------------ pieces
    def distances(self, nodes) -> list:
        """Per bay, the ``(n_rows, n_contour)`` distances of its rows (JAX values allowed)."""
        return [_bay_distances(nodes[k], self.rows[k], self.etas, self.local_chords[k])
                for k in range(len(self.bays))]

    def tensions(self, nodes, u) -> list:
        """Per bay, its unclamped cell tensions (span then chord) at ``u``, N/m, differentiable."""
        return [cell_tensions(scene, nodes[k], self.variables.bay_parameters(u, k))
                for k, scene in enumerate(self.scenes)]

    def _solve_wing(self, u, initial):
        self.solves += 1
        return solve_wing(self.wing, self.fabric, self.variables.parameters(u), rtol=self.rtol,
                          max_steps=self.max_steps, initial=initial, rib_shapes=self.variables.rib_shapes(u),
                          **self.grid)

    def _concrete(self, sol: WingSolution, aux: dict, u) -> WingSolution:
        u = np.asarray(u, np.float64)
        shapes = self.variables.rib_shapes(u)
        return dataclasses.replace(
            sol, nodes=np.asarray(aux["nodes"]), result=np.asarray(aux["result"]),
            residual=np.asarray(aux["residual"]), steps=np.asarray(aux["steps"]),
            mounted=np.asarray(aux["mounted"]), rib_shapes=None if shapes is None else np.asarray(shapes),
            parameters=self.variables.parameters(u).resolved(self.fabric).as_floats())

    def _remember(self, sol: WingSolution, u) -> WingSolution:
        self.previous = sol
        self._solved[key_of(u)] = sol
        return sol

    # ------------------------------------------------------------ evaluation
    def evaluate(self, u):
        """``(f, grad f, g, dg/du, solution)`` at the scaled vector ``u``: the area-weighted mean
        square error (chord^2) and the smooth constraints ``g >= 0``, gradients by reverse mode
        (the rib limits' rows by forward mode, without a solve).

        Raises:
            WingConvergenceError: if a bay does not converge from the mounted shape.
        """
        key = key_of(u)
        if key in self._cache:
            return self._cache[key]
        for initial in ([self.previous, None] if self.previous is not None else [None]):
            held = {}

            def outputs(v):
                sol = self._solve_wing(v, initial)
                held["sol"] = sol
                aux = {"nodes": sol.nodes, "result": sol.result, "residual": sol.residual, "steps": sol.steps,
                       "mounted": sol.mounted}
                if not sol.converged:  # NaN nodes: stop here, nothing downstream is used
                    return jnp.zeros(1), aux
                d = self.distances(sol.nodes)
                f = sum(float(w) * _mean_square(dk, self.objective) for w, dk in zip(self.weights, d))
                if self.constraints is None:
                    return f[None], aux
                t = jnp.concatenate(self.tensions(sol.nodes, v))
                g = constraint_functions(self.constraints, t, self.fabric, self.tension_scale)
                return jnp.concatenate([f[None], g]), aux

            y, pullback, aux = jax.vjp(outputs, jnp.asarray(u, jnp.float64), has_aux=True)
            sol = self._concrete(held["sol"], aux, u)
            if sol.converged:
                break
        else:
            raise WingConvergenceError(sol, sol.failed_bays()[0])
        rows = np.stack([np.asarray(pullback(e)[0]) for e in jnp.eye(y.size, dtype=y.dtype)])
        y = np.asarray(y)
        recorded = y[1:]
        if self.rib_geometries is not None:
            y, rows, g_rib = with_rib_rows(y, rows, self._rib_rows, u)
            recorded = np.concatenate([recorded, [g_rib.min()]])  # history: the least rib-limit row
        self._cache = {key: (y[0], rows[0], y[1:], rows[1:], self._remember(sol, u))}
        self.record(u, y[0], np.linalg.norm(rows[0]), sol, recorded)
        return self._cache[key]

    def solve(self, u) -> WingSolution:
        """The concrete `WingSolution` at ``u`` (from the archive if solved before).

        Raises:
            WingConvergenceError: if a bay does not converge from the mounted shape.
        """
        u = np.asarray(u, np.float64)
        if key_of(u) in self._solved:
            return self._solved[key_of(u)]
        for initial in ([self.previous, None] if self.previous is not None else [None]):
            sol = self._solve_wing(u, initial)
            sol = dataclasses.replace(sol, nodes=np.asarray(sol.nodes), result=np.asarray(sol.result),
                                      residual=np.asarray(sol.residual), steps=np.asarray(sol.steps),
                                      mounted=np.asarray(sol.mounted),
                                      rib_shapes=None if sol.rib_shapes is None else np.asarray(sol.rib_shapes))
            if sol.converged:
                return self._remember(sol, u)
        raise WingConvergenceError(sol, sol.failed_bays()[0])

    def cached(self, key):
        return self._cache.get(key)

    def record(self, u, objective, gradient_norm, solution: WingSolution, constraints):
        entry = {"values": self.variables.values(np.asarray(u, np.float64)), "objective": float(objective),
                 "gradient_norm": float(gradient_norm), "steps": int(np.max(solution.steps)),
                 "constraints": [float(c) for c in constraints]}
        self.history.append(entry)
        if self.on_record is not None:
            self.on_record(entry)

    # ------------------------------------------------------------ measurements
    def measure(self, sol: WingSolution, u) -> dict:
        """Per-bay errors and tension extremes of a concrete converged solution at ``u``."""
        d = [np.asarray(x) for x in self.distances(jnp.asarray(sol.nodes))]
        errors = [_errors(x, self.objective) for x in d]
        t = [np.asarray(x) for x in self.tensions(jnp.asarray(sol.nodes), np.asarray(u, np.float64))]
        mean_square = np.array([np.mean(x**2) if self.objective != "worst" else e[0] ** 2
                                for x, e in zip(d, errors)])
        return {"rms": np.array([e[0] for e in errors]), "max": np.array([e[1] for e in errors]),
                "wing_rms": float(np.sqrt(np.sum(self.weights * mean_square))),
                "min_tension": np.array([x.min() for x in t]), "max_tension": np.array([x.max() for x in t]),
                "tensions": t, "distances": d}


@dataclass(frozen=True, eq=False)
class WingDesignResult(ParameterViews):
    """Outcome of `optimise_wing`.

    Attributes:
        parameters: the shared `forward_solver.Parameters` of the design.
        variables: the optimised names.
        objective: "mid_bay", "average" or "worst" (per bay; module docstring).
        weights: ``(n_bays,)`` bay weights of the wing's objective (planform area).
        rms_error, initial_rms_error: the wing's error, ``sqrt(sum_k w_k ms_k)``,
            fractions of the local chord, at the design and at the start.
        bay_rms_error, bay_max_error: ``(n_bays,)`` RMS and largest normal
            distance of each bay's objective rows from their targets, fractions
            of the local chord, at the design.
        initial_bay_rms_error, initial_bay_max_error: the same at the start.
        bay_results: ``(n_bays,)`` `forward_solver.Result` names of the final solves.
        bay_min_tension, bay_max_tension: ``(n_bays,)`` smallest and largest
            unclamped fibre tension of each bay at the design, N/m.
        solution: the `forward_solver.wing.WingSolution` at the design.
        targets: the target section of each rib.
        success: SLSQP converged, every bay's final solve converged and no
            tension limit is broken by more than `constraints.VIOLATION_TOLERANCE`.
        message: SLSQP's message and whatever failed (constraint, bay, amount).
        active_constraints: bounds, tension limits and rib limits at their
            limit (``"rib_min_thickness@rib 2"``, ``"rib_shape[1][3]<=upper"``).
        violated_constraints: ``{name: {index: amount}}`` for each limit
            broken beyond its tolerance: tension limits by bay (N/m), rib
            limits by rib (`rib_design.rib_report`'s amounts).
        violated_at_start: the same for the starting design (empty when the
            start met every limit): a start that broke a limit may have a
            smaller error than a design that meets it.
        constraint_values: the wing's extreme tensions and the limits, N/m.
        history: one dict per iterate: ``values``, ``objective`` (chord^2),
            ``gradient_norm``, ``constraints`` (``g >= 0`` feasible), ``steps``
            (of the slowest bay).
        solves: forward wing solves (each relaxes every bay once).
        wall_time: s, compilation included.
        method: "slsqp".
        wing: the `forward_solver.wing.Wing` designed.
        rib_shapes: ``(n_ribs, 2 K)`` rib-shape coefficients of the design
            (root to tip), or None when the rib shapes were not optimised.
        rib_limits: per rib, the measured manufacturability limits
            (`rib_design.RibGeometry.measure`) of a shaped rib; empty otherwise.
    """

    parameters: Parameters
    variables: tuple
    objective: str
    weights: np.ndarray
    rms_error: float
    initial_rms_error: float
    bay_rms_error: np.ndarray
    bay_max_error: np.ndarray
    initial_bay_rms_error: np.ndarray
    initial_bay_max_error: np.ndarray
    bay_results: tuple
    bay_min_tension: np.ndarray
    bay_max_tension: np.ndarray
    solution: WingSolution
    targets: tuple
    success: bool = False
    message: str = ""
    active_constraints: list = field(default_factory=list)
    violated_constraints: dict = field(default_factory=dict)
    constraint_values: dict = field(default_factory=dict)
    violated_at_start: dict = field(default_factory=dict)
    history: list = field(default_factory=list)
    solves: int = 0
    wall_time: float = 0.0
    method: str = "slsqp"
    wing: Wing | None = None
    rib_shapes: np.ndarray | None = None
    rib_limits: list = field(default_factory=list)

    @property
    def values(self) -> dict:
        """``{name: value}`` of every design parameter (`variables.VARIABLES`)."""
        return {name: getattr(self.parameters, name) for name in VARIABLES}

    @property
    def n_bays(self) -> int:
        return len(self.bay_rms_error)


def _targets(wing: Wing, targets) -> list:
    if targets is None:
        return list(wing.airfoils)
    if hasattr(targets, "distance"):  # one Airfoil for every rib
        return [targets] * len(wing.airfoils)
    targets = list(targets)
    if len(targets) != len(wing.airfoils):
        raise ValueError(f"give one target section per rib: the wing has {len(wing.airfoils)} ribs, got "
                         f"{len(targets)} targets (or one Airfoil for all, or None for the ribs' own)")
    for k, t in enumerate(targets):
        if not hasattr(t, "distance"):
            raise ValueError(f"target {k} must be a targets.Airfoil, got {type(t).__name__}")
    return targets


def optimise_wing(
    wing: Wing,
    fabric: Fabric,
    targets: Sequence | None = None,
    variables=("pressure",),
    *,
    initial: Parameters | Mapping | None = None,
    bounds: Mapping | None = None,
    objective: str = "average",
    constraints: Constraints | None = Constraints(),
    rib_limits: RibLimits | None = RibLimits(),
    n_span: int = 17,
    n_contour: int = 64,
    max_iterations: int = 50,
    tolerance: float = 1e-6,
    rtol: float = GRADIENT_RTOL,
    max_steps: int = 200_000,
    progress: bool = False,
    callback=None,
) -> WingDesignResult:
    """One pressure (and prestrain, rib scales; a rib shape per rib) for every bay of ``wing`` (module docstring).

    Args:
        wing: the ribs (`forward_solver.wing.Wing`).
        fabric: the skin's `forward_solver.Fabric` (one for the whole wing).
        targets: the target section of each rib (N + 1 `targets.Airfoil`), one
            `targets.Airfoil` for every rib, or None: each rib's own section.
        variables: names to optimise, from `WING_VARIABLES`: shared ones, and
            ``"rib_shape"`` for one set of coefficients per rib.
        initial: the starting `Parameters`, or ``{name: value}`` (Pa,
            fractions) over `variables.DEFAULT_START`; a ``rib_shape`` start
            is one ``(2 K,)`` row for every rib or ``(n_ribs, 2 K)``.
        bounds: ``{name: (lower, upper)}`` of optimised names (defaults
            `variables.DEFAULT_BOUNDS`; ``rib_shape``'s for every coefficient).
        objective: per bay: "mid_bay", "average" (default) or "worst";
            combined over bays weighted by planform area (`bay_weights`).
        constraints: tension limits over every cell of every bay, or None.
        rib_limits: manufacturability limits of every shaped rib against its
            own starting section (`rib_design.RibLimits`), or None.
        n_span, n_contour: the grid of every bay.
        max_iterations: SLSQP's iteration cap (and twice that in forward solves).
        tolerance: SLSQP's ``ftol`` on the objective relative to its start.
        rtol: relative residual every bay is solved to (the implicit gradient
            is only as good as the equilibrium).
        max_steps: step cap of each wing solve.
        progress: a tqdm bar on stderr, one tick per iterate (off by default).
        callback: ``callback(entry)`` after every iterate with the new history entry.

    Returns:
        A `WingDesignResult`.

    Raises:
        ValueError: for an unknown variable or objective, bad bounds, targets
            or limits.
        WingConvergenceError: if a bay's solve at the start (or the final solve
            at a clipped design never solved before) does not converge; a
            failure in between ends the optimisation at the best iterate.
    """
    check_objective(objective)
    if not (isinstance(max_iterations, int) and max_iterations >= 1):
        raise ValueError(f"max_iterations must be a positive integer, got {max_iterations!r}")
    if not (isinstance(tolerance, float | int) and 0 < tolerance < 1):
        raise ValueError(f"tolerance must lie in (0, 1), got {tolerance!r}")
    if constraints is not None:
        if not isinstance(constraints, Constraints):
            raise ValueError(f"constraints must be an inverse_design.Constraints or None, got {constraints!r}")
        constraints.check(fabric)
    if not isinstance(wing, Wing):
        raise ValueError(f"wing must be a forward_solver.wing.Wing, got {type(wing).__name__}")
    targets = _targets(wing, targets)
    design = WingVariables.build(variables, DEFAULT_START if initial is None else initial, bounds,
                                 len(wing.airfoils))
    start = time.perf_counter()
    bar = tqdm(total=max_iterations, desc="optimise_wing", unit="iterate", disable=not progress, leave=False,
               dynamic_ncols=True, bar_format="{desc}: iterate {n_fmt} (cap {total_fmt}), {elapsed} elapsed{postfix}")
    with jax.enable_x64(True), bar:
        problem = WingProblem(wing, fabric, targets, design, objective, constraints, n_span=n_span,
                              n_contour=n_contour, rtol=rtol, max_steps=max_steps, rib_limits=rib_limits)

        def on_record(entry):
            bar.set_postfix_str(f"rms={math.sqrt(max(entry['objective'], 0.0)):.3e}", refresh=False)
            bar.update(1)
            if callback is not None:
                callback(entry)

        problem.on_record = on_record
        u0 = design.start_vector()
        sol0 = problem.evaluate(u0)[-1]
        before = problem.measure(sol0, u0)
        violated_at_start = _start_violations(problem, design, constraints, fabric, sol0.parameters, before, u0)
        try:
            u, success, message = slsqp(problem, u0, max_iterations, tolerance)
        except WingConvergenceError as failure:
            best = problem.best_iterate()
            u = u0 if best is None else best
            success = False
            message = (f"stopped: {failure}; the result is the best iterate whose solves converged; narrow "
                       "the bounds to where every bay has an equilibrium")
        u = np.clip(np.asarray(u, np.float64), design.lower, design.upper)
        sol = problem.solve(u)
        parameters = sol.parameters  # shared (rib shapes: `WingSolution.rib_shapes`)
        after = problem.measure(sol, u)
        if not (np.all(np.isfinite(after["rms"])) and np.all(np.isfinite(sol.nodes))):
            success, message = False, f"{message}; the shape errors at the result are not finite"
        active, violated, report, text = _check_limits(constraints, design, parameters, after, fabric,
                                                       problem.tension_scale)
        shapes = design.rib_shapes(u)
        ribs = []
        if shapes is not None:
            lo, hi = design.rib_shape_bounds
            for k, row in enumerate(np.asarray(shapes)):
                active += [f"rib_shape[{k}][{j}]{side}" for j, c in enumerate(row)
                           for side, hit in ((">=lower", c - lo <= 1e-3 * (hi - lo)),
                                             ("<=upper", hi - c <= 1e-3 * (hi - lo))) if hit]
                if problem.rib_geometries is not None:
                    rib_active, rib_violated, measured = rib_report(
                        problem.rib_geometries[k], parameters.replace(rib_shape=row))
                    ribs.append(measured)
                    active += [f"{name}@rib {k}" for name in rib_active]
                    for name, amount in rib_violated.items():
                        violated.setdefault(name, {})[k] = amount
                        text += (f"{'; ' if text else ''}{name} violated at rib {k}: "
                                 f"{measured[name]:.4g} against the limit {measured[name + '_limit']:.4g}")
        if violated:
            success, message = False, f"{message}; {text}"
        if not sol.converged:
            success = False
    return WingDesignResult(
        parameters=parameters, variables=design.names, objective=objective, weights=problem.weights,
        rms_error=after["wing_rms"], initial_rms_error=before["wing_rms"],
        bay_rms_error=after["rms"], bay_max_error=after["max"],
        initial_bay_rms_error=before["rms"], initial_bay_max_error=before["max"],
        bay_results=tuple(Result(int(r)).name for r in np.asarray(sol.result)),
        bay_min_tension=after["min_tension"], bay_max_tension=after["max_tension"],
        solution=sol, targets=tuple(targets), success=bool(success), message=message,
        active_constraints=active, violated_constraints=violated, constraint_values=report,
        violated_at_start=violated_at_start, history=problem.history, solves=problem.solves, wall_time=time.perf_counter() - start, wing=wing,
        rib_shapes=None if shapes is None else np.asarray(shapes), rib_limits=ribs)


def _start_violations(problem, design, constraints, fabric, parameters, measured, u) -> dict:
    """``{name: {index: amount}}`` of the limits the start breaks, as
    `WingDesignResult.violated_constraints` counts them (tension limits by bay, rib limits by rib)."""
    violated = _check_limits(constraints, design, parameters, measured, fabric, problem.tension_scale)[1]
    shapes = design.rib_shapes(u)
    if shapes is not None and problem.rib_geometries is not None:
        for k, row in enumerate(np.asarray(shapes)):
            for name, amount in rib_report(problem.rib_geometries[k], parameters.replace(rib_shape=row))[1].items():
                violated.setdefault(name, {})[k] = amount
    return violated


def _check_limits(constraints, design, parameters, measured, fabric, scale):
    """Active limits (`constraints.constraint_report` on all bays' tensions) and, per bay, the
    violated ones: ``(active, {name: {bay: amount}}, report, message)``."""
    tensions = np.concatenate(measured["tensions"])
    active, _, report = constraint_report(constraints, design.shared, parameters, tensions, fabric, scale)
    violated, parts = {}, []
    if constraints is None:
        return active, violated, report, ""
    limit = VIOLATION_TOLERANCE * scale
    floor, ceiling = constraints.min_tension, constraints.ceiling(fabric)
    for k, (low, high) in enumerate(zip(measured["min_tension"], measured["max_tension"])):
        if floor is not None and floor - low > limit:
            violated.setdefault("min_tension", {})[k] = float(floor - low)
            parts.append(f"min_tension violated in bay {k}: its smallest fibre tension is {low:.4g} N/m, "
                         f"{floor - low:.4g} N/m below the floor {floor:.4g} N/m (the skin wrinkles)")
        if math.isfinite(ceiling) and high - ceiling > limit:
            violated.setdefault("max_tension", {})[k] = float(high - ceiling)
            parts.append(f"max_tension violated in bay {k}: its largest fibre tension is {high:.4g} N/m, "
                         f"{high - ceiling:.4g} N/m above the ceiling {ceiling:.4g} N/m")
    text = "; ".join(parts)
    if parts:
        text += (" (no design within the bounds meets the limits, or the optimiser stopped early: widen "
                 "the bounds or relax the limits)")
    return active, violated, report, text
