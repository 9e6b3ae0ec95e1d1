"""The sparse Jacobian ``dR/dx`` of the force residual (eq. 10-15), from coloured JVPs (docs/architecture.md).

The static force residual ``R(x)`` of `forces.residual` couples each node to
its 3x3 neighbourhood only, so a handful of Jacobian-vector products give the
whole sparse Jacobian ``J = dR/dx`` (N/m) on the free degrees of freedom:

* Locality. On the structured grid the force on node ``(i, j)`` depends only
  on the nodes ``(i', j')`` with ``|i' - i| <= 1`` and ``|j' - j| <= 1``
  (``j`` taken modulo ``n_contour`` on a closed contour), checked against
  `forces`: the span-edge force of edge ``(i+1/2, j)`` sums the tensions of
  cells ``(i+1/2, j-1/2)`` and ``(i+1/2, j+1/2)``, each a function of its four
  corners only (stretches of eq. 12 of its two span and two contour edges,
  tensions of eq. 10); the contour-edge force of ``(i, j+1/2)`` likewise
  sums cells ``(i-1/2, j+1/2)`` and ``(i+1/2, j+1/2)``; edge directions
  (eq. 13) depend on the edge's two nodes; the pressure area vector of a
  node (eq. 15) sums quarter-cell contributions of its (up to four) adjacent
  cells, each a function of that cell's corners; gravity is constant. Every
  one of these lies in the 3x3 block of nodes around ``(i, j)``, so each row
  of ``J`` has at most 27 non-zeros.
* Colouring. Two columns may share one seed vector when no row sees both.
  Column ``(i, j, c)`` gets colour ``(i mod 3, j mod 3, c)``: same-coloured
  nodes are at least 3 apart in each index, so no 3x3 block holds two of
  them. 27 colours on an open grid. On a closed contour ``j mod 3`` wraps
  correctly only if ``n_contour % 3 == 0``; otherwise the last
  ``n_contour % 3`` contour columns get colours of their own (36 or 45).
* One ``jax.vmap`` of ``jax.jvp`` over the colour seeds gives every column
  of ``J`` compressed; the known sparsity pattern decompresses it into a
  `scipy.sparse.csc_matrix`.

The factor of ``J`` (`JacobianFactor`, made by `factorise`) serves Newton (`newton`), chord Newton
warm starts and the adjoint solves of the implicit derivative (`derivatives.implicit`).
"""

from __future__ import annotations

import functools
import threading
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .. import forces as fk
from ..precision import float64_scope
from ..compilation import stored_jit
from . import threads

__all__ = ["PERMC_SPEC", "ORDERED_OPTIONS", "Sparsity", "JacobianFactor", "OrderedLU", "jacobian_sparsity", "free_dofs",
           "assemble_jacobian", "factorise"]

#: Column ordering of SuperLU. The pattern is structurally symmetric, so a
#: minimum-degree ordering of ``J^T + J`` fits it; measured on a 33x257 closed
#: grid (one core): 0.17 s and 4.0e6 factor non-zeros against 0.58 s and
#: 1.0e7 for the default COLAMD.
PERMC_SPEC = "MMD_AT_PLUS_A"
#: SuperLU's options for a matrix already in that order (`factorise`): no ordering of its own, and the
#: diagonal as pivot wherever it is at least a tenth of its column's largest entry (threshold
#: pivoting, the diagonal preferred). Measured on a 17x64 bay of the 40-cell wing (2,835 unknowns):
#: 3.1-3.7 ms against 4.5 ms a factorisation, the same fill (256,263 against 256,381 non-zeros).
ORDERED_OPTIONS = {"SymmetricMode": True, "DiagPivotThresh": 0.1}


class Sparsity(NamedTuple):
    """Sparsity pattern and column colouring of ``dR/dx`` on a full grid.

    Degrees of freedom are numbered as ``x.reshape(-1)`` of an
    ``(n_span, n_contour, 3)`` array: ``dof = (i * n_contour + j) * 3 + c``.

    Attributes:
        rows: ``(nnz,)`` row dof of every structural non-zero.
        cols: ``(nnz,)`` column dof of every structural non-zero.
        colours: ``(n_dof,)`` colour of every column.
        n_colours: number of colours (27, 36 or 45).
    """

    rows: np.ndarray
    cols: np.ndarray
    colours: np.ndarray
    n_colours: int


class FreePattern(NamedTuple):
    """The pattern restricted to free dofs, in CSC order, with its gather indices."""

    free_dofs: np.ndarray  # (nf,) full dof index of each free dof
    indices: np.ndarray  # CSC row indices (reduced numbering)
    indptr: np.ndarray  # CSC column pointers
    gather_colour: np.ndarray  # (nnz_free,) colour of each non-zero's column
    gather_row: np.ndarray  # (nnz_free,) full row dof of each non-zero
    colours: np.ndarray  # (n_dof,) int32 column colours
    n_colours: int


