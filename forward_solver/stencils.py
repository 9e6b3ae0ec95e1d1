"""The structured grid's stencils: its edges and cells, sums over them and scatters onto the nodes.

The grid is ``(n_span, n_contour)`` nodes, index ``i`` along the span and
``j`` around the contour (closed: ``periodic``, the last node's edge wraps to
the first). Span edges ``(i+1/2, j)``, contour edges ``(i, j+1/2)``, cells
``(i+1/2, j+1/2)``; the force kernel (`forces`) and the shear term (`shear`)
read and scatter through these, and `safe_norm` is the norm every length
of them takes.
"""

from __future__ import annotations

import jax.numpy as jnp

__all__ = ["cell_corners", "contour_edge_sum", "next_j", "safe_norm", "scatter_cell_corners", "scatter_contour_edges",
           "scatter_span_edges", "span_edge_sum", "this_j"]


def safe_norm(v: jnp.ndarray, axis: int = -1) -> jnp.ndarray:
    """Euclidean norm whose gradient stays finite at zero (double-``where``).

    NaN stays NaN (so a stop test on a norm can never pass on a NaN state).
    """
    sq = jnp.sum(v * v, axis=axis)
    nonzero = sq > 0.0
    return jnp.where(nonzero, jnp.sqrt(jnp.where(nonzero, sq, 1.0)), sq)


def next_j(a: jnp.ndarray, periodic: bool) -> jnp.ndarray:
    """``a[:, j+1]`` for every contour edge (wrapping on a closed contour)."""
    return jnp.roll(a, -1, axis=1) if periodic else a[:, 1:]


def this_j(a: jnp.ndarray, periodic: bool) -> jnp.ndarray:
    """``a[:, j]`` for every contour edge (all of them on a closed contour)."""
    return a if periodic else a[:, :-1]


def contour_edge_sum(c: jnp.ndarray, periodic: bool) -> jnp.ndarray:
    """Sum the cell values on both sides of each span edge (along j)."""
    if periodic:
        return c + jnp.roll(c, 1, axis=1)
    return jnp.pad(c, ((0, 0), (1, 0))) + jnp.pad(c, ((0, 0), (0, 1)))


def span_edge_sum(c: jnp.ndarray) -> jnp.ndarray:
    """Sum the cell values on both sides of each contour edge (along i)."""
    pad = [(1, 0), (0, 0)] + [(0, 0)] * (c.ndim - 2)
    pad_hi = [(0, 1), (0, 0)] + [(0, 0)] * (c.ndim - 2)
    return jnp.pad(c, pad) + jnp.pad(c, pad_hi)


def scatter_span_edges(f: jnp.ndarray) -> jnp.ndarray:
    """Nodal sum of edge vectors ``f`` acting ``+f`` on node i and ``-f`` on i+1."""
    return jnp.pad(f, ((0, 1), (0, 0), (0, 0))) - jnp.pad(f, ((1, 0), (0, 0), (0, 0)))


def scatter_contour_edges(f: jnp.ndarray, periodic: bool) -> jnp.ndarray:
    """Nodal sum of edge vectors acting ``+f`` on node j and ``-f`` on j+1."""
    if periodic:
        return f - jnp.roll(f, 1, axis=1)
    return jnp.pad(f, ((0, 0), (0, 1), (0, 0))) - jnp.pad(f, ((0, 0), (1, 0), (0, 0)))


def scatter_cell_corners(c00, c10, c11, c01, periodic: bool) -> jnp.ndarray:
    """Nodal sum of per-cell values given at the cell's four corners.

    ``c00`` belongs to node (i, j), ``c10`` to (i+1, j), ``c11`` to
    (i+1, j+1), ``c01`` to (i, j+1); cells are (ns-1, ncell, ...).
    """
    def pad_i(a, lo):
        return jnp.pad(a, [(lo, 1 - lo)] + [(0, 0)] * (a.ndim - 1))

    at_j = pad_i(c00, 0) + pad_i(c10, 1)  # contributions to the cell's j column
    at_j1 = pad_i(c01, 0) + pad_i(c11, 1)  # contributions to its j+1 column
    if periodic:
        return at_j + jnp.roll(at_j1, 1, axis=1)
    pad_lo = [(0, 0), (0, 1)] + [(0, 0)] * (at_j.ndim - 2)
    pad_hi = [(0, 0), (1, 0)] + [(0, 0)] * (at_j.ndim - 2)
    return jnp.pad(at_j, pad_lo) + jnp.pad(at_j1, pad_hi)


def cell_corners(x: jnp.ndarray, periodic: bool):
    """The four corner arrays (n00, n10, n11, n01) of every cell."""
    lo, hi = x[:-1], x[1:]
    return this_j(lo, periodic), this_j(hi, periodic), next_j(hi, periodic), next_j(lo, periodic)
