"""The Monte Carlo check of a tolerance analysis: wings drawn from the stated distributions, solved.

Monte Carlo (`first_order.Sampling`'s ``samples``): draws wings from the stated distributions and
solves each bay warm from the nominal equilibrium moved by its first-order change
(`model.ToleranceModel.predicted_start`: chord Newton with the nominal's kept factor, the
fallbacks of `forward_solver.solvers.chain` where not) to
`SAMPLE_RTOL`, in this process, or on a Dask cluster (its ``scheduler``: the
samples in chunks, each worker making the nominal factor once by the same
solve as here, so the same seed gives the same numbers). A sample whose solve
fails is counted and named, never dropped.

The samples stream: they are drawn and solved `CHUNK` at a time (`sample_draws`), each
sample's row goes to ``on_sample`` as it is solved, and what stays is what the statistics
need, each sample's measures (a few floats: `inverse_design.memory.sample_memory`), the rows
only where ``keep_rows`` asks, and the first `FAILURES_KEPT` failures named (all counted).
`check_samples` refuses, before any solve, a count whose kept state cannot fit in the
machine's memory. The draws are the same numbers for the same seed whatever the chunks: one
generator draws the normal deviates of every sample in turn and a second, started where the
first ends (past ``samples x columns`` normal deviates), the uniform ones, which is the stream of
`model.ToleranceModel.unit_draws` drawing all samples at once (normal, then uniform).
"""

from __future__ import annotations

import math
from collections import deque

import jax
import jax.numpy as jnp
import numpy as np

from forward_solver import solve_equilibrium

from ..fabric_range import bay_strains
from ..memory import physical_memory, release_free_memory, sample_memory
from .model import ToleranceModel, summary_of

__all__ = ["CHUNK", "CLUSTER_CHUNK", "FAILURES_KEPT", "SAMPLE_RTOL", "SCHEDULER_TIMEOUT_S", "check_samples",
           "connect_scheduler", "monte_carlo", "sample_draws", "solve_wing"]

#: Relative residual of a Monte Carlo wing's solves (the residual force 1e-8 of the pressure load: the
#: command's equilibrium tolerance; its error in the distances is far below their scatter).
SAMPLE_RTOL = 1e-8
#: Samples drawn at a time in this process (the draws held at once: 3 arrays of this many samples' columns).
CHUNK = 256
#: Most samples of a chunk sent to a Dask worker (four chunks per worker thread while the samples last).
CLUSTER_CHUNK = 256
#: Failed samples named in ``failures`` (sample, bay, message); beyond them failures are only counted.
FAILURES_KEPT = 1000
#: Normal deviates drawn at a time to skip the normal stream before the uniform one (`sample_draws`).
_SKIP_BLOCK = 1 << 20


def check_samples(samples: int, model: ToleranceModel, keep_rows: bool, physical: int | None = None) -> int:
    """Refuse a Monte Carlo check whose kept state (`inverse_design.memory.sample_memory`) exceeds the
    machine's memory; returns that estimate, bytes.

    Args:
        samples: Monte Carlo wings (`first_order.Sampling`'s ``samples``).
        model: the design's tolerance model (its bays and columns).
        keep_rows: whether the rows are kept (`first_order.Sampling`'s ``keep_rows``).
        physical: the machine's memory, bytes (default `inverse_design.memory.physical_memory`; None where
            unknown: nothing is refused).

    Raises:
        ValueError: naming ``Sampling.samples``, the estimate, the memory and what to change.
    """
    need = sample_memory(samples, model.n_bays, model.size, keep_rows)
    physical = physical_memory() if physical is None else physical
    if physical is not None and need > physical:
        rows = f" and its row of {model.size} drawn values" if keep_rows else ""
        fits = physical // max(sample_memory(1, model.n_bays, model.size, keep_rows), 1)
        raise ValueError(f"Sampling.samples={samples:,}: the Monte Carlo check would keep about "
                         f"{need / 2**30:,.1f} GiB (each sample's measures{rows}), more than this machine's "
                         f"{physical / 2**30:.1f} GiB of memory; give at most {fits:,} samples"
                         f"{'' if not keep_rows else ', or keep_rows=False to stream the rows to on_sample'}")
    return need