class JacobianFactor(NamedTuple):
    """A sparse LU of the Jacobian on the free dofs, kept on a `Solution` for reuse.

    Attributes:
        lu: the LU of ``jacobian - shift * D`` (`factorise`: an `OrderedLU`, or a
            `scipy.sparse.linalg.SuperLU`); ``J^T y = b`` is ``lu.solve(b, trans="T")``.
        jacobian: the unshifted ``dR/dx`` on the free dofs, N/m,
            `scipy.sparse.csc_matrix`.
        free_dofs: ``(n_free,)`` index of each row/column into ``x.reshape(-1)``.
        shift: the Levenberg shift ``mu`` of ``lu`` (0.0 when unshifted).
        current: True when ``lu`` is the LU of the unshifted Jacobian at the
            solution's own nodes, so it serves adjoint solves as it is.
    """

    lu: object
    jacobian: sp.csc_matrix | None
    free_dofs: np.ndarray
    shift: float
    current: bool


# ------------------------------------------------------------------ sparsity
def _contour_colours(n_contour: int, periodic: bool) -> tuple[np.ndarray, int]:
    """Colour of each contour index ``j`` and the number of contour colours."""
    j = np.arange(n_contour)
    colour = j % 3
    extra = n_contour % 3 if periodic else 0
    if extra:
        # The wrap joins j = n_contour-1 to j = 0: the last `extra` columns
        # would sit closer than 3 to a same-coloured one, so they get their own.
        last = np.arange(n_contour - extra, n_contour)
        colour[last] = 3 + (last - (n_contour - extra))
    return colour, 3 + extra


@functools.lru_cache(maxsize=16)
def jacobian_sparsity(shape: tuple[int, int], periodic: bool) -> Sparsity:
    """The `Sparsity` of ``dR/dx`` on an ``(n_span, n_contour)`` grid, closed contour when ``periodic``.

    Row ``(i, j, c)`` has non-zeros in the columns of its 3x3 node
    neighbourhood, any component; the columns are coloured as the module
    docstring says. Cached per ``(shape, periodic)``; the arrays are read-only.
    """
    ns, nc = (int(s) for s in shape)
    node = np.arange(ns * nc).reshape(ns, nc)
    row_nodes, col_nodes = [], []
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            i = np.arange(ns)[:, None]
            j = np.arange(nc)[None, :]
            i2 = i + di
            j2 = j + dj
            if periodic:
                j2 = j2 % nc
            ok = (i2 >= 0) & (i2 < ns) & (j2 >= 0) & (j2 < nc)
            ok = np.broadcast_to(ok, (ns, nc))
            i2 = np.broadcast_to(np.clip(i2, 0, ns - 1), (ns, nc))
            j2 = np.broadcast_to(np.clip(j2, 0, nc - 1), (ns, nc))
            row_nodes.append(node[ok])
            col_nodes.append(node[i2[ok], j2[ok]])
    pairs = np.unique(np.stack([np.concatenate(row_nodes), np.concatenate(col_nodes)]), axis=1)
    c = np.arange(3)
    rows = (3 * pairs[0][:, None, None] + c[:, None]).repeat(3, axis=2).reshape(-1)
    cols = (3 * pairs[1][:, None, None] + c[None, :]).repeat(3, axis=1).reshape(-1)

    contour_colour, n_contour_colours = _contour_colours(nc, periodic)
    node_colour = (np.arange(ns)[:, None] % 3) * n_contour_colours + contour_colour[None, :]
    colours = (3 * node_colour[..., None] + c).reshape(-1)
    sparsity = Sparsity(rows.astype(np.int64), cols.astype(np.int64), colours.astype(np.int64),
                        9 * n_contour_colours)
    for a in sparsity[:3]:
        a.setflags(write=False)  # shared through the cache
    return sparsity


@functools.lru_cache(maxsize=16)
def _free_pattern(shape: tuple[int, int], periodic: bool, free_key: bytes) -> FreePattern:
    """The pattern of `jacobian_sparsity` on the free dofs, in CSC order."""
    sparsity = jacobian_sparsity(shape, periodic)
    free_node = np.frombuffer(free_key, dtype=bool).reshape(shape)
    free_dof = np.repeat(free_node.reshape(-1), 3)
    reduced = np.cumsum(free_dof) - 1
    keep = free_dof[sparsity.rows] & free_dof[sparsity.cols]
    rows, cols = sparsity.rows[keep], sparsity.cols[keep]
    order = np.lexsort((rows, cols))  # column-major: CSC order
    rows, cols = rows[order], cols[order]
    n_free = int(free_dof.sum())
    indptr = np.concatenate([[0], np.cumsum(np.bincount(reduced[cols], minlength=n_free))])
    pattern = FreePattern(
        free_dofs=np.flatnonzero(free_dof),
        indices=reduced[rows].astype(np.int32),
        indptr=indptr.astype(np.int32),
        gather_colour=sparsity.colours[cols].astype(np.int32),
        gather_row=rows.astype(np.int32),
        colours=sparsity.colours.astype(np.int32),
        n_colours=sparsity.n_colours,
    )
    for a in pattern[:6]:
        a.setflags(write=False)  # shared through the cache
    return pattern


