"""What a grid and its samples cost: the memory and time that ``optimise-pressure`` estimates before it starts.

The command refuses a grid whose estimated peak memory exceeds half of the
memory available, or that has more than `MAX_NODES` nodes (hours per
design), unless told ``--allow-large-grid``; nothing here imports JAX (the
command's options read `MAX_NODES` before JAX is imported).

The coefficients are fits to measurements of the command (peak resident set
size and wall time from ``/usr/bin/time -v``) on the development machine:
Linux, 2-core Intel Xeon shared with other jobs, 24 GB, Python 3.11.7, JAX
0.10.2 on the CPU. Memory in MiB; "optimise" is the default case with
``--max-iterations 2`` (3 forward solves, relaxation then sparse Newton with
its LU factor, and the adjoint), "evaluate" is ``--evaluate`` (one relaxation
solve); times include JIT compilation and the report::

    grid (span x contour)   nodes   evaluate         optimise (3 solves)
    9 x 64                    576    625 MiB   7.8 s    588 MiB    15 s
    17 x 128                 2176    722 MiB    11 s    664 MiB    16 s
    33 x 256                 8448    740 MiB    21 s    950 MiB    46 s
    65 x 512                33280    920 MiB    36 s   2035 MiB    64 s
    129 x 1024             132096   1166 MiB   139 s   6864 MiB   291 s
    9 x 1024, 129 x 64,  ~8200-9200                     810, 822,
    257 x 32 (same nodes, other shapes)                 1011 MiB

Fits of the peak memory, ``a + b * nodes**p`` (`MEMORY_FIT`): optimise
583 MiB + 0.02425 MiB * nodes**1.057 (within 3 % of the five square-ish
grids; the Newton LU fill makes it slightly faster than linear; other
shapes of the same node count lie within 15 %); evaluate 705 MiB + 3.75 KiB
per node (within 13 %). Wall time, ``a + solves * b * nodes**p``
(`TIME_FIT`; ``a`` is mostly start-up and JIT compilation): evaluate 10 s +
2.5e-4 s * nodes**1.115 (one solve and the report); optimise 20 s + solves *
4.2e-5 s * nodes**1.237 per forward solve. Both within 40 % (a shared
machine), enough to tell minutes from hours. The default case (9 x 64)
takes 14 forward solves (`TYPICAL_SOLVES`).

The Monte Carlo samples of ``--samples`` (`check_samples`) are checked before
the design too. Their memory is what the analysis keeps per sample
(`inverse_design.memory.sample_memory`: the command streams the rows to a file,
so a few floats a sample for the statistics' percentiles), over the design's own
estimate; their time is the samples times the bays times a bay's warm solve
(`SAMPLE_TIME_FIT`). That fit is ``benchmarks/sample_cost.py``
(``benchmarks/results/sample_cost.json``) on a 2-core AMD EPYC machine shared
with other jobs (2026-11-28; Python 3.11.7, JAX 0.10.2 on the CPU): one bay,
NACA 2412, chord 1 m, ribs 0.25 m apart, solved warm from the nominal
equilibrium moved by its first-order change to the samples' 1e-8, after 2
samples that compile; seconds per sample and bay::

    grid (span x contour)   nodes   default tolerances   pressure=2% alone
    5 x 32                    160        0.0058               0.0029
    9 x 64                    576        0.0122               0.0048
    17 x 64                  1088        0.021                0.0067
    17 x 128                 2176        0.039                0.0108
    33 x 128                 4224        0.108                0.0213
    33 x 256                 8448        0.178                0.0565
    65 x 256                16640        0.393                0.0755

The fit ``b * nodes**p`` of the default tolerances (the costlier: each bay's
stiffnesses, cuts and ribs move, where a pressure scatter alone takes 2-5 times
less) is 3.7e-5 s * nodes**0.937, within 27% of every row, enough to tell
minutes from hours. A sample costs its bays' solves: a bay of a 3-bay wing on
17 x 64 took 0.022 s a sample in that run. The samples are refused when their memory exceeds
`MEMORY_FRACTION` of the available memory less the design's, when they would take
more than `MAX_SAMPLE_SECONDS` in this process, or, whatever the options, when
their memory exceeds the machine's (`inverse_design.memory.physical_memory`: the
library's own refusal, `inverse_design.tolerance.monte_carlo.check_samples`).
``--scheduler`` lifts the time limit (the cluster's size is its own);
``--allow-large-grid`` lifts both limits, as it does the grid's.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from ..memory import design_memory, physical_memory, sample_memory

__all__ = [
    "MAX_NODES",
    "MAX_SAMPLE_SECONDS",
    "MEMORY_FIT",
    "MEMORY_FRACTION",
    "SAMPLE_TIME_FIT",
    "TIME_FIT",
    "TYPICAL_SOLVES",
    "GridCost",
    "SampleCost",
    "available_memory",
    "check_design_memory",
    "check_grid",
    "check_samples",
    "estimate_cost",
    "estimate_samples",
]

#: Most grid nodes (n_span x n_contour) run without ``--allow-large-grid``: at
#: the cap an optimisation takes about 50 minutes on the development machine
#: (one equilibrium, ``--evaluate``, about 5).
MAX_NODES = 250_000
#: Largest fraction of the available memory that a run's estimate may take.
MEMORY_FRACTION = 0.5
#: ``(a MiB, b MiB, p)`` of peak memory ``a + b * nodes**p``, per mode (see the module docstring).
MEMORY_FIT = {"evaluate": (705.0, 3.75 / 1024, 1.0), "optimise": (583.0, 0.02425, 1.057)}
#: ``(a s, b s, p)`` of the wall time ``a + solves * b * nodes**p``, per mode (see the module docstring).
TIME_FIT = {"evaluate": (10.1, 2.5e-4, 1.115), "optimise": (20.3, 4.2e-5, 1.237)}
#: Forward solves of an optimisation, as the default case takes (14).
TYPICAL_SOLVES = 15
#: ``(b s, p)`` of a Monte Carlo sample's seconds per bay, ``b * nodes**p`` (see the module docstring).
SAMPLE_TIME_FIT = (3.7e-5, 0.937)
#: Most seconds of Monte Carlo samples run in this process without ``--allow-large-grid`` or
#: ``--scheduler``: an hour, about an optimisation at the grid cap (`MAX_NODES`).
MAX_SAMPLE_SECONDS = 3600.0

_MIB = 2**20
# cgroup memory limits (containers): v2, then v1; "max" or a huge number means no limit.
_CGROUP_LIMITS = (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                  ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                   "/sys/fs/cgroup/memory/memory.usage_in_bytes"))


@dataclass(frozen=True)
class GridCost:
    """Estimated cost of a run.

    Attributes:
        nodes: grid nodes, n_span * n_contour.
        memory: peak resident memory, bytes.
        seconds: wall time on the development machine (2 cores): one solve
            for ``--evaluate``, `TYPICAL_SOLVES` for an optimisation.
        solves: forward solves counted in ``seconds``.
    """

    nodes: int
    memory: float
    seconds: float
    solves: int


def estimate_cost(n_span: int, n_contour: int, evaluate: bool = False) -> GridCost:
    """The estimated peak memory and time of ``optimise-pressure`` on an ``n_span x n_contour`` grid.

    Args:
        n_span: grid nodes along the span (ribs included).
        n_contour: grid nodes around the contour.
        evaluate: one equilibrium (``--evaluate``) rather than an optimisation.

    Returns:
        The `GridCost` from the fits of the module docstring.
    """
    nodes = int(n_span) * int(n_contour)
    mode = "evaluate" if evaluate else "optimise"
    a, b, p = MEMORY_FIT[mode]
    t0, t1, q = TIME_FIT[mode]
    solves = 1 if evaluate else TYPICAL_SOLVES
    return GridCost(nodes=nodes, memory=(a + b * nodes**p) * _MIB, seconds=t0 + solves * t1 * nodes**q,
                    solves=solves)


def _read_int(path: str) -> int | None:
    try:
        text = Path(path).read_text().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def available_memory() -> tuple[float | None, str]:
    """Memory a new run may use, bytes, and where the number comes from.

    Linux: ``MemAvailable`` of ``/proc/meminfo`` (free memory plus what the
    kernel can reclaim), else free pages (``os.sysconf``, which leaves out
    the reclaimable cache, so it errs low); lowered to the room left under a
    cgroup memory limit (a container's) when there is one. ``(None, reason)``
    where none of these exist (macOS, Windows): the memory is then not checked.
    """
    available, source = None, ""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    available, source = int(line.split()[1]) * 1024, "MemAvailable in /proc/meminfo"
                    break
    except (OSError, ValueError, IndexError):
        pass
    if available is None:
        try:
            available = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
            source = "free pages (os.sysconf)"
        except (AttributeError, ValueError, OSError):
            return None, "the available memory is unknown on this system"
    for limit_file, usage_file in _CGROUP_LIMITS:
        limit, usage = _read_int(limit_file), _read_int(usage_file)
        if limit is not None and usage is not None and limit < 2**60:
            if limit - usage < available:
                available, source = max(limit - usage, 0), f"the cgroup limit {limit_file}"
            break
    return float(available), source


def _size(n_bytes: float) -> str:
    return f"{n_bytes / 2**30:.1f} GiB" if n_bytes >= 2**30 else f"{n_bytes / _MIB:.0f} MiB"


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 2 * 3600:
        return f"{seconds / 60:.0f} min"
    if seconds < 72 * 3600:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:,.0f} days"


def check_grid(n_span: int, n_contour: int, *, evaluate: bool = False, allow_large: bool = False,
               available: tuple[float | None, str] | None = None) -> GridCost:
    """Refuse a grid the machine cannot run in reasonable memory and time.

    Args:
        n_span, n_contour: the grid (sizes below 1 are left to `forward_solver.Bay` to refuse).
        evaluate: one equilibrium rather than an optimisation.
        allow_large: skip both refusals (``--allow-large-grid``).
        available: ``(bytes or None, source)`` as `available_memory` returns
            it (the default: measured now).

    Returns:
        The `GridCost` estimate.

    Raises:
        ValueError: if the estimated peak memory exceeds `MEMORY_FRACTION`
            of the available memory, or the grid has more than `MAX_NODES`
            nodes; the message gives the estimate, the limit and what to change.
    """
    if not (isinstance(n_span, int) and isinstance(n_contour, int) and n_span >= 1 and n_contour >= 1):
        return GridCost(nodes=0, memory=0.0, seconds=0.0, solves=0)
    cost = estimate_cost(n_span, n_contour, evaluate)
    if allow_large:
        return cost
    free, source = available_memory() if available is None else available
    what = "one equilibrium" if evaluate else f"an optimisation of about {cost.solves} forward solves"
    grid = f"the {n_span} x {n_contour} grid ({cost.nodes:,} nodes)"
    estimate = (f"estimate {_size(cost.memory)} of memory and {_duration(cost.seconds)} for {what} "
                "on a 2-core machine")
    advice = "use a smaller --n-span or --n-contour, or --allow-large-grid to run it anyway"
    if free is not None and cost.memory > MEMORY_FRACTION * free:
        raise ValueError(f"{grid} is too large for this machine: {estimate}, more than the limit of "
                         f"{_size(MEMORY_FRACTION * free)} (half of the {_size(free)} available, {source}); "
                         f"{advice}")
    if cost.nodes > MAX_NODES:
        raise ValueError(f"{grid} exceeds the cap of {MAX_NODES:,} nodes: {estimate}; {advice}")
    return cost


def check_design_memory(n_bays: int, n_span: int, n_contour: int, n_tangents: int, *, allow_large: bool = False,
                        available: tuple[float | None, str] | None = None) -> float:
    """Refuse a design whose estimated peak memory (`inverse_design.memory.design_memory`: bays, grid and
    the Jacobian's tangents) exceeds `MEMORY_FRACTION` of the available memory; returns the estimate, bytes.

    Raises:
        ValueError: one line with the estimate, the limit and what to change.
    """
    estimate = design_memory(n_bays, n_span, n_contour, n_tangents)
    free, source = available_memory() if available is None else available
    if not allow_large and free is not None and estimate > MEMORY_FRACTION * free:
        raise ValueError(f"the design of {n_bays} bays on {n_span} x {n_contour} with {n_tangents} Jacobian tangents "
                         f"per bay needs about {_size(estimate)} of memory, more than the limit of "
                         f"{_size(MEMORY_FRACTION * free)} (half of the {_size(free)} available, {source}); use "
                         "fewer bays, a smaller --n-span or --n-contour, fewer --cut-pattern-terms or "
                         "--rib-shape-terms, or --allow-large-grid to run it anyway")
    return estimate


@dataclass(frozen=True)
class SampleCost:
    """Estimated cost of a run's Monte Carlo samples.

    Attributes:
        samples: Monte Carlo wings.
        memory: what the analysis keeps for them, bytes (`inverse_design.memory.sample_memory`).
        seconds: their solves in this process on the development machine (2 cores).
    """

    samples: int
    memory: float
    seconds: float


def estimate_samples(samples: int, n_bays: int, n_span: int, n_contour: int) -> SampleCost:
    """The estimated memory and time of ``samples`` Monte Carlo wings of ``n_bays`` bays on ``n_span x
    n_contour`` (module docstring: `SAMPLE_TIME_FIT`), their rows streamed to a file."""
    b, p = SAMPLE_TIME_FIT
    return SampleCost(samples=int(samples), memory=float(sample_memory(samples, n_bays)),
                      seconds=float(samples) * n_bays * b * (int(n_span) * int(n_contour)) ** p)


def check_samples(samples: int, n_bays: int, n_span: int, n_contour: int, *, base: float = 0.0,
                  scheduler: bool = False, allow_large: bool = False,
                  available: tuple[float | None, str] | None = None, physical: float | None = None) -> SampleCost:
    """Refuse ``--samples`` the machine cannot hold, or solve in reasonable time (module docstring).

    Args:
        samples: Monte Carlo wings (``--samples``, 1 or more).
        n_bays, n_span, n_contour: the wing's bays and each bay's grid.
        base: the run's own peak memory before the samples, bytes (the design's estimate).
        scheduler: the samples are solved on a Dask cluster (``--scheduler``): no time limit.
        allow_large: lift the memory and time limits (``--allow-large-grid``); the machine's memory
            still holds.
        available: ``(bytes or None, source)`` as `available_memory` returns it (default: measured now).
        physical: the machine's memory, bytes (default `inverse_design.memory.physical_memory`).

    Returns:
        The `SampleCost` estimate.

    Raises:
        ValueError: one line with the estimate, the limit and what to change.
    """
    cost = estimate_samples(samples, n_bays, n_span, n_contour)
    per_sample = estimate_samples(1, n_bays, n_span, n_contour)
    physical = physical_memory() if physical is None else physical
    limits = []  # (the samples that fit, whether these exceed it, the limit in words, whether a flag lifts it)
    if physical is not None:
        room = physical - base
        limits.append((room / per_sample.memory, cost.memory > room,
                       f"this machine's {_size(physical)} of memory with the design's {_size(base)}", False))
    free, source = (None, "") if allow_large else available_memory() if available is None else available
    if free is not None:
        room = MEMORY_FRACTION * free - base
        limits.append((room / per_sample.memory, cost.memory > room,
                       f"the limit of {_size(max(room, 0.0))} of memory (half of the {_size(free)} available, "
                       f"{source}, less the design's {_size(base)})", True))
    slow = not (scheduler or allow_large) and cost.seconds > MAX_SAMPLE_SECONDS
    if not (scheduler or allow_large):
        limits.append((MAX_SAMPLE_SECONDS / per_sample.seconds, slow,
                       f"the limit of {_duration(MAX_SAMPLE_SECONDS)} of solves in this process", True))
    over = [(words, liftable) for _, exceeded, words, liftable in limits if exceeded]
    if not over:
        return cost
    fits = int(max(min(count for count, *_ in limits), 0))
    # (the memory is a few floats a sample whatever the grid: only fewer samples lower it)
    faster = ", a smaller --n-span or --n-contour, --scheduler ADDRESS to solve them on a Dask cluster" if slow else ""
    anyway = ", or --allow-large-grid to run them anyway" if all(liftable for _, liftable in over) else ""
    bays = f"{n_bays} bays" if n_bays > 1 else "1 bay"
    raise ValueError(f"--samples {samples:,} on {bays} of {n_span} x {n_contour} is too many for this machine: "
                     f"estimate {_size(cost.memory)} of memory for their statistics and {_duration(cost.seconds)} of "
                     f"solves on a 2-core machine, more than {' and '.join(words for words, _ in over)}; give at most "
                     f"{fits:,} --samples{faster}{anyway}")
