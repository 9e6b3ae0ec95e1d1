"""Tolerances: what the shop's scatter does to the cured wing, to first order and by Monte Carlo.

Production scatters (docs/tolerances.md): the pressure (one value for the
wing), the fabric's stiffnesses (per lot; each bay's panels are their own
lot), the cut lengths (per bay and fibre direction), the rib stations and the
rib outlines (per rib). Each source maps onto a parameter the solver already
differentiates (`bay_parameters`, per bay):

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

First order (`tolerance_analysis`): per bay, one forward-mode JVP of the
equilibrium (`forward_solver.solve_equilibrium`'s implicit derivative,
within `forward_solver.derivatives.implicit.forward_only`: the design's own equilibrium and
LU factor where the design kept them (its last solve), else one Newton solve
warm from the design, then one back-solve per parameter touching that bay with
that factor) gives ``J``, the Jacobian of every normal distance of the objective's
rows (mm) and of every cell's fibre tension (N/m) in the tolerance
parameters. The distances are linearised, not the rms (at a design the rms
sits at a minimum in the designed directions, so its own derivative is near
zero there and a linearised rms would understate its spread and miss its
shift): with ``d = d0 + J e``, ``E[ms] = (|d0|^2 + tr(J S J^T)) / n``
exactly, and the distributions of the rms, the largest distance and the
least tension come from sampling that linear model (`LINEAR_SAMPLES` draws of
the stated distributions, milliseconds: the largest distance and the least
tension are maxima and minima of many linear functions, which no moment
formula gives). The budget inverts the same model: the mean square of each
draw is ``a + l B + l^2 C`` in a scale ``l`` of the tolerances, so a
tolerance that meets the spec is found by bisection without a solve.

Monte Carlo (``samples``): draws wings from the stated distributions and
solves each bay warm from the nominal equilibrium (chord Newton with its
kept factor, the fallbacks of `forward_solver.solvers.chain` where not) to
`SAMPLE_RTOL`, in this process, or on a Dask cluster (``scheduler``: the
samples in chunks, each worker making the nominal factor once by the same
solve as here, so the same seed gives the same numbers). A sample whose solve
fails is counted and named, never dropped.

Wrinkling onset makes the least tension non-smooth: where a cell's tension
crosses zero within the scatter the linear prediction of the least tension
stops holding (compare it with the samples).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import brentq

from forward_solver import Parameters, solve_equilibrium
from forward_solver.derivatives.custom_jvp import GRADIENT_RTOL
from forward_solver.derivatives.implicit import forward_only

from .constraints import cell_tensions
from .objectives import bay_distances, local_chords, row_targets, station_etas

__all__ = ["DEFAULT_TOLERANCES", "LINEAR_SAMPLES", "SAMPLE_RTOL", "SCHEDULER_TIMEOUT_S", "SOURCES", "SOURCE_UNITS",
           "Tolerance", "ToleranceAnalysis", "connect_scheduler", "parse_tolerance", "parse_tolerances", "solve_sample",
           "tolerance_analysis", "wing_outputs"]

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
#: Draws of the linearised model behind its distributions and the budget (a fixed stream: the same
#: numbers every run; the p95 of 4000 draws is within about 1% of the distribution's).
LINEAR_SAMPLES = 4000
#: Relative residual of a Monte Carlo wing's solves (the residual force 1e-8 of the pressure load: the
#: command's equilibrium tolerance; its error in the distances is far below their scatter).
SAMPLE_RTOL = 1e-8
#: rms over x in [0, 1] of the rib shape's class function sqrt(x) (1 - x) (`forward_solver.model.rib_shape`).
CLASS_RMS = 1.0 / math.sqrt(12.0)
#: The largest common or single-source scale of the tolerances the budget searches.
BUDGET_SCALE_CAP = 1e3


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


def _as_tolerances(tolerances) -> dict:
    """``{name: Tolerance}`` as given, or parsed (`parse_tolerances`)."""
    if isinstance(tolerances, dict) and all(isinstance(t, Tolerance) for t in tolerances.values()):
        return dict(tolerances)
    return parse_tolerances(tolerances)


# ------------------------------------------------------------------ the parameter vector
@dataclass(frozen=True)
class _Column:
    name: str  # as the CSV names it: pressure, stiffness_span_bay_2, rib_station_rib_0
    source: str
    index: int  # the bay or rib (0 for the pressure)


class _Model:
    """The tolerance parameters of a design and their map onto each bay's `Parameters`."""

    def __init__(self, result, tolerances: dict):
        stations = np.asarray(result.wing.stations) if result.wing is not None else None
        self.result = result
        self._setup(result.wing_solution, stations, result.objective, result.per_bay.targets,
                    result.per_bay.weights, tolerances)

    @classmethod
    def at(cls, sol, targets, weights, objective: str, tolerances: dict) -> "_Model":
        """The model of the bays' equilibrium ``sol`` (a concrete `BaysSolution`) with the rib ``targets``,
        bay ``weights`` and ``objective`` rows of a design in progress (`robust`), not a finished result."""
        model = cls.__new__(cls)
        model.result = None
        model._setup(sol, None, objective, targets, weights, tolerances)
        return model

    def _setup(self, sol, stations, objective: str, targets, weights, tolerances: dict) -> None:
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
                self.columns.append(_Column(source + suffix, source, k))
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
        self.etas = station_etas(objective, bays[0].n_span)
        self.rows = [row_targets(targets[k], targets[k + 1], b.chord_root, b.chord_tip, self.etas)
                     for k, b in enumerate(bays)]
        self.chords = [np.asarray(local_chords(b, self.etas), np.float64) for b in bays]
        self.weights = np.asarray(weights if weights is not None else np.ones(n) / n, np.float64)

    def __getstate__(self) -> dict:
        """Pickled (to a Dask worker) without the design result and solutions (they hold LU factors)
        and without a worker's nominal solutions."""
        return {k: (v if k != "design_solutions" else [None] * len(v)) for k, v in self.__dict__.items()
                if k not in ("result", "worker_nominal")}

    @property
    def size(self) -> int:
        return len(self.columns)

    def _nominal(self, column: _Column) -> float:
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

    def deviation(self, e, source: str, index: int):
        """The entry of ``e`` (deviations in the sources' units) of ``source`` at ``index``, or 0."""
        for i, c in enumerate(self.columns):
            if c.source == source and c.index == index:
                return e[i]
        return 0.0

    def bay_parameters(self, k: int, e) -> Parameters:
        """Bay ``k``'s `Parameters` at the deviations ``e`` (``(size,)``, the sources' units; JAX
        values allowed): the module docstring's map."""
        p = self.nominal[k]
        def dev(source, index=k):
            return self.deviation(e, source, index)

        changes = {}
        if "pressure" in self.tolerances:
            changes["pressure"] = p.pressure + dev("pressure", 0)
        for name in ("stiffness_span", "stiffness_chord"):
            if name in self.tolerances:
                changes[name] = getattr(p, name) + dev(name)
        # (b + db) / (b / (1 + e0) + dL) - 1, written as e0 plus a change that is exactly 0 at no
        # deviation: the nominal wing is then the design's own, to the bit (its kept factor serves)
        if {"cut_span", "rib_station"} & set(self.tolerances):
            b, e0 = self.spacing[k], float(p.prestrain_span)
            db = 1e-3 * (dev("rib_station", k + 1) - dev("rib_station", k))
            dl = (1.0 + e0) * 1e-3 * dev("cut_span")
            changes["prestrain_span"] = e0 + (1.0 + e0) * (db - dl) / (b + dl)
        if "cut_chord" in self.tolerances:
            c, e0 = self.contour[k], float(p.prestrain_chord)
            dl = (1.0 + e0) * 1e-3 * dev("cut_chord")
            changes["prestrain_chord"] = e0 - (1.0 + e0) * dl / (c + dl)
        if "rib_profile" in self.tolerances:
            root, tip = p.rib_shapes
            size = self.shape_terms
            root = np.zeros(size) if root is None else np.asarray(root, np.float64)
            tip = np.zeros(size) if tip is None else np.asarray(tip, np.float64)
            ones = np.ones(size)
            a_root = 1e-3 * dev("rib_profile", k) / (self.rib_chords[k] * CLASS_RMS)
            a_tip = 1e-3 * dev("rib_profile", k + 1) / (self.rib_chords[k + 1] * CLASS_RMS)
            changes["rib_shape"] = root + a_root * ones
            changes["rib_shape_tip"] = tip + a_tip * ones
        return p.replace(**changes)

    def outputs(self, k: int, nodes, parameters):
        """Bay ``k``'s normal distances (mm, the objective's rows) and cell tensions (N/m), one vector."""
        d = bay_distances(nodes, self.rows[k], self.etas, self.chords[k])
        d = jnp.reshape(d * jnp.asarray(self.chords[k])[:, None] * 1e3, (-1,))
        return jnp.concatenate([d, cell_tensions(self.scenes[k], nodes, parameters)])

    @property
    def n_distances(self) -> int:
        return len(self.etas) * self.scenes[0].bay.n_contour