def _free_nodes(owner) -> np.ndarray:
    """``(n_span, n_contour)`` the free nodes of a `forces.Reference` or of the `forces.Geometry` it is
    prepared from (the same nodes: the geometry's are made once per bay, and NumPy's copy of them is
    kept with them; a fresh reference's waited for its program and came over from the device each
    time, 0.5 s of the 40-cell wing's design). On the host: no eager slice to compile."""
    free = np.asarray(owner.free)
    return (free[..., 0] if free.ndim == 3 else free) > 0.5


def sparsity_pattern(owner, periodic: bool) -> FreePattern:
    """The Jacobian's `FreePattern` on the free nodes of ``owner`` (`_free_nodes`)."""
    free_node = _free_nodes(owner)
    return _free_pattern(free_node.shape, bool(periodic), free_node.tobytes())


def free_dofs(owner) -> np.ndarray:
    """Index of each free degree of freedom into ``x.reshape(-1)`` (the Jacobian's numbering), of the
    free nodes of ``owner``: a `forces.Reference` or its `forces.Geometry` (`_free_nodes`)."""
    return np.flatnonzero(np.repeat(_free_nodes(owner).reshape(-1), 3))


# ------------------------------------------------------------------ jacobian
@stored_jit(static_argnames=("physics", "n_colours"))
def _jacobian_values(x, ref, params, colours, gather_colour, gather_row, physics, n_colours):
    """Residual and the Jacobian's structural non-zeros from one vmap of jvp over the colours."""
    physics = fk.static_physics(physics)
    free = jnp.broadcast_to(ref.free, x.shape).reshape(-1)
    seeds = (colours[None, :] == jnp.arange(n_colours, dtype=colours.dtype)[:, None]).astype(x.dtype)
    seeds = seeds * free

    def flat_residual(flat):
        return fk.residual(flat.reshape(x.shape), ref, params, physics).reshape(-1)

    def column_group(seed):
        return jax.jvp(flat_residual, (x.reshape(-1),), (seed,))

    r, compressed = jax.vmap(column_group, out_axes=(None, 0))(seeds)
    return r, compressed[gather_colour, gather_row]


def linearise(x, ref, params, physics, pattern: FreePattern):
    """``(J, R_free)`` at ``x``: the free-dof Jacobian (csc, N/m) and residual (N)."""
    r, data = _jacobian_values(jnp.asarray(x), ref, params, pattern.colours, pattern.gather_colour,
                               pattern.gather_row, physics, pattern.n_colours)
    n = pattern.free_dofs.size
    # Copies: scipy may sort or prune index arrays in place, and these are cached.
    jac = sp.csc_matrix((np.asarray(data, dtype=np.float64), pattern.indices.copy(),
                         pattern.indptr.copy()), shape=(n, n))
    return jac, np.asarray(r, dtype=np.float64)[pattern.free_dofs]


def assemble_jacobian(x, ref: fk.Reference, params: fk.KernelInputs, physics: fk.Physics) -> sp.csc_matrix:
    """Sparse Jacobian ``dR/dx`` of `forces.residual` on the free degrees of freedom.

    One ``jax.vmap`` of ``jax.jvp`` over the colour seeds (27 to 45 products,
    compiled once per grid shape and physics), decompressed along the sparsity
    pattern: an ``(n_free, n_free)`` `scipy.sparse.csc_matrix` in N/m, rows and
    columns the free dofs of ``ref.free`` in the order of `free_dofs`, at the
    ``(n_span, n_contour, 3)`` nodes ``x`` (m). The velocity terms of
    ``physics`` are ignored (static residual).
    """
    with float64_scope(x, ref, params):
        return linearise(x, ref, params, physics, sparsity_pattern(ref, physics.periodic))[0]


