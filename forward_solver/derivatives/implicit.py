"""The implicit derivative of an equilibrium: one right-hand side, one linear solve, two linear solvers.

At an equilibrium the static residual of eq. (10)-(15) vanishes on the free
degrees of freedom, ``R(x*(theta), theta) = 0``, so (implicit function
theorem) ``dx*/dtheta = -J^-1 dR/dtheta`` with ``J = dR/dx`` on the free
dofs. `ImplicitAdjoint` is that rule at one equilibrium:

* the right-hand side (`parameter_rhs`) is built here only: one ``jax.jvp``
  of `forces.residual` in the kernel parameters, through `forces.prepare`
  (the cut lengths see the prestrain) and through the held (rib) nodes,
  which move with the rib scales and shapes; that motion is the tangent of
  the held nodes;
* the operator is ``J`` on the full node array with the held dofs mapped to
  themselves (`jacobian_matvec`; the residual is zero there, so the held
  part of the solution is zero and the held nodes' motion is added after);
* the solve is one ``jax.lax.custom_linear_solve``, so reverse mode
  transposes it into the adjoint system ``J^T lambda = xbar`` with the same
  solver's transpose: one adjoint solve per gradient, whatever the number
  of parameters; forward and reverse mode cannot disagree;
* a caller that takes forward-mode derivatives only (the design's Jacobian)
  may say so (`forward_only`): the "lu" tangents of a batch are then solved
  on the host as arrays, without the transposable program;
* the linear solver is pluggable (``linear_solver``): "lu", the sparse LU
  of ``J`` on the host (`HostLU`: scipy through ``jax.pure_callback``; a
  Newton solve's own factor is reused), or "iterative", the matrix-free
  block-Jacobi BiCGStab of `krylov` in JAX (`Krylov`: no host callback, so
  it runs under ``jax.jit`` / ``jax.vmap`` and on any backend).

`solve_equilibrium`'s custom JVP (`adjoint.differentiable_solution`) and the
pure-JAX relaxation (`implicit_nodes`, used by `jit_equilibrium` and by the batched
wing) both differentiate through this one object.
"""

from __future__ import annotations

import collections
import contextlib
import contextvars
import itertools
import weakref
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse.linalg as spla
from jax.scipy.sparse.linalg import bicgstab

from .. import forces as fk
from ..solvers.jacobian import PERMC_SPEC, assemble_jacobian, free_dofs
from .krylov import KRYLOV_MAX_ITERATIONS, KRYLOV_RTOL, jacobian_operator
from ..solution import prepare_compiled
from ..compilation import compiling, signature, stored_jit

__all__ = ["LINEAR_SOLVERS", "default_linear_solver", "ImplicitAdjoint", "HostLU", "Krylov",
           "parameter_rhs", "jacobian_matvec", "implicit_nodes", "forward_only"]

#: Linear solvers of the implicit derivative: the host sparse LU, or matrix-free BiCGStab in JAX.
LINEAR_SOLVERS = ("lu", "iterative")


def default_linear_solver() -> str:
    """"lu" when JAX's default backend is the CPU, else "iterative".

    The LU lives on the host and is reached through ``jax.pure_callback``,
    which fails when JAX sees only an accelerator (``JAX_PLATFORMS=cuda``);
    the iterative solve (`krylov`) is pure JAX and runs where the rest does.
    """
    return "lu" if jax.default_backend() == "cpu" else "iterative"


def held_at_mounted(x, geometry: fk.Geometry, params: fk.KernelInputs):
    """``x`` on the free nodes, the held nodes at the mounted (rib) position of ``params``."""
    mounted = fk.mounted_nodes(geometry, params)
    free = geometry.free[..., None]
    return free * x + (1.0 - free) * mounted