# ------------------------------------------------------------------ statistics
def _stats(values: np.ndarray) -> dict:
    """mean, std, p5 and p95 of the finite ``values`` (NaN for none)."""
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"mean": math.nan, "std": math.nan, "p5": math.nan, "p95": math.nan}
    return {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if v.size > 1 else 0.0,
            "p5": float(np.percentile(v, 5)), "p95": float(np.percentile(v, 95))}


def _measures(model: _Model, distances: list, tensions: list) -> dict:
    """Per bay and for the wing: rms and largest distance (mm), least tension (N/m), of ``(m, ...)``
    arrays of draws (one per bay)."""
    ms = np.stack([np.mean(d**2, axis=-1) for d in distances], axis=-1)  # (m, bays)
    largest = np.stack([np.max(np.abs(d), axis=-1) for d in distances], axis=-1)
    least = np.stack([np.min(t, axis=-1) for t in tensions], axis=-1)
    return {"bay_rms": np.sqrt(ms), "bay_max": largest, "bay_min_tension": least,
            "rms": np.sqrt(ms @ model.weights), "max": largest.max(axis=-1), "min_tension": least.min(axis=-1)}


def _summary_of(measures: dict) -> dict:
    return {"rms": _stats(measures["rms"]), "max": _stats(measures["max"]),
            "min_tension": _stats(measures["min_tension"]),
            "bays": [{"rms": _stats(measures["bay_rms"][:, k]), "max": _stats(measures["bay_max"][:, k]),
                      "min_tension": _stats(measures["bay_min_tension"][:, k])}
                     for k in range(measures["bay_rms"].shape[1])]}


