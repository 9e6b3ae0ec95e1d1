"""The Monte Carlo samples stream (`inverse_design.tolerance.monte_carlo`): the same draws in any chunks as
drawn at once, a memory that grows only by what `inverse_design.memory.sample_memory` counts, and a count
the machine cannot hold refused before any solve. One bay, 5x32, at a fixed equilibrium."""

import tracemalloc

import numpy as np
import pytest

from forward_solver import Fabric, Wing
from inverse_design import SolverSettings, evaluate_design
from inverse_design.memory import sample_memory
from inverse_design.tolerance import Sampling, ToleranceModel, parse_tolerances, tolerance_analysis
from inverse_design.tolerance import monte_carlo as sampling_module
from targets import naca


@pytest.fixture(scope="module")
def one_bay():
    af = naca("2412")
    wing = Wing(airfoils=(af, af), chords=(1.0, 0.9), stations=(0.0, 0.25))
    return evaluate_design(wing.scenes(Fabric(), 5, 32), [af, af], {"pressure": 5e3, "prestrain_span": 0.02,
                           "prestrain_chord": 0.02}, objective="average", wing=wing, solver=SolverSettings(rtol=1e-11))


@pytest.mark.parametrize("tolerances", [{"pressure": "2%", "cut_span": "uniform:0.5", "rib_profile": 0.5},
                                        {"pressure": "2%", "stiffness_span": "10%"}], ids=["uniform", "normal"])
def test_the_draws_are_the_same_in_any_chunks_as_drawn_at_once(one_bay, tolerances):
    # The stream of the draws made all at once (normal, then uniform: the samples' numbers before they
    # streamed), to the bit, whatever the chunk.
    model = ToleranceModel.of(one_bay, parse_tolerances(tolerances))
    count, seed = 1000, 5
    at_once = model.unit_draws(np.random.default_rng([seed, 0]), count) * model.spread[None, :]
    for chunk in (1, 7, 256, 5000):
        parts = list(sampling_module.sample_draws(model, seed, count, chunk))
        assert [first for first, _ in parts] == list(range(0, count, chunk))
        assert np.array_equal(np.concatenate([e for _, e in parts]), at_once), chunk


def _fake_solves(model):
    """A `monte_carlo.solve_wing` that solves nothing: the nominal rows moved by the draw's first column."""
    n_tensions = model.scenes[0].bay.n_contour * 2 * (model.scenes[0].bay.n_span - 1)

    def solve_wing(model, e, starts, rtol):
        return ([np.full(model.n_distances, 1.0 + e[0])] * model.n_bays,
                [np.full(n_tensions, 100.0 + e[0])] * model.n_bays, [])

    return solve_wing


@pytest.mark.parametrize("keep_rows", [False, True])
def test_the_samples_keep_no_more_than_their_estimate(one_bay, monkeypatch, keep_rows):
    # 10,000 samples (their solves replaced by a formula: only what the sampling keeps is measured): the
    # traced peak above the start stays within inverse_design.memory.sample_memory's estimate and a
    # constant (a chunk's draws, the statistics of one bay: well under 1 MiB). Before the samples streamed,
    # every sample's measures (a dict of six arrays) and its row were kept, the draws made at once.
    model = ToleranceModel.of(one_bay, parse_tolerances({"pressure": "2%", "cut_span": "uniform:0.5"}))
    monkeypatch.setattr(sampling_module, "solve_wing", _fake_solves(model))
    count = 10_000
    seen = []
    sampling = Sampling(samples=count, seed=1, keep_rows=keep_rows, on_sample=lambda row: seen.append(row["sample"]))
    tracemalloc.start()
    try:
        start = tracemalloc.get_traced_memory()[0]
        rows, failures, sampled, rms = sampling_module.monte_carlo(model, None, sampling, 1e-11)
        peak = tracemalloc.get_traced_memory()[1] - start
    finally:
        tracemalloc.stop()
    assert seen == list(range(count)) and len(rows) == (count if keep_rows else 0) and failures == []
    assert sampled["count"] == count and sampled["failed"] == 0 and rms.shape == (count,)
    assert sampled["rms"]["p95"] > sampled["rms"]["p5"]
    estimate = sample_memory(count, model.n_bays, model.size, keep_rows)
    assert peak <= estimate + 2**20, (peak, estimate)


def test_more_samples_than_the_machine_holds_are_refused_before_any_solve(one_bay, monkeypatch):
    def no_solve(*args, **kwargs):
        raise AssertionError("solved before refusing")

    monkeypatch.setattr(ToleranceModel, "nominal_solutions", no_solve)
    with pytest.raises(ValueError, match=r"^Sampling\.samples=1,000,000,000,000,000: the Monte Carlo check would "
                                         r"keep about .* GiB .*, more than this machine's .* GiB of memory; give at "
                                         r"most [\d,]+ samples, or keep_rows=False"):
        tolerance_analysis(one_bay, {"pressure": "2%"}, sampling=Sampling(samples=10**15))
    with pytest.raises(ValueError, match="more than this machine's"):
        sampling_module.check_samples(10**6, ToleranceModel.of(one_bay, parse_tolerances({"pressure": "2%"})),
                                      keep_rows=False, physical=2**20)