@partial(jax.jit, static_argnames=("physics",))
def parameter_rhs(x, geometry: fk.Geometry, params: fk.KernelInputs, dparams: fk.KernelInputs, physics: fk.Physics):
    """``(-dR/dtheta . dtheta, dx_held)`` at the equilibrium ``x``, both ``(n_span, n_contour, 3)``.

    The first is zero on held nodes (the residual is); the second, the
    motion of the held nodes with the rib parameters, is zero on free ones.
    """
    physics = fk.static_physics(physics)

    def response(p):
        nodes = held_at_mounted(x, geometry, p)
        return fk.residual(nodes, fk.prepare(geometry, p, physics), p, physics), nodes

    _, (dr, dnodes) = jax.jvp(response, (params,), (dparams,))
    return -dr, (1.0 - geometry.free[..., None]) * dnodes


@stored_jit(static_argnames=("physics",))
def _batched_rhs(x, geometry: fk.Geometry, params: fk.KernelInputs, dparams: fk.KernelInputs, physics: fk.Physics):
    """`parameter_rhs` of a batch of tangents (a leading axis on every leaf of ``dparams``): one
    program, ``jax.vmap(parameter_rhs)``, that a caller holding the batch as arrays calls at top
    level, so that it compiles ahead (`batched_rhs_task`) and is found in the persistent cache
    without batching a traced program in every process."""
    return jax.vmap(partial(parameter_rhs, physics=physics), in_axes=(None, None, None, 0))(
        x, geometry, params, dparams)


def batched_rhs_task(geometry: fk.Geometry, params: fk.KernelInputs, physics: fk.Physics, n_tangents: int):
    """``(key, task)`` for `ahead.Ahead.submit`: compile `_batched_rhs` for ``n_tangents`` tangents at
    an equilibrium on ``geometry``'s grid, as `HostLU.direct_tangent` then calls it (every leaf
    batched, float64 and strongly typed), and trace the
    one-tangent function that its ``custom_vmap`` traces before batching (`_callback_tangent`)."""
    physics = fk.static_physics(physics)
    x = jax.ShapeDtypeStruct(tuple(geometry.free.shape) + (3,), jnp.float64)
    dparams = jax.tree_util.tree_map(lambda a: jax.ShapeDtypeStruct((n_tangents,) + tuple(np.shape(a)),
                                                                    jnp.result_type(a)), params)
    key = ("tangents", signature(x, geometry, params), physics, n_tangents)
    compile_rhs = compiling(_batched_rhs, x, geometry, params, dparams, physics)
    # `HostLU.direct_tangent`'s custom_vmap traces its one-tangent function (`_callback_tangent`)
    # before it batches it: trace it here, so that the call finds its trace in JAX's cache.
    n_free = 3 * int(np.count_nonzero(np.asarray(geometry.free) > 0.5))
    one = jax.tree_util.tree_map(lambda a: jax.ShapeDtypeStruct(a.shape[1:], a.dtype), dparams)
    free = jax.ShapeDtypeStruct((n_free,), jax.dtypes.canonicalize_dtype(np.int64))  # as HostLU's
    token = jax.ShapeDtypeStruct((), jnp.int32)

    def task():
        compile_rhs()
        _callback_tangent.trace(x, geometry, params, one, free, token, physics)

    return key, task


#: Whether implicit tangents may skip transposability (`forward_only`), and how many tangents the
#: caller will ask for (a cold solve compiles their program ahead: `expected_tangents`).
_FORWARD_ONLY = contextvars.ContextVar("forward_only", default=False)
_EXPECTED_TANGENTS = contextvars.ContextVar("expected_tangents", default=None)


def expected_tangents() -> int | None:
    """Within ``forward_only(n_tangents)``: ``n_tangents``, else None."""
    return _EXPECTED_TANGENTS.get() if _FORWARD_ONLY.get() else None