def _unit_draws(model: _Model, rng: np.random.Generator, count: int) -> np.ndarray:
    """``(count, size)`` draws in units of each column's spread: standard normal, or uniform on [-1, 1]."""
    z = rng.standard_normal((count, model.size))
    u = rng.uniform(-1.0, 1.0, (count, model.size))
    return np.where(model.uniform[None, :], u, z)


# ------------------------------------------------------------------ the result
@dataclass
class ToleranceAnalysis:
    """What `tolerance_analysis` found (docs/tolerances.md).

    Attributes:
        tolerances: ``{name: Tolerance}`` given (non-zero).
        columns: the parameter names (``pressure``, ``stiffness_span_bay_0``,
            ``rib_station_rib_1``, ...), in the order of every vector here.
        sources: the source of each column.
        units: the unit of each column (`SOURCE_UNITS`).
        nominal: ``(size,)`` each column's nominal value (the CSV's
            absolute values less the deviation): Pa, N/m, the panels' cut
            lengths and the ribs' stations in mm, 0 for a rib offset.
        std: ``(size,)`` each column's standard deviation in its unit.
        distances: per bay, ``(n_rows * n_contour,)`` nominal normal
            distances of the objective's rows, mm.
        tensions: per bay, the nominal unclamped cell tensions, N/m.
        distance_jacobians, tension_jacobians: per bay, ``(rows, size)``:
            mm and N/m per unit of each column (zero where a column does not
            touch the bay).
        linear, sampled: mean, std, p5 and p95 of the wing's rms and largest
            distance (mm) and least tension (N/m), and per bay (``bays``),
            from the linearised model and from the Monte Carlo samples
            (None without samples).
        shares: ``{"rms" | "max" | "min_tension": {source: fraction}}``.
        sensitivities: per column, ``rms_distance`` (the rms over the rows of
            the distances' change, mm per unit), ``max_distance`` (the change
            of the nominal's largest distance, outward positive, mm per unit)
            and ``min_tension`` (of the nominal's least cell tension, N/m per
            unit), with the column's ``unit``.
        budget: None without a spec, else the spec (mm), each source's
            largest tolerance that alone keeps 95% of wings within it, and
            the common scale factor of all (`_budget`).
        samples: one dict per Monte Carlo sample (the CSV's rows).
        failures: ``[{"sample", "bay", "message"}]`` of the samples whose
            solve failed.
        rms_squared_mean: the linear model's exact ``E[rms^2]``, mm^2.
        timings: ``tolerance`` (first order) and ``samples`` seconds.
        samples_file: where the command streamed the samples' rows (a
            temporary CSV file), or None.
        linear_rms: the linearised model's draws of the wing's rms, mm.
    """

    tolerances: dict
    columns: list
    sources: list
    units: list
    nominal: np.ndarray
    std: np.ndarray
    distances: list
    tensions: list
    distance_jacobians: list
    tension_jacobians: list
    linear: dict
    shares: dict
    rms_squared_mean: float
    sensitivities: dict
    sampled: dict | None = None
    budget: dict | None = None
    samples: list = field(default_factory=list)
    failures: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    samples_file: str | None = None
    linear_rms: np.ndarray | None = None

    def summary(self) -> dict:
        """The ``tolerance`` section of ``summary.json`` (plain JSON values)."""
        return {
            "inputs": {name: {"value": t.value, "relative": t.relative, "uniform": t.uniform, "text": t.text,
                              "unit": "%" if t.relative else SOURCE_UNITS[name]}
                       for name, t in self.tolerances.items()},
            "units": {"distance": "mm", "tension": "N/m"},
            "parameters": [{"name": c, "source": s, "unit": u, "nominal": float(v), "std": float(d)}
                           for c, s, u, v, d in zip(self.columns, self.sources, self.units, self.nominal, self.std)],
            "sensitivities": self.sensitivities,
            "shares": self.shares,
            "linear": self.linear,
            "sampled": self.sampled,
            "rms_squared_mean": self.rms_squared_mean,
            "budget": self.budget,
            "samples": len(self.samples),
            "failed_samples": self.failures,
        }


