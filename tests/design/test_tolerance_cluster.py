"""The Monte Carlo check on a Dask cluster (`inverse_design.tolerance`, ``scheduler``): a `LocalCluster` of
two worker processes draws and solves the same wings as this process, and a scheduler that does not answer
is refused with one line. Small grid (5x32), one bay at a fixed equilibrium."""

import numpy as np
import pytest

from forward_solver import Fabric, Wing
from inverse_design import SolverSettings, evaluate_design
from inverse_design.tolerance import Sampling, connect_scheduler, tolerance_analysis
from inverse_design.tolerance import monte_carlo as tolerance_module
from targets import naca

distributed = pytest.importorskip("distributed")


def test_the_same_seed_gives_the_same_samples_on_a_cluster():
    af = naca("2412")
    wing = Wing(airfoils=(af, af), chords=(1.0, 0.9), stations=(0.0, 0.25))
    design = evaluate_design(wing.scenes(Fabric(), 5, 32), [af, af], {"pressure": 5e3, "prestrain_span": 0.02,
                             "prestrain_chord": 0.02}, objective="average", wing=wing, solver=SolverSettings(rtol=1e-11))
    tolerances = {"pressure": "2%", "stiffness_span": "10%", "cut_chord": 0.5, "rib_profile": 0.5}
    here = tolerance_analysis(design, tolerances, sampling=Sampling(samples=6, seed=3))
    streamed = []
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        there = tolerance_analysis(design, tolerances, sampling=Sampling(samples=6, seed=3, scheduler=client,
                                                                          on_sample=streamed.append))
        assert len(client.nthreads()) == 2
    assert [row["sample"] for row in streamed] == list(range(6))  # streamed in sample order
    assert there.sampled["count"] == 6 and there.sampled["failed"] == 0
    # The same draws (to the bit) and the same solves: the workers' nominal factor comes from the same
    # Newton solve, and their XLA programs from the same flags.
    for a, b in zip(here.samples, there.samples):
        assert a.keys() == b.keys()
        assert [a[k] for k in here.columns] == [b[k] for k in here.columns]
        for key in ("rms", "max", "min_tension"):
            assert b[key] == pytest.approx(a[key], rel=1e-12, abs=1e-15), (key, a[key], b[key])
    assert np.std([row["rms"] for row in here.samples]) > 0  # the samples differ: a real check


def test_a_scheduler_that_does_not_answer_is_refused_in_one_line():
    with pytest.raises(ValueError, match=r"^no Dask scheduler answered at tcp://127.0.0.1:9 within 0.5 s"):
        connect_scheduler("tcp://127.0.0.1:9", timeout=0.5)
    assert tolerance_module.SCHEDULER_TIMEOUT_S >= 5  # (the command waits longer for a real network)


def test_the_command_refuses_a_scheduler_that_does_not_answer_before_any_solve(tmp_path, capsys, monkeypatch):
    from inverse_design.app import cli

    monkeypatch.setattr(tolerance_module, "SCHEDULER_TIMEOUT_S", 0.5)
    code = cli.main(["--tolerance", "pressure=2%", "--samples", "4", "--scheduler", "tcp://127.0.0.1:9",
                     "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith("optimise-pressure: error: --scheduler: no Dask scheduler answered at tcp://127.0.0.1:9")
    assert not (tmp_path / "out").exists()