@contextlib.contextmanager
def forward_only(n_tangents: int | None = None):
    """Within: the "lu" implicit tangent need not be transposable, and under a top-level ``jax.vmap``
    (``jax.jacfwd``'s batching of ``jax.jvp``) it is computed on the concrete batch of tangents:
    one `_batched_rhs` program and one host back-solve of all its columns with the LU, no host
    callback and no ``custom_linear_solve``.

    For callers that take forward-mode derivatives only (the design's ``vmap(jvp)`` Jacobian,
    `inverse_design.problem`): the transposable solve is a program that calls back to the host,
    which JAX's persistent cache never keeps, and whose trace holds the operator's JVP for the
    transpose; both were paid in every process (0.4 s of a cached run of the default case on
    the 2-core development machine). Reverse mode within raises JAX's NotImplementedError (the
    custom batching has no transpose rule); under an enclosing transformation other than the one
    ``jax.vmap`` the batch is traced (`parameter_rhs` and the host callback, as one tangent is).

    ``n_tangents``, the batch's size when known, lets a cold solve within compile the right-hand
    sides' program on the compile-ahead worker while it relaxes (`batched_rhs_task`). An LU
    factor registered within is dropped when its nodes are gone, not kept for a pullback.
    """
    token = _FORWARD_ONLY.set(True)
    expected = _EXPECTED_TANGENTS.set(n_tangents)
    try:
        yield
    finally:
        _EXPECTED_TANGENTS.reset(expected)
        _FORWARD_ONLY.reset(token)


@partial(jax.jit, static_argnames=("physics",))
def jacobian_matvec(x, geometry: fk.Geometry, params: fk.KernelInputs, v, physics: fk.Physics):
    """``J v`` on the free dofs and ``v`` on the held ones (the operator of the linear solve)."""
    physics = fk.static_physics(physics)
    ref = fk.prepare(geometry, params, physics)
    free = ref.free
    return jax.jvp(lambda y: fk.residual(y, ref, params, physics), (x,), (free * v,))[1] + (1.0 - free) * v


def _float64_on_this_thread() -> None:
    """Let a host callback return float64 when XLA runs it on one of its own threads.

    `_precision.float64_scope` turns float64 on for the calling thread only.
    XLA may run a ``jax.pure_callback`` on a worker thread of its own, where
    JAX then canonicalises the callback's float64 result to float32 and
    rejects it ("Incorrect output dtype"). On such a thread (float64 off)
    this turns float64 on for that thread, for good: it runs nothing but
    callbacks. The caller's thread is inside its float64 scope already and
    is left alone.
    """
    if not jax.config.jax_enable_x64:
        jax.enable_x64(True).__enter__()


#: The LU factors a compiled tangent may call back into, by token (`HostLU`), while their
#: equilibrium nodes live.
_FACTORS: dict = {}
#: Factors whose nodes are gone, newest last, kept within `RELEASED_FACTOR_BYTES`: a pullback
#: (``jax.vjp``, ``jax.grad``) holds copies of what it needs, not the nodes themselves.
_RELEASED: collections.OrderedDict = collections.OrderedDict()
#: Memory the released factors may keep (the newest one is always kept), bytes.
RELEASED_FACTOR_BYTES = 512 * 2**20
_TOKENS = itertools.count()
#: Tokens of factors registered within `forward_only`: no pullback can call them once their nodes
#: are gone (nothing there is transposed), so they are dropped then rather than kept among the
#: released ones. A Gauss-Newton design of 40 bays at 17x64 registers 40 factors (about 3 MB each)
#: per iterate; kept, they held `RELEASED_FACTOR_BYTES` after five iterates.
_TRANSIENT: set = set()


def _factor_bytes(factor) -> int:
    return 12 * int(getattr(factor, "nnz", 0))  # a value and an index per nonzero of L and U


def _release(token: int) -> None:
    """Move ``token``'s factor from the live to the released ones, dropping the oldest released
    factors beyond `RELEASED_FACTOR_BYTES`."""
    factor = _FACTORS.pop(token, None)
    if factor is None or token in _TRANSIENT:
        _TRANSIENT.discard(token)
        return
    _RELEASED[token] = factor
    total = sum(_factor_bytes(f) for f in _RELEASED.values())
    while len(_RELEASED) > 1 and total > RELEASED_FACTOR_BYTES:
        total -= _factor_bytes(_RELEASED.popitem(last=False)[1])


def _registered_factor(token):
    key = int(np.asarray(token).reshape(-1)[0])
    factor = _FACTORS.get(key, _RELEASED.get(key))
    if factor is None:
        raise RuntimeError("the sparse LU of this implicit derivative was released: its equilibrium is "
                           "gone and newer factors filled forward_solver.derivatives.implicit.RELEASED_FACTOR_BYTES; "
                           "call the pullback before solving much more, or differentiate again")
    return factor