# ------------------------------------------------------------------ first order
def _bay_jacobian(model: _Model, k: int, start, rtol: float):
    """Bay ``k``'s outputs (`_Model.outputs`) and their Jacobian in its touching columns (forward mode:
    one solve warm from ``start``, then one back-solve per column with the kept factor)."""
    cols = model.touching[k]
    e0 = jnp.zeros(model.size, jnp.float64)

    def outputs(e):
        p = model.bay_parameters(k, e)
        sol = solve_equilibrium(model.scenes[k], p, rtol=rtol, method="auto", initial=start, throw=True)
        return model.outputs(k, sol.nodes, p)

    basis = np.zeros((cols.size, model.size))
    basis[np.arange(cols.size), cols] = 1.0
    if cols.size == 0:
        return np.asarray(outputs(e0)), np.zeros((0, 0))
    with forward_only(cols.size):
        y, dy = jax.vmap(lambda t: jax.jvp(outputs, (e0,), (t,)), out_axes=(None, 0))(basis)
    jac = np.zeros((np.size(y), model.size))
    jac[:, cols] = np.asarray(dy).T
    return np.asarray(y), jac


def _nominal_solutions(model: _Model, rtol: float) -> list:
    """Each bay's equilibrium at the design with a Newton factor: the design's own solution where it
    holds the current factor at that tolerance (the design's last solve), else solved again warm from
    the design's nodes."""
    out = []
    for k in range(model.n_bays):
        kept = model.design_solutions[k]
        factor = None if kept is None else kept.factor
        if factor is not None and factor.current and kept.converged and float(kept.residual) <= rtol:
            out.append(kept)
            continue
        start = model.design_nodes[k]
        out.append(solve_equilibrium(model.scenes[k], model.nominal[k], rtol=rtol, method="newton",
                                     initial=start if np.all(np.isfinite(start)) else None, throw=True))
    return out


def _shares(model: _Model, at_max: np.ndarray, at_min: np.ndarray, q_diag: np.ndarray) -> dict:
    """Each source's share of the mean-square increase (rms), of the largest distance's and of the least
    tension's linearised variance (``at_max``, ``at_min``: their Jacobian rows at the nominal's largest
    point and least cell)."""
    var = model.std**2
    out = {}
    for key, parts in (("rms", q_diag * var), ("max", at_max**2 * var), ("min_tension", at_min**2 * var)):
        total = float(parts.sum())
        out[key] = {s: (float(sum(parts[i] for i, c in enumerate(model.columns) if c.source == s)) / total
                        if total > 0 else 0.0) for s in model.tolerances}
    return out


def _below(p95, target: float, low: float, high: float) -> float:
    """The largest scale in ``[low, high]`` found by bisection to 1e-15 of ``high`` whose ``p95`` meets
    ``target`` (``p95(low)`` does): a root that rounding put a hair above the spec steps back."""
    while high - low > 1e-15 * high:
        mid = 0.5 * (low + high)
        low, high = (mid, high) if p95(mid) <= target else (low, mid)
    return low


