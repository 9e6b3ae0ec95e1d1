"""The peak memory of a design, estimated from its bays, grid and variables before it starts.

A Gauss-Newton design (`methods.GaussNewton`) holds, per bay, its
equilibrium and LU factor (the nodes' count times a constant) and the
tangents of its Jacobian blocks (`methods.blocks.compressed_seeds`: shared + per-bay
+ 2 x per-rib of them, each a node array through the force kernel and the
back-solve), over a base of the interpreter, JAX and the compiled
programs. So the estimate is linear::

    peak MiB = BASE + n_bays x nodes x (PER_NODE + PER_TANGENT_NODE x tangents)

with ``nodes = n_span x n_contour``. The coefficients are fitted to the peak
resident memory (``ru_maxrss``) of ``benchmarks/wing_cells.py`` runs of the
built-in 40-cell wing's first 10 and 20 bays at 17x64 with a field per bay and
a shape per rib (29 tangents), capped at 2 wing solves: 987 and 1324 MiB, 33.7
MiB a bay (0.031 MiB a node; the tangents' share, 0.0005 MiB a node each, is
the size of their node arrays through the force kernel, not a fit).

A design of many iterates holds little more, once two things that grew with
every iterate are gone (found on the same wing's first 10 and 20 bays): the
LU factors of every earlier iterate's Jacobian, kept for pullbacks that a
forward-mode design never calls (about 3 MB a bay and iterate, up to 512 MiB;
now dropped, `forward_solver.derivatives.implicit.forward_only`), and the free
memory that glibc's heap keeps after each iterate (about 100 MB an iterate on
20 bays), which the design now gives back after each wing solve and each
linearisation (`release_free_memory`). Measured with the dropped factors and
the heap held down (then by a fixed mmap threshold): the whole 40-cell design
with a field per bay and a shape per rib (809 variables, 21 wing solves to a
Gauss-Newton tolerance of 1e-4) peaked at 2,053-2,080 MiB in four runs, and at
2,079 MiB in 13 solves to the default 1e-3 (the estimate: 2,000 MiB), its
resident memory level at 1.5-1.6 GB from the fourth iterate, where it had
reached 6.7 GB after 60 minutes and was growing.

A Monte Carlo check of the tolerances (`tolerance.monte_carlo`) draws and
solves its samples a chunk at a time; what it keeps grows with the samples
(`sample_memory`): for the statistics' percentiles, each sample's rms, largest
distance and least tension of the wing and of every bay (``3 + 3 n_bays``
floats), and while the statistics are taken, two copies of one of them
(`STATISTICS_BYTES`); and, where the rows are kept (the library's default,
`tolerance.Sampling`'s ``keep_rows``), each sample's row, a dict of its drawn
values. A row's size, measured with ``tracemalloc`` over 2000 rows (Python 3.11,
a float per column and ``sample``, ``rms``, ``max``, ``min_tension``,
``converged``)::

    columns           1     9     50     250
    bytes a row     741   736   2840   12632

and `ROW_BYTES` ``(768, 52)``, ``768 + 52 * columns``, lies above each
(by 9%-68%: a dict's table grows in powers of two).
"""

from __future__ import annotations

import ctypes
import math
import os
import sys

__all__ = ["BASE_MIB", "PER_NODE_MIB", "PER_TANGENT_NODE_MIB", "ROW_BYTES", "STATISTICS_BYTES", "design_tangents",
           "design_memory", "physical_memory", "release_free_memory", "sample_memory"]

#: The interpreter, JAX, the compiled programs and one bay's work, MiB.
BASE_MIB = 650.0
#: Per node of every bay: the equilibria, LU factors, warm starts and archived solves, MiB.
PER_NODE_MIB = 0.0165
#: Per node of every bay and Jacobian tangent: the tangents and their derivatives, MiB.
PER_TANGENT_NODE_MIB = 0.0005


def design_tangents(names, n_bays: int, *, cut_pattern_terms: int = 0, rib_shape_terms: int = 0,
                    cut_pattern: str = "shared", rib_shape: str = "per_rib") -> int:
    """The Jacobian's tangents per bay (`methods.blocks.compressed_seeds`) of a design, from its names and layouts.

    Args:
        names: the optimised variable names.
        n_bays: bays of the wing.
        cut_pattern_terms: K of the cut field (2 K coefficients).
        rib_shape_terms: K of a rib shape (2 K coefficients).
        cut_pattern: its layout, "shared" or "per_bay".
        rib_shape: its layout, "shared" or "per_rib" (a wing's default).

    Returns:
        shared + per-bay + 2 x per-rib components.
    """
    count = 0
    for name in names:
        if name == "cut_pattern":
            count += 2 * cut_pattern_terms
        elif name == "rib_shape":
            count += 2 * rib_shape_terms * (2 if rib_shape == "per_rib" and n_bays > 1 else 1)
        else:
            count += 1
    return count


