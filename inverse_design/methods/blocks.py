"""The design Jacobian bay by bay: each bay's outputs in the variables that touch it, stored sparse.

A bay's equilibrium (eq. 10-15 between its two rigid ribs) depends on the
shared variables (pressure, uniform prestrains, rib scales, a shared rib shape
or cut field), on its own row of a per-bay cut field and on its two ribs'
rows of per-rib shapes, and on nothing else. So its shape
residuals and cell tensions have a Jacobian block of ``shared + per-bay + 2 x
per-rib`` columns; the rest of the wing's Jacobian in those rows is zero.

Those blocks come from one forward-mode pass through the whole wing with
``shared + per-bay + 2 x per-rib`` tangents (`compressed_seeds`, the
Curtis-Powell-Reid compression of a structured Jacobian): a shared
variable's tangent is its own; a per-bay coefficient's tangent moves that
coefficient of every bay at once (each bay sees only its own); a per-rib
coefficient's tangent moves it on every other rib (even ribs, then odd ones),
so that each bay sees one of its two ribs per tangent. Each bay then
back-solves ``shared + per-bay + 2 x per-rib`` tangents with its kept LU
factor, and `decompress` puts every entry in its column as a
``scipy.sparse`` matrix. A dense forward mode pushes every variable's
tangent through every bay instead (``n_variables x n_bays`` back-solves and
an ``n_outputs x n_variables`` matrix: 8.7 GB on 40 bays of 17x64 with 481
variables). The forward pass itself is
`forward_solver.derivatives.forward.value_and_jacobian`.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse

__all__ = ["compressed_seeds", "decompress", "rib_columns"]


def _layout(variables):
    """``(shared columns, (start, width) of a per-bay field or None, (start, width) of per-rib shapes or None)``."""
    shared, per_bay, per_rib = [], None, None
    for name, part in variables.slices().items():
        if name == "cut_pattern" and variables.cut_patterns is not None:
            per_bay = (part.start, variables.cut_patterns.shape[1])
        elif name == "rib_shape" and variables.rib_shapes is not None:
            per_rib = (part.start, variables.rib_shapes.shape[1])
        else:
            shared.extend(range(part.start, part.stop))
    return shared, per_bay, per_rib


def compressed_seeds(variables, n_bays: int):
    """The tangents of one forward pass that give every bay's Jacobian block, and where each entry goes.

    Args:
        variables: the `variables.DesignVariables`.
        n_bays: bays of the wing.

    Returns:
        ``(seeds, columns)``: ``seeds`` an ``(n_seeds, n_variables)`` array of
        tangents (``n_seeds`` = shared + per-bay + 2 x per-rib components);
        ``columns`` an ``(n_bays, n_seeds)`` integer array: the variable whose
        derivative tangent ``j`` gives in bay ``k``'s outputs.
    """
    shared, per_bay, per_rib = _layout(variables)
    n = variables.size
    seeds, columns = [], []
    for c in shared:
        seed = np.zeros(n)
        seed[c] = 1.0
        seeds.append(seed)
        columns.append(np.full(n_bays, c))
    if per_bay is not None:
        start, width = per_bay
        for i in range(width):
            seed = np.zeros(n)
            seed[start + i:start + n_bays * width:width] = 1.0
            seeds.append(seed)
            columns.append(start + np.arange(n_bays) * width + i)
    if per_rib is not None:
        start, width = per_rib
        bays = np.arange(n_bays)
        for parity in (0, 1):
            for i in range(width):
                seed = np.zeros(n)
                seed[start + parity * width + i:start + (n_bays + 1) * width:2 * width] = 1.0
                seeds.append(seed)
                rib = np.where(bays % 2 == parity, bays, bays + 1)  # the bay's root or tip rib of this parity
                columns.append(start + rib * width + i)
    return np.array(seeds).reshape(-1, n), np.array(columns, dtype=np.int64).T.reshape(n_bays, -1)


def rib_columns(variables, seeds):
    """Where the entries of the ribs' own rows (the rib limits, which depend on the shared variables and on
    their rib's row of per-rib shapes alone) go, pushed along the bays' ``seeds`` (`compressed_seeds`): an
    ``(n_ribs, n_seeds)`` integer array as its ``columns``, one row per rib, for `decompress`. Read off the
    seeds: a seed's column among the rib's own, or for a seed that moves none of them (a per-bay
    coefficient, a per-rib one of the other parity) the first it moves, whose derivative is a zero
    (then dropped) in a column that no other seed moves.

    Raises:
        ValueError: for variables without per-rib shapes (the ribs then share every column).
    """
    shared, _, per_rib = _layout(variables)
    if per_rib is None:
        raise ValueError("rib_columns needs per-rib shapes (variables.rib_shapes); without them every rib "
                         "row moves with the shared columns alone")
    start, width = per_rib
    moved = np.asarray(seeds) != 0.0  # (n_seeds, n_variables); the seeds move disjoint columns
    first = np.argmax(moved, axis=1)
    n_ribs = variables.rib_shapes.shape[0]
    columns = np.empty((n_ribs, moved.shape[0]), np.int64)
    for k in range(n_ribs):
        own = np.zeros(moved.shape[1], bool)
        own[shared] = True
        own[start + k * width:start + (k + 1) * width] = True
        hits = moved & own
        columns[k] = np.where(hits.any(axis=1), np.argmax(hits, axis=1), first)
    return columns


def decompress(compressed, row_bays, columns, n_columns: int) -> scipy.sparse.csr_matrix:
    """The sparse Jacobian of a compressed one (`compressed_seeds`).

    Args:
        compressed: ``(n_rows, n_seeds)`` derivatives along the seeds.
        row_bays: ``(n_rows,)`` the bay of each row.
        columns: ``(n_bays, n_seeds)`` from `compressed_seeds`.
        n_columns: variables.

    Returns:
        ``(n_rows, n_columns)`` CSR matrix.
    """
    compressed = np.asarray(compressed, np.float64)
    n_rows, n_seeds = compressed.shape
    columns = np.asarray(columns)
    # Every row holds one entry per seed, in distinct columns: the CSR arrays directly, each row's
    # columns in order (a COO matrix sorted into CSR took 0.5 s an iterate on 40 bays of 17x64).
    row_bays = np.asarray(row_bays)
    order = np.argsort(columns, axis=1)
    cols = np.take_along_axis(columns, order, axis=1)[row_bays]
    values = np.take_along_axis(compressed, order[row_bays], axis=1)
    index = np.int32 if n_columns < 2**31 and n_rows * n_seeds < 2**31 else np.int64
    matrix = scipy.sparse.csr_matrix((values.reshape(-1), cols.reshape(-1).astype(index),
                                      np.arange(0, n_rows * n_seeds + 1, n_seeds, dtype=index)),
                                     shape=(n_rows, n_columns))
    matrix.has_sorted_indices = True
    matrix.eliminate_zeros()
    return matrix