def _budget(model: _Model, spec: float, a: float, b: np.ndarray, q: np.ndarray, draws: np.ndarray) -> dict:
    """The tolerances that keep 95% of wings within ``spec`` (mm rms) by the linearised mean square
    ``a + b.e + e^T Q e``, over the fixed ``draws`` (unit spreads): each source alone (the largest
    multiple of its given tolerance, others exact) and all together (one common factor)."""

    def largest_scale(mask: np.ndarray) -> float | None:
        on = np.flatnonzero(mask)  # (the columns scaled; the others are exact)
        v = draws[:, on] * model.spread[on][None, :]
        lin, quad = v @ b[on], np.einsum("mi,ij,mj->m", v, q[np.ix_(on, on)], v)

        def p95(scale):
            return _p95(a + scale * lin + scale**2 * quad)

        target = spec**2
        if a > target:
            return 0.0
        grid = np.geomspace(1e-4, BUDGET_SCALE_CAP, 97)
        if p95(grid[-1]) <= target:
            return None
        # the first grid scale that breaks the spec, by bisection over the grid (the 95th percentile
        # grows with the scale: at small scales as its linear term's 95th percentile, beyond as the
        # quadratic's), then the crossing inside that grid step
        first, last = 0, grid.size - 1
        while first < last:
            middle = (first + last) // 2
            first, last = (middle + 1, last) if p95(grid[middle]) <= target else (first, middle)
        low, high = (grid[first - 1] if first else 0.0), grid[first]
        # the crossing in the grid step that brackets it (Brent's method: a few evaluations where
        # bisection to the same 1e-12 of the scale took 40); the scale returned meets the spec
        crossing = brentq(lambda s: p95(s) - target, low, high, xtol=1e-12 * high, rtol=1e-12)
        return crossing if p95(crossing) <= target else _below(p95, target, low, crossing)

    sources = {}
    for s, t in model.tolerances.items():
        mask = np.array([c.source == s for c in model.columns], np.float64)
        scale = largest_scale(mask)
        if scale is not None and s.startswith("stiffness"):  # a scatter of the whole stiffness is no budget
            nominal = min(v for c, v in zip(model.columns, model.nominal_values) if c.source == s)
            if t.scaled(scale).spread(nominal) >= nominal:
                scale = None
        sources[s] = {"scale": scale, "value": None if scale is None else t.value * scale,
                      "text": None if scale is None else t.scaled(scale).text,
                      "unit": "%" if t.relative else SOURCE_UNITS[s], "given": t.text}
    common = largest_scale(np.ones(model.size))
    return {"spec": spec, "nominal_rms": math.sqrt(max(a, 0.0)), "met_at_nominal": bool(a <= spec**2),
            "sources": sources, "common_scale": common,
            "common": None if common is None else {s: t.scaled(common).text for s, t in model.tolerances.items()},
            "meets_given": None if common is None else bool(common >= 1.0)}