def sample_draws(model: ToleranceModel, seed: int, samples: int, chunk: int = CHUNK):
    """The deviations of ``samples`` Monte Carlo wings (the sources' units), ``chunk`` at a time.

    Yields:
        ``(first, e)``: ``e`` ``(n, size)`` the deviations of samples ``first`` to ``first + n - 1``:
        together, exactly ``model.unit_draws(np.random.default_rng([seed, 0]), samples) *
        model.spread`` (module docstring), whatever ``chunk``.
    """
    normal = np.random.default_rng([seed, 0])
    uniform = None
    if model.uniform.any():  # (without uniform columns the uniform deviates are drawn for nothing)
        uniform = np.random.default_rng([seed, 0])
        left = samples * model.size
        while left:  # (the normal deviates use a varying number of the generator's words: drawn to skip)
            n = min(left, _SKIP_BLOCK)
            uniform.standard_normal(n)
            left -= n
    for first in range(0, samples, chunk):
        n = min(chunk, samples - first)
        unit = normal.standard_normal((n, model.size))
        if uniform is not None:
            unit = np.where(model.uniform[None, :], uniform.uniform(-1.0, 1.0, (n, model.size)), unit)
        yield first, unit * model.spread[None, :]


def solve_wing(model: ToleranceModel, e: np.ndarray, starts, rtol: float, strains: list | None = None) -> tuple:
    """Every bay at the deviations ``e``: ``(distances, tensions, failures)`` (NaN where a bay failed;
    failures ``[(bay, message)]``); ``strains``: a list that gets each solved bay's fibre strain range
    (`inverse_design.fabric_range.bay_strains`), for a fabric with a fitted law."""
    distances, tensions, failures = [], [], []
    with jax.enable_x64(True):
        for k in range(model.n_bays):
            p = model.bay_parameters(k, e)
            try:
                sol = solve_equilibrium(model.scenes[k], p, rtol=rtol, method="auto",
                                        initial=None if starts is None else model.predicted_start(k, e, starts[k]),
                                        throw=False)
                ok = sol.converged
                message = "" if ok else sol.message
            except ValueError as exc:  # a drawn value outside the physical range (e.g. a negative stiffness)
                ok, message = False, str(exc)
            if ok:
                y = np.asarray(model.outputs(k, jnp.asarray(sol.nodes), p))
                if strains is not None:
                    strains.append(bay_strains(model.scenes[k], p, sol.nodes))
            else:
                y = np.full(model.n_distances + model.scenes[k].bay.n_contour * 2 * (model.scenes[k].bay.n_span - 1),
                            np.nan)
                failures.append((k, message))
            distances.append(y[:model.n_distances])
            tensions.append(y[model.n_distances:])
    return distances, tensions, failures


def _measured(model: ToleranceModel, e: np.ndarray, starts, rtol: float) -> tuple[dict, list]:
    """A sample's measures (`model.ToleranceModel.measures`, one float each) and failures (`solve_wing`);
    with a fitted law, ``strains`` too: the sample's ``((span least, largest), (chord least, largest))``."""
    if model.scenes[0].fabric.law is None:
        distances, tensions, failures = solve_wing(model, e, starts, rtol)
        strains = None
    else:
        strains = []
        distances, tensions, failures = solve_wing(model, e, starts, rtol, strains)
    measured = model.measures([x[None] for x in distances], [x[None] for x in tensions])
    measured = {key: value[0] for key, value in measured.items()}
    if strains:
        measured["strains"] = ((min(s[0][0] for s in strains), max(s[0][1] for s in strains)),
                               (min(s[1][0] for s in strains), max(s[1][1] for s in strains)))
    return measured, failures


def _row(model: ToleranceModel, index: int, e: np.ndarray, measured: dict, converged: bool) -> dict:
    row = {"sample": index}
    row.update({c.name: float(v + d) for c, v, d in zip(model.columns, model.nominal_values, e)})
    row.update(rms=float(measured["rms"]), max=float(measured["max"]), min_tension=float(measured["min_tension"]),
               converged=bool(converged))
    return row