def _host_solve(token, b, trans: str):
    """``J^-1 b`` (``trans="N"``) or ``J^-T b`` ("T") with the registered factor ``token``, for free-dof
    vectors ``b`` (leading batch axes allowed; float64, or its bits as `_bits`)."""
    _float64_on_this_thread()
    factor = _registered_factor(token)
    b = np.asarray(b)
    if b.dtype == np.uint32:
        b = _from_bits(b)
    b = np.asarray(b, dtype=np.float64)
    flat = b.reshape(-1, b.shape[-1]).T
    out = factor.solve(np.ascontiguousarray(flat), trans=trans)
    return out.T.reshape(b.shape)


def _bits(a):
    """float64 ``a`` as ``(..., 2)`` uint32 words: how a host callback receives float64 exactly.

    JAX hands a callback its operands through ``device_put`` on the thread XLA runs it on; where
    float64 is off on that thread (`_float64_on_this_thread`: the first callback on each of XLA's
    threads) a float64 operand arrives rounded to float32 (relative error 6e-8 in the derivative).
    Words of 32 bits pass unchanged.
    """
    return jax.lax.bitcast_convert_type(a, jnp.uint32)


def _from_bits(words):
    """The float64 array of `_bits` words (host side)."""
    words = np.ascontiguousarray(words, dtype=np.uint32)
    return words.view(np.float64).reshape(words.shape[:-1])


def _solve_n(token, anchor, b):
    del anchor  # an operand only: the program that calls back holds it (or a copy; `HostLU`)
    return _host_solve(token, b, "N")


def _solve_t(token, anchor, b):
    del anchor
    return _host_solve(token, b, "T")


def _apply_lu(token, anchor, free, b, callback):
    """``J^-1 b`` or ``J^-T b`` on a full node array through the host callback (held dofs: 0)."""
    flat = b.reshape(-1)
    shape = jax.ShapeDtypeStruct(flat[free].shape, jnp.float64)
    solved = jax.pure_callback(callback, shape, token, anchor, _bits(flat[free]), vmap_method="expand_dims")
    return flat.at[free].set(solved, unique_indices=True).reshape(b.shape)


@partial(jax.jit, static_argnames=("physics",))
def _callback_tangent(x, geometry: fk.Geometry, params: fk.KernelInputs, dparams: fk.KernelInputs, free, token, physics):
    """``J^-1 (-dR/dtheta . dtheta) + dheld`` by the host LU that ``token`` names, not transposable
    (`HostLU.direct_tangent` of one tangent, or under an enclosing trace)."""
    b, dheld = parameter_rhs(x, geometry, params, dparams, physics)
    return _apply_lu(token, x, free, b, _solve_n) + dheld


@partial(jax.jit, static_argnames=("physics",))
def _lu_solve(x, geometry: fk.Geometry, params: fk.KernelInputs, b, dheld, free, token, physics):
    """``J^-1 b + dheld``, transposable, by the host LU that ``token`` names (`HostLU`).

    A program of its own, apart from the right-hand side (`parameter_rhs`): a program that calls
    back to the host is never put in JAX's persistent compilation cache, so it is kept to the
    solve itself (the operator ``matvec`` is only traced, for the transpose), and the large
    right-hand side compiles once and is cached like the rest (the whole tangent as one program
    compiled for 0.6-0.8 s in every process).
    """
    matvec = partial(jacobian_matvec, x, geometry, params, physics=physics)
    return jax.lax.custom_linear_solve(matvec, b, solve=lambda _, r: _apply_lu(token, x, free, r, _solve_n),
                                       transpose_solve=lambda _, r: _apply_lu(token, x, free, r, _solve_t)) + dheld


