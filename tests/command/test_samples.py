"""``--samples`` bounded (docs/tolerances.md, docs/errors.md): a count the machine cannot hold or solve in
reasonable time is refused before any solve with one line (`resources.check_samples`). On 5x32 bays."""

import re

import pytest

from inverse_design.app import cli, design, resources
from support.cases import IN_PROCESS, SMALL


@pytest.mark.parametrize("samples, message", [
    # 1e9 wings: 72 bytes each for the statistics (67 GiB, more than half of any test machine's memory
    # and than most machines' own) and 49 days of solves. Before: the design ran, then the draws of every
    # sample at once (24 GB), and no stop ended it (the run).
    ("1000000000", r"--samples 1,000,000,000 on 1 bay of 5 x 32 is too many for this machine: estimate [\d.]+ GiB "
                   r"of memory for their statistics and [\d,]+ days of solves on a 2-core machine, more than .*; give "
                   r"at most [\d,]+ --samples, a smaller --n-span or --n-contour, --scheduler ADDRESS"),
    # 1e7 wings: 690 MiB, but 12 hours of solves.
    ("10000000", r"--samples 10,000,000 on 1 bay of 5 x 32 is too many for this machine: estimate [\d.]+ MiB of "
                 r"memory for their statistics and [\d.]+ h of solves on a 2-core machine, more than the limit of "
                 r"60 min of solves in this process; give at most [\d,]+ --samples, a smaller --n-span or "
                 r"--n-contour, --scheduler ADDRESS to solve them on a Dask cluster, or --allow-large-grid"),
], ids=["memory", "time"])
def test_too_many_samples_are_refused_before_any_solve(samples, message, tmp_path, capsys, monkeypatch):
    solved = []

    def no_solve(*args, **kwargs):
        solved.append(True)
        raise AssertionError("the design ran before the samples were refused")

    monkeypatch.setattr(design, "optimise", no_solve)
    monkeypatch.chdir(tmp_path)
    code = cli.main(["--tolerance", "pressure=2%", "--samples", samples, *SMALL, *IN_PROCESS])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith("optimise-pressure: error: ")
    assert re.search(message, err), err
    assert solved == [] and list(tmp_path.iterdir()) == []


def test_check_samples_refuses_by_memory_time_and_the_machine_and_says_what_to_change():
    plenty = (1e15, "test")
    per_sample = resources.estimate_samples(1, 1, 9, 64)
    # memory: half of 2 GiB, less the design's 0.5 GiB
    over = int(0.5 * 2**30 / per_sample.memory) + 1
    with pytest.raises(ValueError, match=r"more than the limit of 512 MiB of memory \(half of the 2\.0 GiB "
                                         r"available, test, less the design's 512 MiB\); give at most [\d,]+ "
                                         r"--samples, or --allow-large-grid"):
        resources.check_samples(over, 1, 9, 64, base=2**29, scheduler=True, available=(2 * 2**30, "test"),
                                physical=2**40)
    assert resources.check_samples(over, 1, 9, 64, base=2**29, scheduler=True, allow_large=True,
                                   available=(2 * 2**30, "test"), physical=2**40).samples == over
    # time: an hour in this process; a cluster's time is its own
    slow = int(resources.MAX_SAMPLE_SECONDS / per_sample.seconds) + 1
    with pytest.raises(ValueError, match=r"limit of 60 min of solves in this process; give at most [\d,]+ --samples"):
        resources.check_samples(slow, 1, 9, 64, available=plenty, physical=2**40)
    assert resources.check_samples(slow, 1, 9, 64, scheduler=True, available=plenty, physical=2**40).samples == slow
    # more than the machine's memory: refused whatever the options
    with pytest.raises(ValueError, match=r"is too many for this machine: .* more than this machine's 1\.0 GiB of "
                                         r"memory with the design's 0 MiB; give at most [\d,]+ --samples$"):
        resources.check_samples(2**30 // 60, 1, 9, 64, allow_large=True, available=plenty, physical=2**30)
    # the memory unknown: the time limit still holds
    assert resources.check_samples(1000, 1, 9, 64, available=(None, "unknown"), physical=None).samples == 1000
