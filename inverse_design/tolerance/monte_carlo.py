"""The Monte Carlo check of a tolerance analysis: wings drawn from the stated distributions, solved.

Monte Carlo (`first_order.Sampling`'s ``samples``): draws wings from the stated distributions and
solves each bay warm from the nominal equilibrium (chord Newton with its
kept factor, the fallbacks of `forward_solver.solvers.chain` where not) to
`SAMPLE_RTOL`, in this process, or on a Dask cluster (its ``scheduler``: the
samples in chunks, each worker making the nominal factor once by the same
solve as here, so the same seed gives the same numbers). A sample whose solve
fails is counted and named, never dropped.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from forward_solver import solve_equilibrium

from .model import ToleranceModel, summary_of

__all__ = ["SAMPLE_RTOL", "SCHEDULER_TIMEOUT_S", "connect_scheduler", "monte_carlo", "solve_wing"]

#: Relative residual of a Monte Carlo wing's solves (the residual force 1e-8 of the pressure load: the
#: command's equilibrium tolerance; its error in the distances is far below their scatter).
SAMPLE_RTOL = 1e-8


def solve_wing(model: ToleranceModel, e: np.ndarray, starts, rtol: float) -> tuple:
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


def _row(model: ToleranceModel, index: int, e: np.ndarray, measured: dict, converged: bool) -> dict:
    row = {"sample": index}
    row.update({c.name: float(v + d) for c, v, d in zip(model.columns, model.nominal_values, e)})
    row.update(rms=float(measured["rms"][0]), max=float(measured["max"][0]),
               min_tension=float(measured["min_tension"][0]), converged=bool(converged))
    return row


def monte_carlo(model: ToleranceModel, nominal, sampling, nominal_rtol: float) -> tuple[list, list, dict]:
    """The Monte Carlo wings of ``sampling`` (a `first_order.Sampling`), each solved warm from the
    ``nominal`` equilibria (``nominal_rtol``: their residual, which a Dask worker solves them to again).

    Returns:
        ``(rows, failures, sampled)``: one dict per sample (the CSV's rows, each also given to
        ``sampling.on_sample`` as it is solved, in sample order), ``[{"sample", "bay", "message"}]`` of
        the samples whose solve failed, and the samples' statistics (`model.summary_of`, with ``count``
        and ``failed``).
    """
    rng = np.random.default_rng([sampling.seed, 0])
    draws = model.unit_draws(rng, sampling.samples) * model.spread[None, :]
    rows, failures, measures = [], [], []
    solved = ((solve_wing(model, e, nominal, sampling.rtol) for e in draws) if sampling.scheduler is None
              else _solve_on_cluster(model, draws, sampling.rtol, nominal_rtol, sampling.scheduler))
    for m, (d, t, failed) in enumerate(solved):
        measured = model.measures([x[None] for x in d], [x[None] for x in t])
        measures.append(measured)
        row = _row(model, m, draws[m], measured, not failed)
        rows.append(row)
        failures += [{"sample": m, "bay": k, "message": msg} for k, msg in failed]
        if sampling.on_sample is not None:
            sampling.on_sample(row)
    sampled = summary_of({key: np.concatenate([m[key] for m in measures]) for key in measures[0]})
    sampled.update(count=sampling.samples, failed=len({f["sample"] for f in failures}))
    return rows, failures, sampled


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
    """A Dask worker's chunk of samples: `solve_wing` of each, warm from the nominal equilibrium that the
    worker solves once (the same solve as `tolerance_analysis`'s, so the samples are the same)."""
    with jax.enable_x64(True):
        if getattr(model, "worker_nominal", None) is None:
            model.worker_nominal = model.nominal_solutions(nominal_rtol)
    return [solve_wing(model, e, model.worker_nominal, rtol) for e in draws]


def _solve_on_cluster(model: ToleranceModel, draws: np.ndarray, rtol: float, nominal_rtol: float, scheduler):
    """`solve_wing` of every draw on a Dask cluster, yielded in sample order as the chunks come back
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