class HostLU:
    """The sparse LU of ``J`` on the host (scipy), reached through ``jax.pure_callback``.

    The factor is registered under an integer token that the compiled solve (`_lu_solve`) passes
    to two fixed host functions, so one program serves every factor: a callback closing over its own
    factor made a new program per factor (traced, batched and compiled again on every design
    iterate: some 50 ms a tangent, and one compilation per factor). The registration is live as
    long as ``anchor`` (the equilibrium nodes, a JAX array, passed along to every call); after
    that the factor stays among the most recently released ones (`RELEASED_FACTOR_BYTES`), for a
    pullback that holds copies of the nodes but not the nodes; one registered within
    `forward_only` is dropped then (no pullback can call it).

    Args:
        factor: a ``scipy.sparse.linalg.SuperLU`` of ``J`` on the free dofs.
        free: index of each free dof into ``x.reshape(-1)`` (its numbering).
        anchor: the equilibrium nodes ``x`` (a JAX array) the factor belongs to.
    """

    name = "lu"

    def __init__(self, factor, free, anchor):
        self.factor = factor
        self.free_host = np.asarray(free)
        self.free = jax.device_put(self.free_host)  # (a transfer: no eager program to compile)
        token = next(_TOKENS)
        _FACTORS[token] = factor
        if _FORWARD_ONLY.get():
            _TRANSIENT.add(token)
        weakref.finalize(anchor, _release, token)
        self.token = jax.device_put(np.int32(token))  # 32 bits: unchanged whether float64 is on or off

    @classmethod
    def at(cls, x, geometry, params, physics, factor=None) -> "HostLU":
        """The LU at ``x`` (a JAX array): ``factor`` (a `jacobian.JacobianFactor`) when it is current,
        else a fresh one."""
        if factor is not None and factor.current:
            return cls(factor.lu, np.asarray(factor.free_dofs), x)
        ref = prepare_compiled(geometry, params, fk.static_physics(physics))
        lu = spla.splu(assemble_jacobian(x, ref, params, physics), permc_spec=PERMC_SPEC)
        return cls(lu, free_dofs(ref), x)

    def host_solve(self, b, trans: str):
        """``J^-1 b`` (``trans="N"``) or ``J^-T b`` ("T") for free-dof vectors ``b`` (leading batch axes allowed)."""
        return _host_solve(self.token, b, trans)

    def tangent(self, x, geometry, params, dparams, physics):
        """`ImplicitAdjoint.tangent` with this factor: the right-hand side, the transposable solve (one
        compiled program for every factor), the held nodes' motion; within `forward_only`, the
        direct solve of the concrete tangents (`direct_tangent`)."""
        physics = fk.static_physics(physics)
        if _FORWARD_ONLY.get():
            return self.direct_tangent(x, geometry, params, dparams, physics)
        return self._transposable(x, geometry, params, dparams, physics)

    def _transposable(self, x, geometry, params, dparams, physics):
        b, dheld = parameter_rhs(x, geometry, params, dparams, physics)
        return _lu_solve(x, geometry, params, b, dheld, self.free, self.token, physics)

    def direct_tangent(self, x, geometry, params, dparams, physics):
        """The tangent as `tangent`, not transposable. Batched by a top-level ``jax.vmap`` (whose
        custom batching rule sees the batch as arrays), the right-hand sides come from one
        `_batched_rhs` program and the LU back-solves them all in one host call; otherwise (one
        tangent, or under an enclosing trace) `parameter_rhs` and the host callback solve, traced."""

        def traced(dparams):  # a compiled function: its trace is cached (custom_vmap traces it per call)
            return _callback_tangent(x, geometry, params, dparams, self.free, self.token, physics)

        solve = jax.custom_batching.custom_vmap(traced)

        @solve.def_vmap
        def solve_batch(axis_size, in_batched, dparams):
            if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(dparams)):
                axes = jax.tree_util.tree_map(lambda b: 0 if b else None, in_batched[0])
                return jax.vmap(traced, in_axes=(axes,))(dparams), True
            # Every leaf batched and on the host: one program per batch size (`batched_rhs_task`).
            dparams = jax.tree_util.tree_map(
                lambda a, b: np.asarray(a) if b else np.broadcast_to(np.asarray(a), (axis_size,) + np.shape(a)),
                dparams, in_batched[0])
            b, dheld = _batched_rhs(x, geometry, params, dparams, physics)
            flat = np.asarray(b, np.float64).reshape(axis_size, -1)
            out = np.zeros_like(flat)
            out[:, self.free_host] = self.host_solve(flat[:, self.free_host], "N")
            return jnp.asarray(out.reshape(b.shape) + np.asarray(dheld, np.float64)), True

        return solve(dparams)


