"""The implicit derivative of an equilibrium, as a value: `ImplicitAdjoint`, and its host sparse LU.

At an equilibrium the static residual of eq. (10)-(15) vanishes on the free
degrees of freedom, ``R(x*(theta), theta) = 0``, so (implicit function
theorem) ``dx*/dtheta = -J^-1 dR/dtheta`` with ``J = dR/dx`` on the free
dofs. `ImplicitAdjoint` is that rule, the value ``adjoint=`` of
`solve_equilibrium` (the shortcut "implicit" names its default):

* the right-hand side and the operator are `rhs.parameter_rhs` and
  `rhs.jacobian_matvec`, built there only;
* the solve is one ``jax.lax.custom_linear_solve``, so reverse mode
  transposes it into the adjoint system ``J^T lambda = xbar`` with the same
  solver's transpose: one adjoint solve per gradient, whatever the number
  of parameters; forward and reverse mode cannot disagree;
* a caller that takes forward-mode derivatives only (the design's Jacobian)
  may say so (`forward_only`);
* the linear solver is a value too (``ImplicitAdjoint(linear_solver=...)``):
  `SparseLU` ("lu"), the sparse LU of ``J`` on the host (scipy through
  ``jax.pure_callback``, `HostLU`; a Newton solve's own factor is reused),
  or `krylov.BiCGStab` ("iterative"), matrix-free in JAX (no host callback,
  so it runs under ``jax.jit`` / ``jax.vmap`` and on any backend); None
  picks by the backend (`default_linear_solver`).

`solve_equilibrium`'s custom JVP (`custom_jvp`) and the pure-JAX relaxation (`implicit_nodes`:
`relax.traced_solution`, the batched wing) both differentiate through this one rule.
"""

from __future__ import annotations

import collections
import contextlib
import contextvars
import itertools
import weakref
from dataclasses import dataclass
from functools import partial
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from .. import forces as fk
from ..compilation import compiling, signature
from ..precision import float64_scope
from ..programs import prepare_compiled
from ..solvers.jacobian import PERMC_SPEC, JacobianFactor, assemble_jacobian, factorise, free_dofs
from .krylov import BiCGStab
from .rhs import batched_rhs, jacobian_matvec, kernel_tangent, parameter_rhs

__all__ = ["SparseLU", "LINEAR_SOLVERS", "as_linear_solver", "default_linear_solver", "ImplicitAdjoint",
           "HostLU", "top_level", "implicit_nodes", "forward_only", "expected_tangents",
           "batched_rhs_task"]

#: Runs concrete host work at top level, outside a caller's transformation (see
#: `custom_jvp.differentiable_solution`); a JAX without ``jax.core.eval_context`` runs it under the
#: caller's trace: the same result, with the programs compiled twice.
top_level = getattr(jax.core, "eval_context", contextlib.nullcontext)


def batched_rhs_task(geometry: fk.Geometry, params: fk.KernelInputs, physics: fk.Physics, n_tangents: int):
    """``(key, task)`` for `compilation.Ahead.submit`: compile `rhs.batched_rhs` for ``n_tangents`` tangents at
    an equilibrium on ``geometry``'s grid, as `HostLU.direct_tangent` then calls it (every leaf
    batched, float64 and strongly typed), and trace the
    one-tangent function that its ``custom_vmap`` traces before batching (`_callback_tangent`)."""
    physics = fk.static_physics(physics)
    x = jax.ShapeDtypeStruct(tuple(geometry.free.shape) + (3,), jnp.float64)
    dparams = jax.tree_util.tree_map(lambda a: jax.ShapeDtypeStruct((n_tangents,) + tuple(np.shape(a)),
                                                                    jnp.result_type(a)), params)
    key = ("tangents", signature(x, geometry, params), physics, n_tangents)
    compile_rhs = compiling(batched_rhs, x, geometry, params, dparams, physics)
    n_free = 3 * int(np.count_nonzero(np.asarray(geometry.free) > 0.5))
    one = jax.tree_util.tree_map(lambda a: jax.ShapeDtypeStruct(a.shape[1:], a.dtype), dparams)
    free = jax.ShapeDtypeStruct((n_free,), jax.dtypes.canonicalize_dtype(np.int64))  # as HostLU's
    token = jax.ShapeDtypeStruct((), jnp.int32)

    def task():
        compile_rhs()
        _callback_tangent.trace(x, geometry, params, one, free, token, physics)  # found then in JAX's cache

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
    one `rhs.batched_rhs` program and one host back-solve of all its columns with the LU, no host
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