def tolerance_analysis(result, tolerances, *, spec: float | None = None, samples: int = 0, seed: int = 0,
                       rtol: float = GRADIENT_RTOL, sample_rtol: float = SAMPLE_RTOL,
                       linear_samples: int = LINEAR_SAMPLES, on_sample=None, scheduler=None) -> ToleranceAnalysis:
    """First-order tolerance analysis of a design, and optionally its Monte Carlo check (module docstring).

    Args:
        result: a `DesignResult` (`optimise_pressure`, `optimise_wing`, `evaluate_design`).
        tolerances: ``{name: Tolerance}`` or anything `parse_tolerances` takes
            (``{"pressure": "2%", "cut_span": 0.5}``, ``["defaults"]``).
        spec: the shape specification, mm: 95% of wings within this
            area-weighted rms distance; gives the budget. None: no budget.
        samples: Monte Carlo wings to solve (0: first order only).
        seed: the Monte Carlo draws' seed (the same seed draws the same wings).
        rtol: relative residual of the nominal solve behind the Jacobian (the
            implicit derivative is only as good as the equilibrium).
        sample_rtol: relative residual of every Monte Carlo solve (`SAMPLE_RTOL`).
        linear_samples: draws of the linearised model.
        on_sample: called with each sample's row (a dict: ``sample``, the
            drawn absolute value of every column, ``rms``, ``max``,
            ``min_tension``, ``converged``) as it is solved, in sample order.
        scheduler: where the Monte Carlo wings are solved: None (this
            process), a Dask scheduler's address (``"tcp://host:8786"``) or a
            ``distributed.Client`` (`connect_scheduler`; the ``dask`` extra).
            The same seed gives the same numbers either way.

    Returns:
        A `ToleranceAnalysis`.

    Raises:
        ValueError: for bad tolerances, a negative ``samples``, a spec of 0 or
            less, a stiffness scatter reaching the nominal stiffness, or a
            scheduler that cannot be reached.
        ImportError: for a scheduler without ``distributed`` installed.
        forward_solver.ConvergenceError: if the nominal design does not solve.
    """
    if not isinstance(samples, int) or isinstance(samples, bool) or samples < 0:
        raise ValueError(f"samples must be a whole number, 0 or more, got {samples!r}")
    if spec is not None and not (math.isfinite(spec) and spec > 0):
        raise ValueError(f"the shape spec is an rms distance in mm and must be positive, got {spec!r}")
    tolerances = _as_tolerances(tolerances)
    start = time.perf_counter()
    with jax.enable_x64(True):
        model = _Model(result, tolerances)
        for c, v, spread in zip(model.columns, model.nominal_values, model.spread):
            if c.source.startswith("stiffness") and spread >= v:
                raise ValueError(f"tolerance {c.source}={model.tolerances[c.source].text}: a stiffness scatter of "
                                 f"{spread:g} N/m reaches the nominal {v:g} N/m (100% or more); give less")
        nominal = _nominal_solutions(model, rtol)
        d0, t0, jd, jt = [], [], [], []
        nd = model.n_distances
        for k in range(model.n_bays):
            y, jac = _bay_jacobian(model, k, nominal[k], rtol)
            d0.append(y[:nd]), t0.append(y[nd:]), jd.append(jac[:nd]), jt.append(jac[nd:])
    # the wing's mean square as a quadratic in e: a + b.e + e^T Q e (each bay on its own columns)
    size = model.size
    a, b, q = 0.0, np.zeros(size), np.zeros((size, size))
    for w, d, j, cols in zip(model.weights, d0, jd, model.touching):
        jc = j[:, cols]
        a += w * float(d @ d) / d.size
        b[cols] += w * 2.0 * (jc.T @ d) / d.size
        q[np.ix_(cols, cols)] += w * (jc.T @ jc) / d.size
    rng = np.random.default_rng([seed, 1])  # the linear model's stream, apart from the samples'
    draws = _unit_draws(model, rng, linear_samples)
    linear_measures = _linear_measures(model, d0, t0, jd, jt, draws)
    linear = _summary_of(linear_measures)
    cov = model.std**2
    rms_squared_mean = float(a + np.sum(np.diag(q) * cov))
    # the nominal's largest distance and least tension: their bay and row
    far = max(range(model.n_bays), key=lambda k: np.max(np.abs(d0[k])))
    at_max = jd[far][int(np.argmax(np.abs(d0[far])))] * np.sign(d0[far][int(np.argmax(np.abs(d0[far])))])
    low = min(range(model.n_bays), key=lambda k: np.min(t0[k]))
    at_min = jt[low][int(np.argmin(t0[low]))]
    shares = _shares(model, at_max, at_min, np.diag(q))
    sensitivities = {c.name: {"unit": SOURCE_UNITS[c.source], "rms_distance": float(math.sqrt(max(q[i, i], 0.0))),
                              "max_distance": float(at_max[i]), "min_tension": float(at_min[i])}
                     for i, c in enumerate(model.columns)}
    budget = None if spec is None else _budget(model, float(spec), a, b, q, draws)
    analysis = ToleranceAnalysis(
        tolerances=model.tolerances, columns=[c.name for c in model.columns],
        sources=[c.source for c in model.columns], units=[SOURCE_UNITS[c.source] for c in model.columns],
        nominal=model.nominal_values, std=model.std, distances=d0, tensions=t0, distance_jacobians=jd,
        tension_jacobians=jt, linear=linear, shares=shares, rms_squared_mean=rms_squared_mean,
        sensitivities=sensitivities, budget=budget, timings={"tolerance": time.perf_counter() - start},
        linear_rms=linear_measures["rms"])
    if samples:
        t = time.perf_counter()
        _monte_carlo(model, analysis, nominal, samples, seed, sample_rtol, on_sample, scheduler, rtol)
        analysis.timings["samples"] = time.perf_counter() - t
    return analysis