def design_memory(n_bays: int, n_span: int, n_contour: int, n_tangents: int) -> float:
    """Estimated peak resident memory of a Gauss-Newton design, bytes (module docstring).

    Args:
        n_bays: bays of the wing.
        n_span, n_contour: the grid of every bay.
        n_tangents: the Jacobian's tangents (`design_tangents`).
    """
    nodes = n_bays * n_span * n_contour
    mib = BASE_MIB + nodes * (PER_NODE_MIB + PER_TANGENT_NODE_MIB * max(n_tangents, 1))
    return math.ceil(mib * 2**20)


#: ``(base, per column)`` bytes of a Monte Carlo sample's row kept in memory (module docstring).
ROW_BYTES = (768, 52)
#: Bytes a sample while the statistics are taken: the finite values of one measure copied, the copy that
#: the percentile partitions, and the finiteness mask (8 + 8 + 1, rounded up).
STATISTICS_BYTES = 24


def sample_memory(samples: int, n_bays: int, n_columns: int = 0, keep_rows: bool = False) -> int:
    """What a Monte Carlo check of ``samples`` wings keeps, bytes, at its peak (module docstring): the
    per-sample measures of the statistics and their transient copies, and with ``keep_rows`` each
    sample's row of ``n_columns`` drawn values. The chunk of draws being solved (a few hundred
    samples) and the failures named (a bounded list) are left out: they do not grow with ``samples``.

    Args:
        samples: Monte Carlo wings.
        n_bays: bays of the wing.
        n_columns: tolerance parameters (the rows' drawn values; only with ``keep_rows``).
        keep_rows: whether every sample's row is kept in memory.
    """
    per_sample = 8 * (3 + 3 * n_bays) + STATISTICS_BYTES
    if keep_rows:
        per_sample += ROW_BYTES[0] + ROW_BYTES[1] * n_columns
    return int(samples) * per_sample


def physical_memory() -> int | None:
    """The machine's physical memory, bytes (``os.sysconf``), or None where the system does not say."""
    try:
        pages, size = os.sysconf("SC_PHYS_PAGES"), os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return None
    return pages * size if pages > 0 and size > 0 else None


def release_free_memory() -> bool:
    """Give the heap's free memory back to the system (glibc's ``malloc_trim(0)``): a design calls it
    after each wing solve and each linearisation, so that its resident memory stays level.

    glibc raises its mmap threshold to the size of each mapped block a program frees (up to 32 MiB),
    so after the first iterate the arrays an iterate makes and frees (the Jacobian's tangents and
    decompression, the LU factors, the step QP) come from the heap, which fragmentation keeps from
    shrinking: measured on the first 20 bays of the 40-cell wing (17x64, a field per bay and a shape per
    rib, 409 variables), resident 1,057 MB after the first iterate and 1,756 MB after the eighth. Fixing
    the threshold at 128 KiB instead (``mallopt``) held it level, but every XLA program then mapped and
    unmapped its larger buffers on each call: the 40-cell wing's Jacobian values (a bay, 36 colours)
    4.9 ms a call against 1.7 ms, half the time in the kernel's page faults, and its designs 16.3 s
    against 13.9 s (3 variables) and 52.7 s against 43.1 s (809 variables) with this call instead,
    peak memory 1,104 and 1,513 MB against 1,116 and 1,640 MB (the 2-core development machine, one run
    each). One call costs 5-20 ms on those designs. Nothing happens outside glibc.

    Returns:
        Whether memory was given back.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None)
        if not hasattr(libc, "gnu_get_libc_version"):  # glibc only
            return False
        return bool(libc.malloc_trim(ctypes.c_size_t(0)))
    except (OSError, AttributeError):
        return False
    try:
        libc = ctypes.CDLL(None)
        if not hasattr(libc, "gnu_get_libc_version"):  # glibc only: the parameter is its own
            return False
        return bool(libc.mallopt(ctypes.c_int(_M_MMAP_THRESHOLD), ctypes.c_int(int(threshold))))
    except (OSError, AttributeError):
        return False