def _float64_on_this_thread() -> None:
    """Let a host callback return float64 when XLA runs it on one of its own threads, where float64
    is off (`precision.float64_scope` turns it on for the calling thread only) and JAX would reject
    the result ("Incorrect output dtype"): on for that thread, for good (it runs nothing but
    callbacks). The caller's thread, inside its float64 scope already, is left alone."""
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
        factor: the LU of ``J`` on the free dofs (`jacobian.factorise`).
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
        `rhs.batched_rhs` program and the LU back-solves them all in one host call; otherwise (one
        tangent, or under an enclosing trace) `parameter_rhs` and the host callback solve, traced."""

        def traced(dparams):  # a compiled function: its trace is cached (custom_vmap traces it per call)
            return _callback_tangent(x, geometry, params, dparams, self.free, self.token, physics)

        solve = jax.custom_batching.custom_vmap(traced)

        @solve.def_vmap
        def solve_batch(axis_size, in_batched, dparams):
            if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(dparams)):
                axes = jax.tree_util.tree_map(lambda b: 0 if b else None, in_batched[0])
                return jax.vmap(traced, in_axes=(axes,))(dparams), True
            dparams = jax.tree_util.tree_map(
                lambda a, b: np.asarray(a) if b else np.broadcast_to(np.asarray(a), (axis_size,) + np.shape(a)),
                dparams, in_batched[0])
            return self.batch_tangents(x, geometry, params, dparams, physics), True

        return solve(dparams)

    def batch_tangents(self, x, geometry, params, dparams, physics):
        """The ``(n, n_span, n_contour, 3)`` tangents of ``n`` concrete kernel-parameter tangents (a leading
        axis on every leaf of ``dparams``): one `rhs.batched_rhs` program, one host back-solve."""
        b, dheld = batched_rhs(x, geometry, params, dparams, fk.static_physics(physics))
        flat = np.asarray(b, np.float64).reshape(b.shape[0], -1)
        out = np.zeros_like(flat)
        out[:, self.free_host] = self.host_solve(flat[:, self.free_host], "N")
        return jax.device_put(out.reshape(b.shape) + np.asarray(dheld, np.float64))


@dataclass(frozen=True)
class SparseLU:
    """The implicit tangent's linear solver on the host: scipy's sparse LU of ``J`` (`HostLU`).

    It needs concrete values and a CPU backend (a host callback), so it
    refuses ``jax.jit`` and ``jax.vmap``. The shortcut ``linear_solver="lu"``
    names the default value.

    Args:
        permc_spec: SuperLU's column ordering of a fresh factor (`jacobian.PERMC_SPEC`).
    """

    permc_spec: str = PERMC_SPEC
    name: ClassVar[str] = "lu"

    def bind(self, x, geometry, params, physics, factor=None) -> HostLU:
        """The LU at the equilibrium ``x`` (a JAX array): ``factor`` (a `jacobian.JacobianFactor`, e.g. a
        Newton solve's `Solution.factor`) when it is current, else `current_factor`'s."""
        if factor is None or not factor.current:
            factor = self.current_factor(x, geometry, params, physics)
        return HostLU(factor.lu, np.asarray(factor.free_dofs), x)

    def current_factor(self, x, geometry, params, physics) -> JacobianFactor:
        """The `jacobian.JacobianFactor` at the equilibrium ``x`` (a JAX array): ``J`` assembled
        (`jacobian.assemble_jacobian`) and factorised."""
        ref = prepare_compiled(geometry, params, fk.static_physics(physics))
        jac = assemble_jacobian(x, ref, params, physics)
        return JacobianFactor(factorise(jac, permc_spec=self.permc_spec), jac, free_dofs(geometry), 0.0, True)

    def check_traceable(self, where: str) -> None:
        """Refuse ``jax.jit`` / ``jax.vmap`` (a host sparse LU needs concrete values)."""
        raise TypeError(f"linear_solver='lu' needs concrete values (a host sparse LU); {where} use "
                        "linear_solver='iterative' or None")


#: The linear solvers by shortcut name: the host sparse LU, or matrix-free BiCGStab in JAX.
LINEAR_SOLVERS = {"lu": SparseLU(), "iterative": BiCGStab()}


def default_linear_solver():
    """`SparseLU` when JAX's default backend is the CPU, else `krylov.BiCGStab`.

    The LU lives on the host and is reached through ``jax.pure_callback``,
    which fails when JAX sees only an accelerator (``JAX_PLATFORMS=cuda``);
    the iterative solve (`krylov`) is pure JAX and runs where the rest does.
    """
    return LINEAR_SOLVERS["lu" if jax.default_backend() == "cpu" else "iterative"]


def as_linear_solver(linear_solver):
    """The linear solver value of ``linear_solver``: a value as it is, a shortcut name
    (`LINEAR_SOLVERS`), or None for the backend's default (`default_linear_solver`).

    Raises:
        ValueError: for an unknown name.
    """
    if linear_solver is None:
        return default_linear_solver()
    if isinstance(linear_solver, str):
        if linear_solver not in LINEAR_SOLVERS:
            raise ValueError(f"linear_solver must be one of {tuple(LINEAR_SOLVERS)} or None, got {linear_solver!r}")
        return LINEAR_SOLVERS[linear_solver]
    return linear_solver


class ImplicitTangent:
    """The implicit rule at one equilibrium ``x``: `tangent` maps a kernel-parameter tangent to ``dx*``."""

    def __init__(self, solver, x, geometry, params, physics):
        self.solver, self.x, self.geometry, self.params, self.physics = solver, x, geometry, params, physics

    def tangent(self, dparams: fk.KernelInputs):
        """``dx*`` for a kernel-parameter tangent: ``-J^-1 dR/dtheta . dtheta`` plus the held nodes' motion."""
        return self.solver.tangent(self.x, self.geometry, self.params, dparams, self.physics)

    def tangents(self, dparams: fk.KernelInputs):
        """`tangent` of a batch of concrete kernel-parameter tangents (a leading axis on every leaf): the
        host LU's `HostLU.batch_tangents`, otherwise the linear solver's tangent under ``jax.vmap``."""
        if isinstance(self.solver, HostLU):
            return self.solver.batch_tangents(self.x, self.geometry, self.params, dparams, self.physics)
        return jax.vmap(self.tangent)(dparams)


@dataclass(frozen=True)
class ImplicitAdjoint:
    """Derivatives of an equilibrium by the implicit function theorem (module docstring).

    Args:
        linear_solver: `SparseLU` ("lu"), `krylov.BiCGStab` ("iterative"), or
            None: the backend's default (`default_linear_solver`; under
            ``jax.jit`` / ``jax.vmap``, BiCGStab).
    """

    linear_solver: object = None
    name: ClassVar[str] = "implicit"

    def solver(self):
        """The linear solver value (None resolved by the backend)."""
        return as_linear_solver(self.linear_solver)

    def at(self, x, geometry, params, physics, factor=None) -> ImplicitTangent:
        """The rule at the equilibrium ``x`` (``factor``: a `jacobian.JacobianFactor` of ``J`` at ``x``
        that the LU reuses)."""
        physics = fk.static_physics(physics)
        return ImplicitTangent(self.solver().bind(x, geometry, params, physics, factor), x, geometry, params,
                               physics)

    def primal(self, scene, parameters, solve, rtol: float, max_steps: int):
        """The concrete solve whose equilibrium is differentiated: ``solve(parameters)``, `prepared`."""
        del rtol, max_steps
        return self.prepared(scene, parameters, solve(parameters))

    def prepared(self, scene, parameters, solution):
        """``solution`` (concrete, at ``parameters``) with what its derivative takes made now: with the
        host LU, the factor of ``J`` at its nodes where it converged without one (chord Newton keeps the
        nearby solution's; a relaxation has none), as `jvp` would make it (`SparseLU.current_factor`).
        A wing's bays are so prepared two at a time (`solvers.bay_starts.presolve`), and the factor
        is the next warm start's too."""
        solver = self.solver()
        if not (isinstance(solver, SparseLU) and solution.converged) or (
                solution.factor is not None and solution.factor.current):
            return solution
        with float64_scope():
            x = jax.device_put(np.asarray(solution.nodes, np.float64))  # (as `jvp` transfers them)
            factor = solver.current_factor(x, scene.bay.geometry(), scene.params(parameters),
                                           fk.static_physics(scene.physics(dynamic=False)))
        return solution.replace(factor=factor)

    def jvp(self, scene, parameters, dparameters, concrete, solution, max_steps: int):
        """``(nodes, tangent)`` of the equilibrium ``solution`` at ``concrete`` (the primal values of
        ``parameters``) along ``dparameters``; NaN where it did not converge."""
        del parameters, max_steps
        if not solution.converged:
            # No equilibrium, no implicit derivative: the caller sees the failure (throw) or
            # gets the failed solution, whose tangent is undefined.
            nan = jnp.full(solution.nodes.shape, jnp.nan)
            return jnp.asarray(solution.nodes), nan
        with top_level():  # concrete: the LU (a fresh one after chord Newton) as a plain call
            params = scene.params(concrete)
            x = jax.device_put(np.asarray(solution.nodes, np.float64))  # (a transfer, not an eager operation)
            rule = self.at(x, scene.bay.geometry(), params, scene.physics(dynamic=False), solution.factor)
        return x, rule.tangent(kernel_tangent(dparameters, params))

    def traced_solver(self, where: str):
        """The linear solver under ``jax.jit`` / ``jax.vmap`` (None: BiCGStab); a TypeError for the LU."""
        solver = BiCGStab() if self.linear_solver is None else as_linear_solver(self.linear_solver)
        solver.check_traceable(where)
        return solver

    def describe(self) -> dict:
        """The `Solution.extra` entries of a derivative taken this way."""
        return {"adjoint": self.name, "linear_solver": self.solver().name}


@partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def implicit_nodes(solver, physics: fk.Physics, x, geometry: fk.Geometry, params: fk.KernelInputs, converged):
    """The equilibrium ``x`` (returned as is), differentiable in ``params`` by the implicit rule with the
    pure-JAX linear solver ``solver`` (a `krylov.BiCGStab`: under ``jax.jit`` and ``jax.vmap``).

    ``x`` must be the equilibrium at ``params`` computed without derivatives
    (under ``jax.lax.stop_gradient``); its own tangent and the geometry's are
    ignored (the geometry is the bay's, a constant). Where ``converged`` is
    False there is no equilibrium and the tangent is NaN (the solve's result
    code says why).
    """
    return x


@implicit_nodes.defjvp
def _implicit_nodes_jvp(solver, physics, primals, tangents):
    x, geometry, params, converged = primals
    dx = solver.tangent(x, geometry, params, tangents[2], fk.static_physics(physics))
    return x, jnp.where(converged, dx, jnp.nan)