def monte_carlo(model: ToleranceModel, nominal, sampling, nominal_rtol: float) -> tuple[list, list, dict, np.ndarray]:
    """The Monte Carlo wings of ``sampling`` (a `first_order.Sampling`), each solved warm from the
    ``nominal`` equilibria (``nominal_rtol``: their residual, which a Dask worker solves them to again),
    streamed (module docstring).

    Returns:
        ``(rows, failures, sampled, rms)``: one dict per sample where ``sampling.keep_rows`` (the CSV's
        rows, each also given to ``sampling.on_sample`` as it is solved, in sample order; else empty),
        ``[{"sample", "bay", "message"}]`` of the first `FAILURES_KEPT` failed solves, the samples'
        statistics (`model.summary_of`, with ``count`` and ``failed``: every failed sample; with a fitted
        law ``fibre_strains``, the least and largest strain any sample reached per direction) and each
        sample's wing rms, mm (NaN where it failed).
    """
    count, n = sampling.samples, model.n_bays
    kept = {key: np.empty(count) for key in ("rms", "max", "min_tension")}
    kept.update({key: np.empty((count, n)) for key in ("bay_rms", "bay_max", "bay_min_tension")})
    rows, failures, failed, reached = [], [], 0, None
    solved = (_solve_here(model, nominal, sampling) if sampling.scheduler is None
              else _solve_on_cluster(model, sampling, nominal_rtol))
    for m, e, (measured, failed_bays) in solved:
        for key, values in kept.items():
            values[m] = measured[key]
        if "strains" in measured:  # (a fitted law: the strains every sample reached, kept as four floats)
            (a, b), (c, d) = measured["strains"]
            reached = ([a, b], [c, d]) if reached is None else (
                [min(reached[0][0], a), max(reached[0][1], b)], [min(reached[1][0], c), max(reached[1][1], d)])
        row = _row(model, m, e, measured, not failed_bays)
        if sampling.keep_rows:
            rows.append(row)
        if failed_bays:
            failed += 1
            failures += [{"sample": m, "bay": k, "message": msg}
                         for k, msg in failed_bays][:max(FAILURES_KEPT - len(failures), 0)]
        if sampling.on_sample is not None:
            sampling.on_sample(row)
    sampled = summary_of(kept)
    sampled.update(count=count, failed=failed)
    if reached is not None:
        sampled["fibre_strains"] = {"span": reached[0], "chord": reached[1]}
    return rows, failures, sampled, kept["rms"]


def _solve_here(model: ToleranceModel, nominal, sampling):
    """``(sample, e, (measures, failures))`` of every sample, solved in this process, in sample order."""
    for first, draws in sample_draws(model, sampling.seed, sampling.samples):
        for i, e in enumerate(draws):
            yield first + i, e, _measured(model, e, nominal, sampling.rtol)
        release_free_memory()  # a chunk's freed arrays back to the system: the heap stays level


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


def _solve_chunk(model: ToleranceModel, draws: np.ndarray, rtol: float, nominal_rtol: float) -> list:
    """A Dask worker's chunk of samples: the measures and failures of each (`solve_wing`), warm from the
    nominal equilibrium that the worker solves once (the same solve as `tolerance_analysis`'s, so the
    samples are the same)."""
    with jax.enable_x64(True):
        if getattr(model, "worker_nominal", None) is None:
            model.worker_nominal = model.nominal_solutions(nominal_rtol)
    return [_measured(model, e, model.worker_nominal, rtol) for e in draws]


def _solve_on_cluster(model: ToleranceModel, sampling, nominal_rtol: float):
    """``(sample, e, (measures, failures))`` of every sample, solved on a Dask cluster, in sample order as
    the chunks come back: chunks of at most `CLUSTER_CHUNK` samples (four per worker thread where the
    samples are fewer: a slow chunk holds up few), drawn as they are sent, at most four per worker thread
    in flight."""
    from distributed import Client

    scheduler = sampling.scheduler
    client = scheduler if isinstance(scheduler, Client) else connect_scheduler(scheduler)
    try:
        threads = max(sum(client.nthreads().values()), 1)
        size = max(1, min(CLUSTER_CHUNK, math.ceil(sampling.samples / (4 * threads))))
        shared = client.scatter(model, broadcast=True)  # (once per worker, not once per chunk)
        pending = deque()
        for first, draws in sample_draws(model, sampling.seed, sampling.samples, size):
            pending.append((first, draws, client.submit(_solve_chunk, shared, draws, sampling.rtol, nominal_rtol,
                                                        pure=False)))
            if len(pending) >= 4 * threads:
                yield from _collect(*pending.popleft())
        while pending:
            yield from _collect(*pending.popleft())
    finally:
        if client is not scheduler:
            client.close()


def _collect(first: int, draws: np.ndarray, future):
    """The samples of one chunk sent to the cluster, as `_solve_on_cluster` yields them."""
    results = future.result()
    future.release()
    for i, (e, result) in enumerate(zip(draws, results)):
        yield first + i, e, result
