"""The design Jacobian bay by bay: each bay's outputs in the variables that touch it, stored sparse.

A bay's equilibrium (eq. 10-15 between its two rigid ribs) depends on the
shared variables (pressure, uniform prestrains, rib scales, a shared rib shape
or cut field), on its own row of a per-bay cut field and on its two ribs'
rows of per-rib shapes, and on nothing else. So its shape residuals and cell
tensions have a Jacobian block of ``shared + per-bay + 2 x per-rib`` columns
(`bay_columns`); the rest of the wing's Jacobian in those rows is zero.
`bay_jacobian` computes one block by forward mode through the implicit
equilibrium (`implicit_equilibrium`: one back-solve per column with the
bay's kept LU factor, all columns in one host call), and `block_rows`
assembles the blocks into a ``scipy.sparse`` matrix. Per Gauss-Newton
iterate that is one wing solve plus ``shared + per-bay + 2 x per-rib``
back-solves per bay, where a dense forward mode pushes every variable's
tangent through every bay (``n_variables x n_bays`` back-solves, a dense
``n_outputs x n_variables`` matrix: 8.7 GB on 40 bays of 17x64 with 481
variables).

`implicit_equilibrium` is the reusable piece: a function of one bay's
`forward_solver.Parameters` that returns a converged solve's nodes and
differentiates them by the implicit function theorem (`forward_solver.implicit.ImplicitAdjoint`)
with that solve's own factor, without solving again.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse

from forward_solver.adjoint import _concrete, _kernel_tangent
from forward_solver.implicit import ImplicitAdjoint, forward_only

__all__ = ["bay_columns", "implicit_equilibrium", "bay_jacobian", "block_rows"]


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
    shared, per_bay, per_rib = [], None, None
    for name, part in variables.slices().items():
        if name == "cut_pattern" and variables.cut_patterns is not None:
            per_bay = (part.start, variables.cut_patterns.shape[1])
        elif name == "rib_shape" and variables.rib_shapes is not None:
            per_rib = (part.start, variables.rib_shapes.shape[1])
        else:
            shared.extend(range(part.start, part.stop))
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


def implicit_equilibrium(scene, solution):
    """``parameters -> nodes``: a converged solve's nodes, differentiable by the implicit function theorem.

    The primal is ``solution.nodes`` whatever the parameters (they must be the
    ones it was solved at); the tangent is ``-J^-1 dR/dtheta . dtheta`` plus
    the ribs' motion (`forward_solver.implicit.ImplicitAdjoint` with the
    solve's own LU factor when it is current, else a fresh one, made once).
    Under ``jax.vmap`` of ``jax.jvp`` within `forward_solver.implicit.forward_only`
    every tangent of the batch is back-solved in one host call.

    Args:
        scene: the bay's `forward_solver.Scene`.
        solution: its converged `forward_solver.Solution` (concrete nodes, m).

    Returns:
        A function of the bay's `forward_solver.Parameters` (JAX values
        allowed under ``jax.jvp``) returning ``(n_span, n_contour, 3)`` nodes, m.
    """
    x = jnp.asarray(np.asarray(solution.nodes, np.float64))
    geometry = scene.bay.geometry()
    physics = scene.physics(dynamic=False)
    made = {}

    @jax.custom_jvp
    def nodes(parameters):
        return x

    @nodes.defjvp
    def nodes_jvp(primals, tangents):
        (parameters,), (dparameters,) = primals, tangents
        params = scene.params(_concrete(parameters))
        if "adjoint" not in made:
            made["adjoint"] = ImplicitAdjoint(x, geometry, params, physics, "lu", factor=solution.factor)
        return x, made["adjoint"].tangent(_kernel_tangent(dparameters, params))

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
