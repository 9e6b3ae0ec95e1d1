"""The design Jacobian bay by bay: each bay's outputs in the variables that touch it, stored sparse.

A bay's equilibrium (eq. 10-15 between its two rigid ribs) depends on the
shared variables (pressure, uniform prestrains, rib scales, a shared rib shape
or cut field), on its own row of a per-bay cut field and on its two ribs'
rows of per-rib shapes, and on nothing else (`bay_columns`). So its shape
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
variables).

`implicit_equilibrium` and `bay_jacobian` are the same derivative for one
bay alone (a converged solve's nodes, differentiated by the implicit function
theorem with its own factor, without solving again): for callers that need
one bay's block, such as a tolerance analysis.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse

from forward_solver.derivatives.custom_jvp import concrete_parameters
from forward_solver.derivatives.implicit import ImplicitAdjoint, forward_only
from forward_solver.derivatives.rhs import kernel_tangent

__all__ = ["bay_columns", "compressed_seeds", "decompress", "implicit_equilibrium", "bay_jacobian", "block_rows"]


def bay_columns(variables, n_bays: int) -> list[np.ndarray]:
    """The columns of the scaled design vector that move each bay, root to tip.

    Args:
        variables: the `variables.DesignVariables`.
        n_bays: bays of the wing.

    Returns:
        Per bay, the sorted indices into the scaled vector: every shared
        component, the bay's row of a per-bay cut field, its two ribs' rows of
        per-rib shapes.
    """
    shared, per_bay, per_rib = _layout(variables)
    columns = []
    for k in range(n_bays):
        own = list(shared)
        if per_bay is not None:
            start, width = per_bay
            own.extend(range(start + k * width, start + (k + 1) * width))
        if per_rib is not None:
            start, width = per_rib
            own.extend(range(start + k * width, start + (k + 2) * width))
        columns.append(np.array(sorted(own), dtype=np.int64))
    return columns


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


def implicit_equilibrium(scene, solution):
    """``parameters -> nodes``: a converged solve's nodes, differentiable by the implicit function theorem.

    The primal is ``solution.nodes`` whatever the parameters (they must be the
    ones it was solved at); the tangent is ``-J^-1 dR/dtheta . dtheta`` plus
    the ribs' motion (`forward_solver.derivatives.implicit.ImplicitAdjoint` with the
    solve's own LU factor when it is current, else a fresh one, made once).
    Under ``jax.vmap`` of ``jax.jvp`` within `forward_solver.derivatives.implicit.forward_only`
    every tangent of the batch is back-solved in one host call.

    Args:
        scene: the bay's `forward_solver.Scene`.
        solution: its converged `forward_solver.Solution` (concrete nodes, m).

    Returns:
        A function of the bay's `forward_solver.Parameters` (JAX values
        allowed under ``jax.jvp``) returning ``(n_span, n_contour, 3)`` nodes, m.
    """
    x_host = np.asarray(solution.nodes, np.float64)  # made a JAX array at the call (float64 on there)
    geometry = scene.bay.geometry()
    physics = scene.physics(dynamic=False)
    made = {}

    @jax.custom_jvp
    def nodes(parameters):
        return jnp.asarray(x_host, jnp.float64)

    @nodes.defjvp
    def nodes_jvp(primals, tangents):
        (parameters,), (dparameters,) = primals, tangents
        x = jnp.asarray(x_host, jnp.float64)
        params = scene.params(concrete_parameters(parameters))
        if "adjoint" not in made:
            made["adjoint"] = ImplicitAdjoint("lu").at(x, geometry, params, physics, factor=solution.factor)
        return x, made["adjoint"].tangent(kernel_tangent(dparameters, params))

    return nodes


def bay_jacobian(outputs, u, columns):
    """``outputs(v)`` at the scaled vector ``u`` and its Jacobian in ``v[columns]`` (forward mode).

    Args:
        outputs: ``v -> (y, aux)`` of a JAX vector ``v`` (the whole scaled
            vector), differentiable in ``v[columns]`` only through
            `implicit_equilibrium` and plain JAX.
        u: ``(n_variables,)`` the scaled vector.
        columns: the indices of the variables that move ``y``.

    Returns:
        ``(y, block, aux)``: the values, the ``(len(y), len(columns))`` Jacobian
        (NumPy) and the auxiliary output at ``u``.
    """
    base = jnp.asarray(u, jnp.float64)
    columns = np.asarray(columns)

    def restricted(w):
        return outputs(base.at[columns].set(w))

    def push(t):
        return jax.jvp(restricted, (base[columns],), (t,), has_aux=True)

    with forward_only(columns.size):
        y, dy, aux = jax.vmap(push, out_axes=(None, 0, None))(np.eye(columns.size, dtype=np.float64))
    return np.asarray(y), np.asarray(dy).T, aux


def block_rows(blocks, row_offsets, columns, n_rows: int, n_columns: int, scales=None) -> scipy.sparse.csr_matrix:
    """The sparse matrix of dense blocks: block ``i`` at rows ``row_offsets[i] + arange(len)``, columns ``columns[i]``.

    Args:
        blocks: dense ``(rows_i, len(columns[i]))`` arrays.
        row_offsets: first row of each block.
        columns: the column indices of each block.
        n_rows: rows of the matrix.
        n_columns: columns of the matrix.
        scales: a factor per block (default 1).

    Returns:
        A ``(n_rows, n_columns)`` CSR matrix.
    """
    data, rows, cols = [], [], []
    for i, (block, offset, cols_i) in enumerate(zip(blocks, row_offsets, columns)):
        block = np.asarray(block, np.float64)
        r, c = np.nonzero(block)
        data.append(block[r, c] * (1.0 if scales is None else scales[i]))
        rows.append(r + offset)
        cols.append(np.asarray(cols_i)[c])
    if not data:
        return scipy.sparse.csr_matrix((n_rows, n_columns))
    return scipy.sparse.csr_matrix((np.concatenate(data), (np.concatenate(rows), np.concatenate(cols))),
                                   shape=(n_rows, n_columns))
