"""The peak memory of a design, estimated from its bays, grid and variables before it starts.

A Gauss-Newton design (`methods.gauss_newton`) holds, per bay, its
equilibrium and LU factor (the nodes' count times a constant) and the
tangents of its Jacobian blocks (`blocks.compressed_seeds`: shared + per-bay
+ 2 x per-rib of them, each a node array through the force kernel and the
back-solve), over a base of the interpreter, JAX and the compiled
programs. So the estimate is linear::

    peak MiB = BASE + n_bays x nodes x (PER_NODE + PER_TANGENT_NODE x tangents)

with ``nodes = n_span x n_contour``. The coefficients are fitted to the peak
resident memory (``ru_maxrss``) of ``benchmarks/wing_cells.py`` runs of the
built-in 40-cell wing's first 10 and 20 bays at 17x64 with a field per bay and
a shape per rib (29 tangents), capped at 2 wing solves: 987 and 1324 MiB, 33.7
MiB a bay (0.031 MiB a node; the tangents' share, 0.0005 MiB a node each, is
the size of their node arrays through the force kernel, not a fit). A run of
many iterates holds more: the archive of every solve grows with them
(measured: the uncapped 40-bay design, 809 variables, 6.7 GiB resident after
60 minutes at load 7-16 and still growing, against the estimate's 2.0 GiB;
the cause is not found: the archive of solves is small and the released LU
factors are capped at 512 MiB), so the estimate is the floor a design needs,
and the command refuses on it.
"""

from __future__ import annotations

import math

__all__ = ["BASE_MIB", "PER_NODE_MIB", "PER_TANGENT_NODE_MIB", "design_tangents", "design_memory"]

#: The interpreter, JAX, the compiled programs and one bay's work, MiB.
BASE_MIB = 650.0
#: Per node of every bay: the equilibria, LU factors, warm starts and archived solves, MiB.
PER_NODE_MIB = 0.0165
#: Per node of every bay and Jacobian tangent: the tangents and their derivatives, MiB.
PER_TANGENT_NODE_MIB = 0.0005


def design_tangents(names, n_bays: int, *, cut_pattern_terms: int = 0, rib_shape_terms: int = 0,
                    cut_pattern: str = "shared", rib_shape: str = "per_rib") -> int:
    """The Jacobian's tangents per bay (`blocks.compressed_seeds`) of a design, from its names and layouts.

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
