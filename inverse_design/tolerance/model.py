"""The tolerance model of a design: its tolerance parameters (`Column`), their map onto each bay's
`forward_solver.Parameters`, and the one per-bay Jacobian of the distances and tensions in them
(`ToleranceModel.bay_jacobian`).

Each source maps onto a parameter the solver already differentiates
(`ToleranceModel.bay_parameters`, per bay):

* ``pressure`` (Pa) and ``stiffness_span`` / ``stiffness_chord`` (N/m): the
  `forward_solver.Parameters` fields themselves, bay by bay.
* ``cut_span`` / ``cut_chord`` (mm): a panel cut ``dL`` longer than its
  reference length ``L / (1 + e)`` (``L`` the mounted length: the rib spacing
  along the span, the mean contour length of the bay's mounted skin around
  it) has the prestrain ``L / (L / (1 + e) + dL) - 1`` (paper eq. 12; to first
  order ``-(1 + e)^2 dL / L``), exact for a uniform cut; a designed cut field
  keeps its shape and moves by the same amount.
* ``rib_station`` (mm): rib k mounted ``ds_k`` off its station stretches bay
  k - 1's span fibres by ``ds_k`` and shortens bay k's: their span prestrain
  becomes ``(b + db) / (b / (1 + e) + dL) - 1`` with ``db = ds_{k+1} - ds_k``.
  The bay is solved at its nominal spacing: the bulge's own growth with the
  spacing (relative order ``2 db / b``, 0.8% of the bulge for 1 mm on 0.25 m)
  is left out, against the span tension's change (``db / b`` over the
  prestrain: 20% for 1 mm on a 2% prestrain).
* ``rib_profile`` (mm): rib k's outline offset outward by the rib shape's
  class function alone (`forward_solver.model.rib_shape`: every Bernstein
  coefficient of both surfaces raised by the same ``a``): ``dz = a C(x)
  c``, ``C(x) = sqrt(x) (1 - x)``, with ``a`` chosen so that the offset's
  rms over the chord is the value given (``a = dn / (c C_rms)``, ``C_rms =
  1/sqrt(12)``). It leaves the trailing edge (a seam) in place and grows the
  nose like a thicker rib. It is the rib's thickness scatter in the model's
  own terms, not a uniform normal offset (which the model cannot hold at the
  trailing edge).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from forward_solver import Parameters, Solution, solve_equilibrium
from forward_solver.compilation import stored_jit
from forward_solver.derivatives.implicit import ImplicitAdjoint
from forward_solver.derivatives.rhs import kernel_tangent
from forward_solver.model.parameters import PARAMETER_NAMES
from forward_solver.programs import mounted_compiled

from ..constraints import fibre_tensions, tension_inputs
from ..objectives import WingTargets, row_points
from .inputs import SOURCE_SCOPE, SOURCES

__all__ = ["CLASS_RMS", "MOUNTING_SOURCES", "Column", "ToleranceModel", "bay_changes", "bay_values", "summary_of"]

#: The sources that move a bay's mounted shape (its ribs' outline): `ToleranceModel.predicted_start`.
MOUNTING_SOURCES = ("rib_profile",)
#: rms over x in [0, 1] of the rib shape's class function sqrt(x) (1 - x) (`forward_solver.model.rib_shape`).
CLASS_RMS = 1.0 / math.sqrt(12.0)


def bay_values(nominal: list, spacing, contour, rib_chords, shape_terms: int) -> dict:
    """The per-bay nominal values `bay_changes` reads: ``{name: (n_bays, ...) array}`` (``rib_chords``:
    ``(n_bays + 1,)``, a rib's chord; unset rib shapes as zero coefficients)."""

    def shapes(index: int) -> np.ndarray:
        return np.stack([np.zeros(shape_terms) if p.rib_shapes[index] is None
                         else np.asarray(p.rib_shapes[index], np.float64) for p in nominal])

    return {"pressure": np.array([float(p.pressure) for p in nominal]),
            "stiffness_span": np.array([float(p.stiffness_span) for p in nominal]),
            "stiffness_chord": np.array([float(p.stiffness_chord) for p in nominal]),
            "prestrain_span": np.array([float(p.prestrain_span) for p in nominal]),
            "prestrain_chord": np.array([float(p.prestrain_chord) for p in nominal]),
            "spacing": np.asarray(spacing, np.float64), "contour": np.asarray(contour, np.float64),
            "rib_chords": np.asarray(rib_chords, np.float64), "rib_shape": shapes(0), "rib_shape_tip": shapes(1)}


def bay_changes(e, k, values: dict, offsets: tuple) -> dict:
    """The fields of bay ``k``'s `Parameters` that the deviations ``e`` change (the module docstring's
    map), in operators and indexing alone: NumPy's arithmetic on concrete values, one program under
    ``jax.jit`` with ``k`` traced (`ToleranceModel.bay_parameters`).

    Args:
        e: ``(size,)`` deviations, the sources' units.
        k: the bay.
        values: `bay_values`.
        offsets: ``((source, first column), ...)`` of the sources present: a source's column of bay or
            rib ``i`` is its first column plus ``i`` (one for the wing: the first).
    """
    first = dict(offsets)

    def dev(source, index=k):
        if source not in first:
            return 0.0
        return e[first[source] + (0 if SOURCE_SCOPE[source] == "wing" else index)]

    changes = {}
    if "pressure" in first:
        changes["pressure"] = values["pressure"][k] + dev("pressure")
    for name in ("stiffness_span", "stiffness_chord"):
        if name in first:
            changes[name] = values[name][k] + dev(name)
    # (b + db) / (b / (1 + e0) + dL) - 1, written as e0 plus a change that is exactly 0 at no
    # deviation: the nominal wing is then the design's own, to the bit (its kept factor serves)
    if {"cut_span", "rib_station"} & first.keys():
        b, e0 = values["spacing"][k], values["prestrain_span"][k]
        db = 1e-3 * (dev("rib_station", k + 1) - dev("rib_station", k))
        dl = (1.0 + e0) * 1e-3 * dev("cut_span")
        changes["prestrain_span"] = e0 + (1.0 + e0) * (db - dl) / (b + dl)
    if "cut_chord" in first:
        c, e0 = values["contour"][k], values["prestrain_chord"][k]
        dl = (1.0 + e0) * 1e-3 * dev("cut_chord")
        changes["prestrain_chord"] = e0 - (1.0 + e0) * dl / (c + dl)
    if "rib_profile" in first:
        root, tip = values["rib_shape"][k], values["rib_shape_tip"][k]
        a_root = 1e-3 * dev("rib_profile", k) / (values["rib_chords"][k] * CLASS_RMS)
        a_tip = 1e-3 * dev("rib_profile", k + 1) / (values["rib_chords"][k + 1] * CLASS_RMS)
        changes["rib_shape"] = root + a_root
        changes["rib_shape_tip"] = tip + a_tip
    return changes


_traced_bay_changes = partial(jax.jit, static_argnames=("offsets",))(bay_changes)


@partial(stored_jit, static_argnames=("offsets",))
def _change_tangents(basis, k, values: dict, offsets: tuple) -> dict:
    """The derivatives of `bay_changes` at no deviation along each row of ``basis`` (``(n, size)``):
    ``{name: (n, ...)}``, one program (``k`` among its operands)."""
    e0 = jnp.zeros(basis.shape[1], basis.dtype)
    return jax.vmap(lambda t: jax.jvp(lambda e: bay_changes(e, k, values, offsets), (e0,), (t,))[1])(basis)


@partial(stored_jit, static_argnames=("physics",))
def _bay_outputs(distances, chords, x, geometry, params, physics):
    """A bay's rows' distances (fractions of their local chords) in mm, flat, then its cells' fibre
    tensions (N/m; `constraints.fibre_tensions`): one program."""
    return jnp.concatenate([(distances * chords[:, None] * 1e3).reshape(-1),
                            fibre_tensions(x, geometry, params, physics)])


@partial(stored_jit, static_argnames=("etas", "physics"))
def _outputs_and_tangents(distances, normals, chords, x, dx, geometry, params, dparams, etas, physics):
    """`_bay_outputs` at the nodes ``x`` and its derivatives along each of a batch of the nodes' and
    kernel parameters' tangents (``dx``: ``(n, n_span, n_contour, 3)``; every leaf of ``dparams``
    with a leading axis ``n``): a row point's distance moves by the target's ``normals`` there
    times the point's motion (`objectives.bay_projections`). ``((n_outputs,), (n, n_outputs))``,
    one program."""

    def one(dx, dparams):
        dpoints = jax.jvp(lambda n: row_points(n, etas, chords), (x,), (dx,))[1]
        dd = jnp.sum(normals * dpoints, axis=-1) * chords[:, None] * 1e3
        dt = jax.jvp(lambda n, p: fibre_tensions(n, geometry, p, physics), (x, params), (dx, dparams))[1]
        return jnp.concatenate([dd.reshape(-1), dt])

    return _bay_outputs(distances, chords, x, geometry, params, physics), jax.vmap(one)(dx, dparams)


@dataclass(frozen=True)
class Column:
    """One tolerance parameter."""

    name: str  # as the CSV names it: pressure, stiffness_span_bay_2, rib_station_rib_0
    source: str
    index: int  # the bay or rib (0 for the pressure)


class ToleranceModel:
    """The tolerance parameters of a design and their map onto each bay's `Parameters` (module docstring).

    Args:
        sol: the design's concrete `forward_solver.solution.BaysSolution` (its bays, parameters, LU
            factors where kept).
        targets: the design's rows against its targets (`objectives.WingTargets`).
        tolerances: ``{name: Tolerance}`` (`inputs.as_tolerances`; a source at 0 does not scatter).
        stations: the ribs' span stations, m (None: from the bays' rib spacings).

    Attributes:
        columns: the parameters (`Column`), in the order of every vector of deviations.
        nominal_values, spread, std, uniform: ``(size,)`` each column's nominal value, spread
            (standard deviation or half-width) and standard deviation in its source's unit, and
            whether it is uniform.
        touching: per bay, the indices of the columns its equilibrium depends on.
        start_tangents: per bay, the tangents ``(len(touching[k]), n_span, n_contour, 3)`` of its
            nodes in its touching columns, m per unit, kept by
            `bay_jacobian` (None before): a sample's first-order warm start (`predicted_start`). They
            hold as many numbers per bay as its tension rows' Jacobian and half again.
    """

    def __init__(self, sol, targets: WingTargets, tolerances: dict, stations=None):
        self.n_bays = n = len(sol.bays)
        self.design_nodes = [np.asarray(sol.nodes[k]) for k in range(n)]  # (the nominal solves' start)
        self.design_solutions = list(sol.solutions) if sol.solutions is not None else [None] * n
        self.scenes = [sol.scene(k) for k in range(n)]
        fabric = self.scenes[0].fabric
        self.nominal = [sol.bay_parameters(k).resolved(fabric) for k in range(n)]
        self.tolerances = {name: t for name, t in tolerances.items() if t.value > 0}
        wing = n > 1
        self.columns = []
        for source in SOURCES:
            if source not in self.tolerances:
                continue
            scope = SOURCE_SCOPE[source]
            count = 1 if scope == "wing" else n if scope == "bay" else n + 1
            for k in range(count):
                suffix = "" if scope == "wing" or (scope == "bay" and not wing) else f"_{scope}_{k}"
                self.columns.append(Column(source + suffix, source, k))
        bays = [s.bay for s in self.scenes]
        self.spacing = np.array([b.rib_spacing for b in bays])
        mounted = np.asarray(sol.mounted) if sol.mounted is not None else np.asarray(sol.nodes)
        segments = np.linalg.norm(np.roll(mounted, -1, axis=2) - mounted, axis=-1)  # (bays, span, contour)
        self.contour = segments.sum(axis=2).mean(axis=1)  # m, mean contour length of each bay's skin
        chords = [b.chord_root for b in bays] + [bays[-1].chord_tip]
        self.rib_chords = np.array([c * float(self.nominal[min(k, n - 1)].rib_chord_scale)
                                    for k, c in enumerate(chords)])
        self.stations = stations if stations is not None else np.concatenate([[0.0], np.cumsum(self.spacing)])
        shapes = [p.rib_shapes for p in self.nominal]
        self.shape_terms = next((np.size(s[0]) for s in shapes if s[0] is not None), 2)
        # the nominal value of each column, in its source's unit
        self.nominal_values = np.array([self._nominal(c) for c in self.columns])
        self.spread = np.array([self.tolerances[c.source].spread(v) for c, v in
                                zip(self.columns, self.nominal_values)])
        self.uniform = np.array([self.tolerances[c.source].uniform for c in self.columns])
        self.std = np.where(self.uniform, self.spread / math.sqrt(3.0), self.spread)
        self.touching = [self._touching(k) for k in range(n)]
        self.start_tangents = [None] * n
        self.start_mounted = [None] * n  # (the nominal's mounted shape, beside its tangents)
        self.targets = targets
        self.weights = np.asarray(targets.weights, np.float64)
        # (`bay_changes`' operands: the first column of each source present, and each bay's nominal values)
        firsts = {}
        for i, c in enumerate(self.columns):
            firsts.setdefault(c.source, i)
        self._offsets = tuple(firsts.items())
        self._bay_values = bay_values(self.nominal, self.spacing, self.contour, self.rib_chords, self.shape_terms)

    @classmethod
    def of(cls, result, tolerances: dict) -> "ToleranceModel":
        """The model of a finished design (a `DesignResult`: its solution, targets, objective and wing)."""
        sol = result.wing_solution
        targets = WingTargets([sol.scene(k).bay for k in range(len(sol.bays))], result.per_bay.targets,
                              result.objective)
        return cls(sol, targets, tolerances, None if result.wing is None else np.asarray(result.wing.stations))

    def __getstate__(self) -> dict:
        """Pickled (to a Dask worker) without the design's solutions (they hold LU factors) and without a
        worker's nominal solutions."""
        return {k: (v if k != "design_solutions" else [None] * len(v)) for k, v in self.__dict__.items()
                if k != "worker_nominal"}

    @property
    def size(self) -> int:
        return len(self.columns)

    def _nominal(self, column: Column) -> float:
        p = self.nominal[min(column.index, self.n_bays - 1)]
        if column.source == "pressure":
            return float(p.pressure)
        if column.source.startswith("stiffness"):
            return float(getattr(p, column.source))
        if column.source == "cut_span":
            return 1e3 * self.spacing[column.index] / (1.0 + float(p.prestrain_span))
        if column.source == "cut_chord":
            return 1e3 * self.contour[column.index] / (1.0 + float(p.prestrain_chord))
        if column.source == "rib_station":
            return 1e3 * float(self.stations[column.index])
        return 0.0  # rib_profile: the offset itself

    def _touching(self, k: int) -> np.ndarray:
        """Indices of the columns that bay ``k``'s equilibrium depends on."""
        return np.array([i for i, c in enumerate(self.columns)
                         if SOURCE_SCOPE[c.source] == "wing" or (SOURCE_SCOPE[c.source] == "bay" and c.index == k)
                         or (SOURCE_SCOPE[c.source] == "rib" and c.index in (k, k + 1))], dtype=int)

    def bay_parameters(self, k: int, e) -> Parameters:
        """Bay ``k``'s `Parameters` at the deviations ``e`` (``(size,)``, the sources' units; JAX
        values allowed): the module docstring's map (`bay_changes`). Concrete deviations (a Monte
        Carlo sample) take NumPy's arithmetic; JAX ones (a caller's own ``jax.jvp`` or ``jax.jit``) one
        jitted program for every bay, ``k`` among its operands (the map's dozen operations were each an
        eager program of their own under ``vmap`` and ``jvp``). `bay_jacobian` takes the map's tangents
        from one stored program of its own (`_change_tangents`)."""
        if isinstance(e, jax.Array):
            changes = _traced_bay_changes(e, np.int32(k), self._bay_values, self._offsets)
        else:
            changes = bay_changes(np.asarray(e, np.float64), k, self._bay_values, self._offsets)
        return self.nominal[k].replace(**changes)

    def outputs(self, k: int, nodes, parameters):
        """Bay ``k``'s normal distances (mm, the objective's rows) and cell tensions (N/m), one vector."""
        return _bay_outputs(self.targets.distances(k, nodes), np.asarray(self.targets.chords[k], np.float64),
                            nodes, *tension_inputs(self.scenes[k], parameters))

    @property
    def n_distances(self) -> int:
        return self.targets.n_distances

    def bay_jacobian(self, k: int, start, rtol: float):
        """Bay ``k``'s `outputs` and their ``(n_outputs, size)`` Jacobian in the columns (zero outside
        ``touching[k]``), forward mode by the implicit rule at the nominal equilibrium: ``start`` (a
        `Solution` converged within ``rtol``, its LU factor reused where current) or, otherwise, the
        solve warm from it (a `Solution` or nodes). The columns' parameter tangents (one program,
        `_change_tangents`), their nodes' tangents (one right-hand-side program and one back-solve
        of them all, `forward_solver.derivatives.implicit.ImplicitTangent.tangents`) and the outputs'
        (with their values, one program, `_outputs_and_tangents`) are each one call with concrete
        values: no transformation of the solve is traced (under ``jax.vmap`` of ``jax.jvp`` of the
        whole chain it was, in every process, most of the default case's analysis). The nodes'
        tangents are kept (``start_tangents[k]``) with the nominal's mounted shape (``start_mounted[k]``)."""
        cols = self.touching[k]
        scene = self.scenes[k]
        p = self.bay_parameters(k, np.zeros(self.size))  # (the design's own to the bit: `bay_changes`)
        sol = start
        if not (isinstance(sol, Solution) and sol.converged and float(sol.residual) <= rtol):
            sol = solve_equilibrium(scene, p, rtol=rtol, method="auto", initial=start, throw=True)
        geometry, params, physics = tension_inputs(scene, p)
        x = jax.device_put(np.asarray(sol.nodes, np.float64))  # (a transfer, not an eager operation)
        distances, normals = self.targets.projections(k, x)
        chords = np.asarray(self.targets.chords[k], np.float64)
        if cols.size == 0:
            y = np.asarray(_bay_outputs(distances, chords, x, geometry, params, physics))
            return y, np.zeros((y.size, self.size))
        basis = np.zeros((cols.size, self.size))
        basis[np.arange(cols.size), cols] = 1.0
        changes = _change_tangents(basis, np.int32(k), self._bay_values, self._offsets)
        dparams = kernel_tangent(Parameters(**dict.fromkeys(PARAMETER_NAMES)).replace(**changes), params)
        dparams = jax.tree_util.tree_map(  # (a parameter no column moves: its zero for every column)
            lambda d, like: d if np.ndim(d) > np.ndim(like) else np.broadcast_to(d, (cols.size,) + np.shape(like)),
            dparams, params)
        dx = ImplicitAdjoint().at(x, geometry, params, physics, sol.factor).tangents(dparams)
        etas = tuple(float(e) for e in self.targets.etas)
        y, dy = _outputs_and_tangents(distances, normals, chords, x, dx, geometry, params, dparams, etas, physics)
        y = np.asarray(y)
        jac = np.zeros((y.size, self.size))
        jac[:, cols] = np.asarray(dy).T
        self.start_tangents[k] = np.asarray(dx)
        self.start_mounted[k] = np.asarray(mounted_compiled(geometry, scene.params(self.nominal[k])))
        return y, jac

    def predicted_start(self, k: int, e, nominal):
        """Bay ``k``'s warm start at the deviations ``e``: its ``nominal`` `Solution` (with its LU factor),
        its nodes moved by their first-order change (``start_tangents[k]``, where `bay_jacobian` kept
        them), so that the chord Newton iteration with the nominal factor starts within the deviations'
        second-order error; otherwise ``nominal`` as it is. (A solve starts from its warm start's
        displacement on its own mounted shape, `forward_solver.solution.initial_nodes`: where the ribs
        move, the tangents hold the mounted shape's change, which that adds again, so it is taken off.)"""
        tangents = self.start_tangents[k]
        if tangents is None or not isinstance(nominal, Solution):
            return nominal
        e = np.asarray(e, np.float64)
        nodes = np.asarray(nominal.extra.get("primal_nodes", nominal.nodes)) + np.tensordot(
            e[self.touching[k]], tangents, axes=1)
        if any(self.columns[c].source in MOUNTING_SOURCES and e[c] != 0.0 for c in self.touching[k]):
            scene = self.scenes[k]
            geometry = scene.bay.geometry()
            moved = np.asarray(mounted_compiled(geometry, scene.params(self.bay_parameters(k, e))))
            nodes = nodes - (moved - self.start_mounted[k])
        return nominal.replace(nodes=nodes, extra={**nominal.extra, "primal_nodes": nodes})

    def nominal_solutions(self, rtol: float) -> list:
        """Each bay's equilibrium at the design with a Newton factor: the design's own solution where it
        holds the current factor at that tolerance (the design's last solve), else solved again warm
        from the design's nodes."""
        out = []
        for k in range(self.n_bays):
            kept = self.design_solutions[k]
            factor = None if kept is None else kept.factor
            if factor is not None and factor.current and kept.converged and float(kept.residual) <= rtol:
                out.append(kept)
                continue
            start = self.design_nodes[k]
            out.append(solve_equilibrium(self.scenes[k], self.nominal[k], rtol=rtol, method="newton",
                                         initial=start if np.all(np.isfinite(start)) else None, throw=True))
        return out

    def unit_draws(self, rng: np.random.Generator, count: int) -> np.ndarray:
        """``(count, size)`` draws in units of each column's spread: standard normal, or uniform on [-1, 1]."""
        z = rng.standard_normal((count, self.size))
        u = rng.uniform(-1.0, 1.0, (count, self.size))
        return np.where(self.uniform[None, :], u, z)

    def measures(self, distances: list, tensions: list) -> dict:
        """Per bay and for the wing: rms and largest distance (mm), least tension (N/m), of ``(m, ...)``
        arrays of draws (one per bay)."""
        ms = np.stack([np.mean(d**2, axis=-1) for d in distances], axis=-1)  # (m, bays)
        largest = np.stack([np.max(np.abs(d), axis=-1) for d in distances], axis=-1)
        least = np.stack([np.min(t, axis=-1) for t in tensions], axis=-1)
        return {"bay_rms": np.sqrt(ms), "bay_max": largest, "bay_min_tension": least,
                "rms": np.sqrt(ms @ self.weights), "max": largest.max(axis=-1), "min_tension": least.min(axis=-1)}


def _stats(values: np.ndarray) -> dict:
    """mean, std, p5 and p95 of the finite ``values`` (NaN for none)."""
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"mean": math.nan, "std": math.nan, "p5": math.nan, "p95": math.nan}
    return {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if v.size > 1 else 0.0,
            "p5": float(np.percentile(v, 5)), "p95": float(np.percentile(v, 95))}


def summary_of(measures: dict) -> dict:
    """mean, std, p5 and p95 of the wing's rms, largest distance and least tension, and per bay (``bays``)."""
    return {"rms": _stats(measures["rms"]), "max": _stats(measures["max"]),
            "min_tension": _stats(measures["min_tension"]),
            "bays": [{"rms": _stats(measures["bay_rms"][:, k]), "max": _stats(measures["bay_max"][:, k]),
                      "min_tension": _stats(measures["bay_min_tension"][:, k])}
                     for k in range(measures["bay_rms"].shape[1])]}