# ------------------------------------------------------------------ factor
class OrderedLU:
    """The LU of ``J`` made as SuperLU's of ``J[order][:, order]`` (`factorise`); solves with ``J`` itself.

    Made on the wing's helper thread (`threads.each`), its SuperLU is kept and finally freed there
    (`threads.keep`: SciPy's SuperLU frees a factor's memory only on the thread that made it).

    Attributes:
        lu: the `scipy.sparse.linalg.SuperLU` of the reordered matrix.
        order: ``(n,)`` the symmetric permutation.
    """

    __slots__ = ("_lu", "_key", "order")

    def __init__(self, lu, order: np.ndarray):
        self._lu, self._key, self.order = lu, None, order
        if threads.on_helper():
            self._lu, self._key = None, threads.keep(lu)

    def __del__(self):
        if getattr(self, "_key", None) is not None:
            threads.release(self._key)

    @property
    def lu(self):
        return self._lu if self._key is None else threads.kept(self._key)

    @property
    def shape(self) -> tuple[int, int]:
        return self.lu.shape

    @property
    def nnz(self) -> int:
        """The non-zeros of its L and U factors."""
        return self.lu.nnz

    def solve(self, b, trans: str = "N") -> np.ndarray:
        """``J^-1 b`` (``trans="N"``) or ``J^-T b`` ("T"); ``b`` of shape ``(n,)`` or ``(n, k)``."""
        b = np.asarray(b)
        x = np.empty(b.shape, np.result_type(b.dtype, np.float64))
        x[self.order] = self.lu.solve(np.ascontiguousarray(b[self.order]), trans=trans)
        return x


class _Reordering(NamedTuple):
    order: np.ndarray  # the symmetric permutation
    gather: np.ndarray  # the reordered matrix's values are the matrix's at these positions
    indices: np.ndarray  # the reordered matrix's CSC row indices ...
    indptr: np.ndarray  # ... and column pointers


_REORDERINGS: dict = {}  # (in the order last used)
_REORDERINGS_LOCK = threading.Lock()
#: Structures whose reordering `factorise` keeps, the most recently used (the grids of a run are few).
_MAX_REORDERINGS = 16


def _reordering(matrix: sp.csc_matrix, order: np.ndarray) -> _Reordering:
    """How to make ``matrix[order][:, order]`` (sorted CSC) from ``matrix.data`` alone."""
    n = matrix.shape[0]
    positions = sp.csc_matrix((np.arange(1, matrix.nnz + 1, dtype=np.float64), matrix.indices, matrix.indptr),
                              shape=(n, n))[order][:, order].tocsc()
    positions.sort_indices()
    return _Reordering(order, positions.data.astype(np.int64) - 1, positions.indices, positions.indptr)


def factorise(matrix: sp.csc_matrix, permc_spec: str = PERMC_SPEC):
    """The sparse LU of ``matrix`` (CSC): ``.solve(b, trans="N" | "T")``.

    With the default ordering (`PERMC_SPEC`), SuperLU orders a structure the first time it meets it; every
    matrix of that structure is then reordered by that permutation on both sides and factorised without
    ordering again (`ORDERED_OPTIONS`, an `OrderedLU`): a Newton solve factorises the same structure at
    every iteration, and a design every bay at every iterate. The first matrix of a structure is
    factorised twice (ordered, then reordered), so that its factor and every later one's are the same
    to the bit whatever the process met before. Another ``permc_spec``: SuperLU's own
    (`scipy.sparse.linalg.splu`).

    Raises:
        RuntimeError: when the matrix is exactly singular (SuperLU's).
    """
    if permc_spec != PERMC_SPEC:
        return spla.splu(matrix, permc_spec=permc_spec)
    matrix = sp.csc_matrix(matrix)
    matrix.sum_duplicates()  # (canonical: sorted indices, no duplicates; a no-op for the solver's matrices)
    key = (matrix.shape, matrix.indptr.tobytes(), matrix.indices.tobytes())
    with _REORDERINGS_LOCK:  # (a wing's bays are factorised two at a time: `threads.each`)
        reordering = _REORDERINGS.pop(key, None)
    if reordering is None:  # SuperLU's ordering of this structure (its numeric factor is not used: every
        # factor of a structure comes from the same reordered matrix, whatever the process met before)
        reordering = _reordering(matrix, np.argsort(spla.splu(matrix, permc_spec=permc_spec).perm_c))
    with _REORDERINGS_LOCK:
        _REORDERINGS.pop(key, None)  # (another thread's, meanwhile)
        while len(_REORDERINGS) >= _MAX_REORDERINGS:
            _REORDERINGS.pop(next(iter(_REORDERINGS)))  # the least recently used
        _REORDERINGS[key] = reordering  # (the most recently used now)
    reordered = sp.csc_matrix((matrix.data[reordering.gather], reordering.indices.copy(), reordering.indptr.copy()),
                              shape=matrix.shape)
    return OrderedLU(spla.splu(reordered, permc_spec="NATURAL", options=ORDERED_OPTIONS), reordering.order)
