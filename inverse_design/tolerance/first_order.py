"""The first-order tolerance analysis of a design (`tolerance_analysis`) and its budget.

First order: per bay (`model.ToleranceModel.bay_jacobian`), the implicit derivative of the
equilibrium in forward mode (the design's own equilibrium and LU factor where the design kept
them (its last solve), else one Newton solve warm from the design, then one back-solve per
parameter touching that bay with that factor) gives ``J``, the Jacobian of every normal
distance of the objective's rows (mm) and of every cell's fibre tension (N/m) in the tolerance
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

Wrinkling onset makes the least tension non-smooth: where a cell's tension
crosses zero within the scatter the linear prediction of the least tension
stops holding (compare it with the samples).
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import jax
import numpy as np
from scipy.optimize import brentq

from forward_solver.derivatives.custom_jvp import GRADIENT_RTOL
from forward_solver.solvers.threads import each

from ..fabric_range import FabricRangeWarning, outside_tested_range
from .inputs import SOURCE_UNITS, as_tolerances
from .model import ToleranceModel, summary_of
from .monte_carlo import SAMPLE_RTOL, check_samples, monte_carlo

__all__ = ["BUDGET_SCALE_CAP", "LINEAR_SAMPLES", "Sampling", "ToleranceAnalysis", "tolerance_analysis"]

#: Draws of the linearised model behind its distributions and the budget (a fixed stream: the same
#: numbers every run; the p95 of 4000 draws is within about 1% of the distribution's).
LINEAR_SAMPLES = 4000
#: The largest common or single-source scale of the tolerances the budget searches.
BUDGET_SCALE_CAP = 1e3


@dataclass(frozen=True)
class Sampling:
    """How a tolerance analysis samples: the linearised model's draws and the Monte Carlo check.

    Args:
        samples: Monte Carlo wings to solve (0: first order only).
        seed: the draws' seed (the same seed draws the same wings and the same linear draws).
        rtol: relative residual of every Monte Carlo solve (`monte_carlo.SAMPLE_RTOL`).
        scheduler: where the Monte Carlo wings are solved: None (this
            process), a Dask scheduler's address (``"tcp://host:8786"``) or a
            ``distributed.Client`` (`monte_carlo.connect_scheduler`; the ``dask`` extra).
            The same seed gives the same numbers either way.
        on_sample: called with each sample's row (a dict: ``sample``, the
            drawn absolute value of every column, ``rms``, ``max``,
            ``min_tension``, ``converged``) as it is solved, in sample order.
        linear_samples: draws of the linearised model (`LINEAR_SAMPLES`).
        keep_rows: keep every sample's row in `ToleranceAnalysis.samples`
            (`inverse_design.memory.ROW_BYTES` a row); False: the rows only go to
            ``on_sample`` (the command streams them to a file) and the analysis keeps
            each sample's few measures (`monte_carlo`'s module docstring).

    Raises:
        ValueError: for a negative number of samples (`tolerance_analysis` refuses, before any
            solve, a number whose kept state exceeds the machine's memory:
            `monte_carlo.check_samples`).
    """

    samples: int = 0
    seed: int = 0
    rtol: float = SAMPLE_RTOL
    scheduler: object = None
    on_sample: object = field(default=None, compare=False)
    linear_samples: int = LINEAR_SAMPLES
    keep_rows: bool = True

    def __post_init__(self):
        if not isinstance(self.samples, int) or isinstance(self.samples, bool) or self.samples < 0:
            raise ValueError(f"samples must be a whole number, 0 or more, got {self.samples!r}")


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
        samples: one dict per Monte Carlo sample (the CSV's rows; empty
            unless `Sampling`'s ``keep_rows``).
        failures: ``[{"sample", "bay", "message"}]`` of the samples whose
            solve failed (the first `monte_carlo.FAILURES_KEPT`; ``sampled``
            counts them all).
        rms_squared_mean: the linear model's exact ``E[rms^2]``, mm^2.
        timings: ``tolerance`` (first order) and ``samples`` seconds.
        samples_file: where the command streamed the samples' rows (a
            temporary CSV file), or None.
        linear_rms: the linearised model's draws of the wing's rms, mm.
        sampled_rms: each Monte Carlo sample's wing rms, mm (NaN where its
            solve failed), or None without samples.
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
    sampled_rms: np.ndarray | None = None

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
            "samples": 0 if self.sampled is None else self.sampled["count"],
            "failed_samples": self.failures,
        }


def _shares(model: ToleranceModel, at_max: np.ndarray, at_min: np.ndarray, q_diag: np.ndarray) -> dict:
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


def _budget(model: ToleranceModel, spec: float, a: float, b: np.ndarray, q: np.ndarray, draws: np.ndarray) -> dict:
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


def tolerance_analysis(result, tolerances, *, spec: float | None = None, sampling: Sampling = Sampling(),
                       rtol: float = GRADIENT_RTOL) -> ToleranceAnalysis:
    """First-order tolerance analysis of a design, and optionally its Monte Carlo check (module docstring).

    Args:
        result: a `DesignResult` (`optimise_pressure`, `optimise_wing`, `evaluate_design`).
        tolerances: ``{name: Tolerance}`` or anything `parse_tolerances` takes
            (``{"pressure": "2%", "cut_span": 0.5}``, ``["defaults"]``).
        spec: the shape specification, mm: 95% of wings within this
            area-weighted rms distance; gives the budget. None: no budget.
        sampling: the draws of the linearised model and the Monte Carlo check (`Sampling`; default
            first order only).
        rtol: relative residual of the nominal solve behind the Jacobian (the
            implicit derivative is only as good as the equilibrium).

    Returns:
        A `ToleranceAnalysis`.

    Raises:
        ValueError: for bad tolerances, a spec of 0 or less, a stiffness
            scatter reaching the nominal stiffness, more samples than the
            machine's memory holds (`monte_carlo.check_samples`), or a scheduler
            that cannot be reached.
        ImportError: for a scheduler without ``distributed`` installed.
        forward_solver.ConvergenceError: if the nominal design does not solve.
    """
    if spec is not None and not (math.isfinite(spec) and spec > 0):
        raise ValueError(f"the shape spec is an rms distance in mm and must be positive, got {spec!r}")
    tolerances = as_tolerances(tolerances)
    start = time.perf_counter()
    with jax.enable_x64(True):
        model = ToleranceModel.of(result, tolerances)
        for c, v, spread in zip(model.columns, model.nominal_values, model.spread):
            if c.source.startswith("stiffness") and spread >= v:
                raise ValueError(f"tolerance {c.source}={model.tolerances[c.source].text}: a stiffness scatter of "
                                 f"{spread:g} N/m reaches the nominal {v:g} N/m (100% or more); give less")
        check_samples(sampling.samples, model, sampling.keep_rows)  # (before any solve)
        nominal = model.nominal_solutions(rtol)

        def jacobian(k):  # (a bay whole on one thread: the same numbers on either)
            with jax.enable_x64(True):  # (a thread's own setting: the helper's too)
                return model.bay_jacobian(k, nominal[k], rtol)

        d0, t0, jd, jt = [], [], [], []
        nd = model.n_distances
        for y, jac in each(jacobian, model.n_bays):  # two bays at a time: their solves and LU back-solves
            d0.append(y[:nd]), t0.append(y[nd:]), jd.append(jac[:nd]), jt.append(jac[nd:])
    # the wing's mean square as a quadratic in e: a + b.e + e^T Q e (each bay on its own columns)
    size = model.size
    a, b, q = 0.0, np.zeros(size), np.zeros((size, size))
    for w, d, j, cols in zip(model.weights, d0, jd, model.touching):
        jc = j[:, cols]
        a += w * float(d @ d) / d.size
        b[cols] += w * 2.0 * (jc.T @ d) / d.size
        q[np.ix_(cols, cols)] += w * (jc.T @ jc) / d.size
    rng = np.random.default_rng([sampling.seed, 1])  # the linear model's stream, apart from the samples'
    draws = model.unit_draws(rng, sampling.linear_samples)
    linear_measures = _linear_measures(model, d0, t0, jd, jt, draws)
    linear = summary_of(linear_measures)
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
    if sampling.samples:
        t = time.perf_counter()
        analysis.samples, analysis.failures, analysis.sampled, analysis.sampled_rms = monte_carlo(
            model, nominal, sampling, rtol)
        analysis.timings["samples"] = time.perf_counter() - t
        if "fibre_strains" in analysis.sampled:
            line = outside_tested_range(model.scenes[0].fabric, analysis.sampled["fibre_strains"],
                                        "the Monte Carlo samples")
            if line is not None:
                warnings.warn(line, FabricRangeWarning, stacklevel=2)
    return analysis


def _reach(model: ToleranceModel, jac: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """How far each row of ``jac @ e`` (``jac`` on the columns ``cols``) can go over the draws: 6
    standard deviations of the normal columns plus the whole reach of the uniform ones."""
    uniform, std, spread = model.uniform[cols], model.std[cols], model.spread[cols]
    normal = np.sqrt(((jac * np.where(uniform, 0.0, std)[None, :]) ** 2).sum(axis=1))
    uniform = (np.abs(jac) * np.where(uniform, spread, 0.0)[None, :]).sum(axis=1)
    return 6.0 * normal + uniform


def _linear_measures(model: ToleranceModel, d0, t0, jd, jt, draws: np.ndarray) -> dict:
    """`ToleranceModel.measures` of the linearised model at ``draws`` (unit spreads). Each bay's mean square is its
    quadratic form in the deviations (exact); the largest distance and the least tension look only at
    the points and cells that can be the extreme (`_reach`: a row whose best case cannot reach the
    others' worst is never the extreme; `_least`), so a 17x64 bay's 3000 rows become a few dozen or
    hundred."""
    e = draws * model.spread[None, :]

    def bay(i):  # (the bays two at a time where there is a second core: NumPy's products release Python's lock)
        d, t, cols = d0[i], t0[i], model.touching[i]
        n, ec, j, k = d.size, e[:, cols], jd[i][:, cols], jt[i][:, cols]  # (a bay's own columns)
        b, q = 2.0 * (j.T @ d) / n, (j.T @ j) / n
        ms = float(d @ d) / n + ec @ b + np.einsum("mi,ij,mj->m", ec, q, ec)
        reach = _reach(model, j, cols)
        keep = np.abs(d) + reach >= np.max(np.abs(d) - reach)
        largest = np.max(np.abs(d[keep][None, :] + ec @ j[keep].T), axis=1)
        return ms, largest, _least(t, k, ec, _reach(model, k, cols))

    ms, largest, least = (np.stack(x, axis=1) for x in zip(*each(bay, len(d0))))
    return {"bay_rms": np.sqrt(np.maximum(ms, 0.0)), "bay_max": largest, "bay_min_tension": least,
            "rms": np.sqrt(np.maximum(ms @ model.weights, 0.0)), "max": largest.max(axis=1),
            "min_tension": least.min(axis=1)}


def _least(t: np.ndarray, k: np.ndarray, ec: np.ndarray, reach: np.ndarray, block: int = 512) -> np.ndarray:
    """``min(t + ec @ k.T, axis=1)``: each draw's least row. The rows are visited in blocks by their
    lowest reach ``t - reach``, and the visit stops once no row left can go below every draw's least so
    far (on a bay whose tensions are near-uniform most of its cells can reach the floor, but few do).
    Blocks of 512 rows: on the 40-cell wing (4000 draws, 2048 cells a bay, every cell within reach of
    the floor) the 40 bays took 2.6 s in blocks of 64 rows, 1.0 s in 512, 0.9 s in one product, the
    same numbers to the bit."""
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