class Krylov:
    """Matrix-free block-Jacobi BiCGStab in JAX (`krylov`); traceable under ``jax.jit`` and ``jax.vmap``."""

    name = "iterative"

    def tangent(self, x, geometry, params, dparams, physics):
        """`ImplicitAdjoint.tangent` by BiCGStab: the right-hand side, the transposable solve, the held
        nodes' motion."""
        b, dheld = parameter_rhs(x, geometry, params, dparams, physics)
        return _krylov_solve(x, geometry, params, b, dheld, fk.static_physics(physics))


@partial(jax.jit, static_argnames=("physics",))
def _krylov_solve(x, geometry, params, b, dheld, physics):
    """``J^-1 b + dheld`` by BiCGStab, transposable (the held nodes' motion added in the program: an
    eager addition was one more compilation in a fresh process)."""
    matvec, preconditioner, transposed_preconditioner = jacobian_operator(x, geometry, params, physics)

    def solver(precondition):
        def solve(operator, r):
            out, _ = bicgstab(operator, r, tol=KRYLOV_RTOL, atol=0.0, maxiter=KRYLOV_MAX_ITERATIONS,
                              M=precondition)
            return out
        return solve

    return jax.lax.custom_linear_solve(matvec, b, solve=solver(preconditioner),
                                       transpose_solve=solver(transposed_preconditioner)) + dheld


class ImplicitAdjoint:
    """The implicit derivative at one equilibrium, with a pluggable linear solver.

    Args:
        x: ``(n_span, n_contour, 3)`` equilibrium nodes, m (concrete, or
            traced under ``jax.jit`` for the "iterative" solver).
        geometry: the bay's `forces.Geometry`.
        params: the kernel parameters of the equilibrium.
        physics: static switches.
        linear_solver: "lu" (`HostLU`) or "iterative" (`Krylov`).
        factor: a `jacobian.JacobianFactor` of ``J`` at ``x`` to reuse ("lu").
    """

    def __init__(self, x, geometry, params, physics, linear_solver: str = "lu", factor=None):
        if linear_solver not in LINEAR_SOLVERS:
            raise ValueError(f"linear_solver must be one of {LINEAR_SOLVERS}, got {linear_solver!r}")
        self.x = x
        self.geometry = geometry
        self.params = params
        self.physics = fk.static_physics(physics)
        self.linear_solver = linear_solver
        self.solver = (HostLU.at(x, geometry, params, self.physics, factor) if linear_solver == "lu"
                       else Krylov())

    def tangent(self, dparams: fk.KernelInputs):
        """``dx*`` for a kernel-parameter tangent: ``-J^-1 dR/dtheta . dtheta`` plus the held nodes' motion."""
        return self.solver.tangent(self.x, self.geometry, self.params, dparams, self.physics)


@partial(jax.custom_jvp, nondiff_argnums=(0,))
def implicit_nodes(physics: fk.Physics, x, geometry: fk.Geometry, params: fk.KernelInputs, converged):
    """The equilibrium ``x`` (returned as is), differentiable in ``params`` by `ImplicitAdjoint`
    with the "iterative" solver (pure JAX: under ``jax.jit`` and ``jax.vmap``).

    ``x`` must be the equilibrium at ``params`` computed without derivatives
    (under ``jax.lax.stop_gradient``); its own tangent and the geometry's are
    ignored (the geometry is the bay's, a constant). Where ``converged`` is
    False there is no equilibrium and the tangent is NaN (the solve's result
    code says why).
    """
    return x


@implicit_nodes.defjvp
def _implicit_nodes_jvp(physics, primals, tangents):
    x, geometry, params, converged = primals
    dx = ImplicitAdjoint(x, geometry, params, physics, "iterative").tangent(tangents[2])
    return x, jnp.where(converged, dx, jnp.nan)