def _reach(model: _Model, jac: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """How far each row of ``jac @ e`` (``jac`` on the columns ``cols``) can go over the draws: 6
    standard deviations of the normal columns plus the whole reach of the uniform ones."""
    uniform, std, spread = model.uniform[cols], model.std[cols], model.spread[cols]
    normal = np.sqrt(((jac * np.where(uniform, 0.0, std)[None, :]) ** 2).sum(axis=1))
    uniform = (np.abs(jac) * np.where(uniform, spread, 0.0)[None, :]).sum(axis=1)
    return 6.0 * normal + uniform


def _linear_measures(model: _Model, d0, t0, jd, jt, draws: np.ndarray) -> dict:
    """`_measures` of the linearised model at ``draws`` (unit spreads). Each bay's mean square is its
    quadratic form in the deviations (exact); the largest distance and the least tension look only at
    the points and cells that can be the extreme (`_reach`: a row whose best case cannot reach the
    others' worst is never the extreme; `_least`), so a 17x64 bay's 3000 rows become a few dozen or
    hundred."""
    e = draws * model.spread[None, :]
    ms, largest, least = [], [], []
    for d, j, t, k, cols in zip(d0, jd, t0, jt, model.touching):
        n, ec, j, k = d.size, e[:, cols], j[:, cols], k[:, cols]  # (a bay's own columns)
        b, q = 2.0 * (j.T @ d) / n, (j.T @ j) / n
        ms.append(float(d @ d) / n + ec @ b + np.einsum("mi,ij,mj->m", ec, q, ec))
        reach = _reach(model, j, cols)
        keep = np.abs(d) + reach >= np.max(np.abs(d) - reach)
        largest.append(np.max(np.abs(d[keep][None, :] + ec @ j[keep].T), axis=1))
        least.append(_least(t, k, ec, _reach(model, k, cols)))
    ms, largest, least = (np.stack(x, axis=1) for x in (ms, largest, least))
    return {"bay_rms": np.sqrt(np.maximum(ms, 0.0)), "bay_max": largest, "bay_min_tension": least,
            "rms": np.sqrt(np.maximum(ms @ model.weights, 0.0)), "max": largest.max(axis=1),
            "min_tension": least.min(axis=1)}


def _least(t: np.ndarray, k: np.ndarray, ec: np.ndarray, reach: np.ndarray, block: int = 64) -> np.ndarray:
    """``min(t + ec @ k.T, axis=1)``: each draw's least row. The rows are visited in blocks by their
    lowest reach ``t - reach``, and the visit stops once no row left can go below every draw's least so
    far (on a bay whose tensions are near-uniform most of its cells can reach the floor, but few do)."""
    low = t - reach
    order = np.argsort(low, kind="stable")
    bound = np.min(t + reach)  # (no draw's least lies above it)
    least = np.full(ec.shape[0], np.inf)
    for start in range(0, order.size, block):
        if low[order[start]] > min(bound, float(least.max())):
            break
        rows = order[start:start + block]
        least = np.minimum(least, np.min(t[rows][None, :] + ec @ k[rows].T, axis=1))
    return least


def _p95(values: np.ndarray) -> float:
    """``np.percentile(values, 95)`` (its linear interpolation) by partition: O(n), not a sort."""
    n = values.size
    h = 0.95 * (n - 1)
    low = int(math.floor(h))
    high = min(low + 1, n - 1)
    part = np.partition(values, (low, high))
    return float(part[low] + (h - low) * (part[high] - part[low]))


# ------------------------------------------------------------------ Monte Carlo
def _solve_wing(model: _Model, e: np.ndarray, starts, rtol: float) -> tuple:
    """Every bay at the deviations ``e``: ``(distances, tensions, failures)`` (NaN where a bay failed;
    failures ``[(bay, message)]``)."""
    distances, tensions, failures = [], [], []
    with jax.enable_x64(True):
        for k in range(model.n_bays):
            p = model.bay_parameters(k, e)
            try:
                sol = solve_equilibrium(model.scenes[k], p, rtol=rtol, method="auto",
                                        initial=None if starts is None else starts[k], throw=False)
                ok = sol.converged
                message = "" if ok else sol.message
            except ValueError as exc:  # a drawn value outside the physical range (e.g. a negative stiffness)
                ok, message = False, str(exc)
            if ok:
                y = np.asarray(model.outputs(k, jnp.asarray(sol.nodes), p))
            else:
                y = np.full(model.n_distances + model.scenes[k].bay.n_contour * 2 * (model.scenes[k].bay.n_span - 1),
                            np.nan)
                failures.append((k, message))
            distances.append(y[:model.n_distances])
            tensions.append(y[model.n_distances:])
    return distances, tensions, failures


def _row(model: _Model, index: int, e: np.ndarray, measured: dict, converged: bool) -> dict:
    row = {"sample": index}
    row.update({c.name: float(v + d) for c, v, d in zip(model.columns, model.nominal_values, e)})
    row.update(rms=float(measured["rms"][0]), max=float(measured["max"][0]),
               min_tension=float(measured["min_tension"][0]), converged=bool(converged))
    return row


def _monte_carlo(model: _Model, analysis: ToleranceAnalysis, nominal, count: int, seed: int, rtol: float,
                 on_sample, scheduler, nominal_rtol: float) -> None:
    rng = np.random.default_rng([seed, 0])
    draws = _unit_draws(model, rng, count) * model.spread[None, :]
    rows, failures, measures = [], [], []
    solved = ((_solve_wing(model, e, nominal, rtol) for e in draws) if scheduler is None
              else _solve_on_cluster(model, draws, rtol, nominal_rtol, scheduler))
    for m, (d, t, failed) in enumerate(solved):
        measured = _measures(model, [x[None] for x in d], [x[None] for x in t])
        measures.append(measured)
        row = _row(model, m, draws[m], measured, not failed)
        rows.append(row)
        failures += [{"sample": m, "bay": k, "message": msg} for k, msg in failed]
        if on_sample is not None:
            on_sample(row)
    analysis.samples = rows
    analysis.failures = failures
    sampled = _summary_of({key: np.concatenate([m[key] for m in measures]) for key in measures[0]})
    sampled.update(count=count, failed=len({f["sample"] for f in failures}))
    analysis.sampled = sampled


#: Seconds `connect_scheduler` waits for a Dask scheduler to answer.
SCHEDULER_TIMEOUT_S = 10.0


def connect_scheduler(address: str, timeout: float | None = None):
    """A ``distributed.Client`` of the Dask scheduler at ``address`` (``"tcp://host:8786"``).

    Raises:
        ImportError: without the ``distributed`` package (the ``dask`` extra).
        ValueError: if no scheduler answers there within ``timeout`` seconds
            (default `SCHEDULER_TIMEOUT_S`).
    """
    try:
        from distributed import Client
    except ImportError:
        raise ImportError("a Dask scheduler needs the distributed package: "
                          "pip install 'inflatable-wing[dask]'") from None
    wait = SCHEDULER_TIMEOUT_S if timeout is None else timeout
    try:
        return Client(address, timeout=wait)
    except (OSError, TimeoutError, ValueError) as exc:  # (refused, no answer in time, a malformed address)
        raise ValueError(f"no Dask scheduler answered at {address} within {wait:g} s ({exc}): start one "
                         f"(dask scheduler) or give its address") from None


def _solve_chunk(model: _Model, draws: np.ndarray, rtol: float, nominal_rtol: float) -> list:
    """A Dask worker's chunk of samples: `_solve_wing` of each, warm from the nominal equilibrium that the
    worker solves once (the same solve as `tolerance_analysis`'s, so the samples are the same)."""
    with jax.enable_x64(True):
        if getattr(model, "worker_nominal", None) is None:
            model.worker_nominal = _nominal_solutions(model, nominal_rtol)
    return [_solve_wing(model, e, model.worker_nominal, rtol) for e in draws]


def _solve_on_cluster(model: _Model, draws: np.ndarray, rtol: float, nominal_rtol: float, scheduler):
    """`_solve_wing` of every draw on a Dask cluster, yielded in sample order as the chunks come back
    (four chunks per worker thread: a slow chunk holds up few samples)."""
    from distributed import Client

    client = scheduler if isinstance(scheduler, Client) else connect_scheduler(scheduler)
    try:
        threads = max(sum(client.nthreads().values()), 1)
        shared = client.scatter(model, broadcast=True)  # (once per worker, not once per chunk)
        futures = [client.submit(_solve_chunk, shared, chunk, rtol, nominal_rtol, pure=False)
                   for chunk in np.array_split(draws, min(len(draws), 4 * threads))]
        for future in futures:
            yield from future.result()
            future.release()
    finally:
        if client is not scheduler:
            client.close()


def wing_outputs(result, tolerances, deviations, *, rtol: float = SAMPLE_RTOL) -> tuple[list, list]:
    """The wing at ``deviations`` (``(size,)``, in the units of `ToleranceAnalysis.columns`), every bay
    solved cold: per bay its normal distances (mm, the objective's rows) and cell tensions (N/m), NaN
    where a bay failed. The map of the first-order analysis, for checks (central differences)."""
    with jax.enable_x64(True):
        model = _Model(result, _as_tolerances(tolerances))
    d, t, _ = _solve_wing(model, np.asarray(deviations, np.float64), None, rtol)
    return d, t


def solve_sample(result, tolerances, values: dict, *, rtol: float = SAMPLE_RTOL) -> dict:
    """One wing solved alone (cold, from its mounted shape) at drawn absolute ``values`` (a CSV row's
    columns: ``{"pressure": Pa, "stiffness_span_bay_0": N/m, ...}``; columns not given stay nominal).

    Returns:
        ``{"rms", "max", "min_tension", "converged"}`` as the sample's CSV row.
    """
    with jax.enable_x64(True):
        model = _Model(result, _as_tolerances(tolerances))
    e = np.array([float(values.get(c.name, v)) - v for c, v in zip(model.columns, model.nominal_values)])
    d, t, failed = _solve_wing(model, e, None, rtol)
    measured = _measures(model, [x[None] for x in d], [x[None] for x in t])
    return {key: float(measured[key][0]) for key in ("rms", "max", "min_tension")} | {"converged": not failed}
