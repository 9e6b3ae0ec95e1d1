"""Results of a solve: the `Solution` (built by `make_solution` alone), its result codes, the error a failed
solve raises, a warm start's nodes (`initial_nodes`), and the same for N bays (`BaysSolution`)."""

from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass, field
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import forces as fk
from .model.fabric import Fabric
from .model.parameters import Parameters, ParameterViews, bay_parameters
from .model.scene import Scene
from .precision import device_arrays, float64_scope
from .programs import mounted_compiled, static_forces
from .solvers.jacobian import JacobianFactor

__all__ = ["Result", "Solution", "ConvergenceError", "BaysSolution", "BaysConvergenceError", "RESULT_MESSAGES",
           "RESULT_ADVICE", "Stop", "make_solution", "initial_nodes"]


class Result(enum.IntEnum):
    """Why a solve stopped (carried out of the compiled loop as an integer)."""

    converged = 0
    max_steps_reached = 1
    nonfinite = 2
    diverged = 3
    stalled = 4


#: What each result code means.
RESULT_MESSAGES = {
    Result.converged: "converged: the relative residual is below the tolerance",
    Result.max_steps_reached: "max_steps_reached: the step cap was hit before the residual fell below the tolerance",
    Result.nonfinite: ("nonfinite: the state became NaN or infinite (the nodes returned are the last finite "
                       "state before it)"),
    Result.diverged: ("diverged: a node moved further than the divergence bound (by default chord + rib "
                      "spacing) from its mounted shape; the run was stopped there, before it could overflow"),
    Result.stalled: ("stalled: the relaxation's residual stopped falling, or falls so slowly that it would need "
                     "more than 30,000 further steps, so it was stopped early"),
}

#: What to change, when the solver has nothing more specific to say (`Solution.detail`).
RESULT_ADVICE = {
    Result.converged: "",
    Result.max_steps_reached: "raise max_steps, loosen rtol, or warm-start from a nearby solution",
    Result.nonfinite: "the iteration is unstable or the input is non-physical",
    Result.diverged: "the pressure is beyond what the fabric can hold at this prestrain, or the iteration is unstable",
    Result.stalled: ("use method='auto', which hands over to Newton's method: it does not cycle; slack fabric "
                     "(negative prestrain) and a fabric whose Poisson coupling is large against the ratio of its "
                     "stiffnesses make the relaxation cycle"),
}


class ConvergenceError(RuntimeError):
    """A solve did not converge; ``.solution`` holds what it reached."""

    def __init__(self, solution: "Solution", batch: tuple | None = None):
        where = ""
        if batch is not None:
            index, failed, total = batch
            where = f"{failed} of {total} solves of the batch failed; the first, at index {index}, "
        super().__init__(f"{where}{solution.method} solve failed after {int(solution.steps)} steps: "
                         f"{solution.message} (relative residual {float(solution.residual):.3e})")
        self.solution = solution


@dataclass(frozen=True, eq=False)
class Solution(ParameterViews):
    """The rest state (or where a solve stopped).

    Attributes:
        nodes: ``(n_span, n_contour, 3)`` node positions, m.
        tension_span: ``(n_span - 1, n_cells)`` cell tension T11, N/m.
        tension_chord: ``(n_span - 1, n_cells)`` cell tension T22, N/m.
        wrinkled: ``(n_span - 1, n_cells)`` bool, cells where a fibre tension
            would be compressive (a wrinkled skin cures wrinkled).
        result: the `Result` code.
        steps: explicit steps (or Newton iterations) taken.
        residual: ``||R_free||_2 / (p * A)``: the 2-norm of the static force
            residual on the free nodes over the pressure times the nominal
            skin area (the total pressure load), dimensionless.
        wall_time: seconds spent in the solve (compilation included on a
            first call); None under ``jax.jit`` / ``jax.vmap``.
        method: the solver that produced it.
        parameters: the `Parameters` it was solved at, every field set
            (stiffnesses resolved from the fabric); floats.
        rib_spacing: m, for `section`.
        history: for `simulate`, a dict of arrays (time, kinetic_energy,
            peak_displacement, pressure); None otherwise.
        extra: solver-specific diagnostics (``extra["precision"]`` is the
            floating-point type the iteration ran in).
        detail: what the solver found about this particular failure and what
            to change (e.g. "lower the Courant coefficient"); `message` gives
            it in place of the result code's general advice
            (`RESULT_ADVICE`). Empty when there is nothing specific to say.
        factor: the sparse LU of the Jacobian (`jacobian.JacobianFactor`)
            when a Newton method made one, else None: a warm start from this
            solution reuses it (chord Newton), and so do the implicit
            derivative's adjoint solves when it is current. A live object of
            this process, which `without_factor` and pickling drop.

    A `Solution` is a JAX pytree whose leaves are ``nodes``, the tensions and
    ``wrinkled`` (everything else is static), so it may be the auxiliary
    output of ``jax.value_and_grad(..., has_aux=True)``; under an eager
    ``jax.grad`` / ``jax.jacfwd`` of `solve_equilibrium` they are traced and
    differentiable. Under ``jax.jit`` or ``jax.vmap`` of the parameters
    (`relax.traced_solution`) ``result`` (int32 `Result` codes), ``steps``,
    ``residual`` and ``parameters`` are arrays and leaves too, a batch with
    a leading axis on every leaf (``jax.tree_util.tree_map(lambda a: a[i],
    batch)`` is member ``i``), and ``wall_time`` is None.

    Arrays are float64 numpy arrays whatever precision the iteration ran in,
    and ``residual`` is always evaluated in float64 at the returned ``nodes``:
    a float32 solve reports the residual of the shape it returns.
    """

    nodes: np.ndarray
    tension_span: np.ndarray
    tension_chord: np.ndarray
    wrinkled: np.ndarray
    result: Result
    steps: int
    residual: float
    wall_time: float
    method: str
    parameters: Parameters
    rib_spacing: float
    history: dict | None = None
    extra: dict = field(default_factory=dict)
    detail: str = ""
    factor: JacobianFactor | None = None

    def replace(self, **changes) -> "Solution":
        """A copy with some fields changed (unknown names raise TypeError)."""
        return dataclasses.replace(self, **changes)

    def without_factor(self) -> "Solution":
        """This solution without its LU factor (scipy's SuperLU, megabytes on a fine grid, which does not
        pickle): what is kept beside others, pickled or saved (pickling drops it by itself)."""
        return self if self.factor is None else self.replace(factor=None)

    def __getstate__(self) -> dict:
        """Pickled without the LU factor (`without_factor`)."""
        return {**self.__dict__, "factor": None}

    @property
    def converged(self):
        """Whether the solve converged: a bool (an array of them for a `jax.vmap` batch).

        Under ``jax.jit`` it is a traced boolean array.
        """
        if isinstance(self.result, jax.core.Tracer):
            return self.result == Result.converged
        codes = np.asarray(self.result)
        return bool(codes == Result.converged) if codes.ndim == 0 else codes == Result.converged

    @property
    def message(self) -> str:
        """Why the solve stopped, and for a failure what to change (one solve, not a batch)."""
        code = Result(int(np.asarray(self.result)))
        advice = self.detail or RESULT_ADVICE[code]
        head = RESULT_MESSAGES[code]
        if code == Result.max_steps_reached and "newton_iterations" in (self.extra or {}):
            # Newton stops on its own iteration cap, a stalled line search or slow progress, never
            # on max_steps: the detail says which.
            head = "max_steps_reached: the Newton iteration stopped before the residual fell below the tolerance"
        return f"{head}; {advice}" if advice else head

    @property
    def wrinkled_fraction(self) -> float:
        """Fraction of the cells that are wrinkled."""
        return float(np.mean(self.wrinkled))

    def section(self, eta: float = 0.5) -> np.ndarray:
        """The x-z profile at ``y = eta * rib_spacing``, ``(n_contour, 2)`` in m.

        Rows are interpolated linearly in the span index (rows are evenly
        spaced at the ribs); ``eta = 0.5`` on an odd ``n_span`` is a grid row.
        """
        if not 0.0 <= eta <= 1.0:
            raise ValueError(f"eta must lie in [0, 1] (a fraction of the rib spacing), got {eta!r}")
        n_span = self.nodes.shape[0]
        s = eta * (n_span - 1)
        i0 = min(int(np.floor(s)), n_span - 2)
        w = s - i0
        row = (1.0 - w) * self.nodes[i0] + w * self.nodes[i0 + 1]
        return np.stack([row[:, 0], row[:, 2]], axis=-1)

    def raise_if_failed(self) -> "Solution":
        """Return self if converged, else raise `ConvergenceError`.

        For a batch (a `jax.vmap` of `solve_equilibrium`), raises if any
        member failed, naming the first; its ``solution`` is that member.
        """
        converged = np.asarray(self.converged)
        if converged.ndim == 0:
            if not converged:
                raise ConvergenceError(self)
            return self
        if not converged.all():
            index = np.unravel_index(int(np.argmin(converged.reshape(-1))), converged.shape)
            member = jax.tree_util.tree_map(lambda a: np.asarray(a)[index], self)
            raise ConvergenceError(member, batch=(index, int((~converged).sum()), converged.size))
        return self


#: `Solution` fields that are always pytree leaves.
_ARRAY_FIELDS = ("nodes", "tension_span", "tension_chord", "wrinkled")
#: Fields that are leaves when the solve ran under ``jax.jit`` / ``jax.vmap`` (arrays then),
#: and static Python values (`Result`, int, float, float `Parameters`) otherwise.
_STATUS_FIELDS = ("result", "steps", "residual", "parameters")
_STATIC_FIELDS = ("wall_time", "method", "rib_spacing", "history", "extra", "detail", "factor")


def _flatten(sol: Solution):
    traced = not isinstance(sol.result, Result)
    data = _ARRAY_FIELDS + (_STATUS_FIELDS if traced else ())
    static = _STATIC_FIELDS + (() if traced else _STATUS_FIELDS)
    children = [(jax.tree_util.GetAttrKey(name), getattr(sol, name)) for name in data]
    return children, (traced, tuple(getattr(sol, name) for name in static))


def _unflatten(aux, children) -> Solution:
    traced, static_values = aux
    data = _ARRAY_FIELDS + (_STATUS_FIELDS if traced else ())
    static = _STATIC_FIELDS + (() if traced else _STATUS_FIELDS)
    return Solution(**dict(zip(data, children)), **dict(zip(static, static_values)))


jax.tree_util.register_pytree_with_keys(
    Solution, _flatten, _unflatten,
    flatten_func=lambda sol: ([c for _, c in _flatten(sol)[0]], _flatten(sol)[1]),
)


class Stop(NamedTuple):
    """Where a solve stopped, for `make_solution` (as a `loop.LoopOutput` or `newton.NewtonResult` says it)."""

    result: object  # the `Result` code (an int, or an int32 array under jax.jit / jax.vmap)
    residual: object  # ||R_free|| / (p A)


def make_solution(out, forces, nodes, steps, wall_time, method: str, parameters: Parameters, bay,
                  **fields) -> Solution:
    """A `Solution` from where a solver stopped and the forces at its nodes: every `Solution` is built here.

    Concrete: float64 numpy arrays, a `Result`, an int and floats, the
    parameters as floats; under ``jax.jit`` or ``jax.vmap`` (an abstract
    ``out.result``) the values as they are (`Solution`).

    Args:
        out: where the solver stopped: anything with ``result`` (a `Result`
            code) and ``residual``: a `loop.LoopOutput`, a
            `newton.NewtonResult`, a `Stop`.
        forces: `forces.Forces` at ``nodes`` (tensions, wrinkles).
        nodes: ``(n_span, n_contour, 3)`` the returned nodes, m.
        steps: explicit steps or iterations taken.
        wall_time: seconds, or None (not measured inside a compiled call).
        method: the solver's name.
        parameters: the resolved `Parameters` of the solve.
        bay: the `Bay` (for the rib spacing).
        **fields: the optional `Solution` fields ``history``, ``extra``,
            ``detail`` and ``factor``.
    """
    if isinstance(out.result, jax.core.Tracer):
        arrays = (nodes, forces.tension_span, forces.tension_chord, forces.wrinkled)
        status = dict(result=out.result, steps=steps, residual=out.residual, parameters=parameters)
    else:
        arrays = (*(np.asarray(a, dtype=np.float64) for a in (nodes, forces.tension_span, forces.tension_chord)),
                  np.asarray(forces.wrinkled))
        status = dict(result=Result(int(out.result)), steps=int(steps), residual=float(out.residual),
                      parameters=parameters.as_floats())
    return Solution(*arrays, **status, wall_time=wall_time, method=method, rib_spacing=bay.rib_spacing, **fields)


def initial_nodes(initial, geometry: fk.Geometry, params: fk.KernelInputs) -> jnp.ndarray:
    """Starting shape: the mounted one, or a warm start whose held nodes are re-mounted.

    Held nodes (ribs, seams) always start at this solve's mounted position, so
    a warm start from a solution with other rib scales moves the ribs too. A
    `Solution` passes on its displacement from its own mounted shape, added to
    this solve's mounted shape: after a change of rib scales the free nodes
    move with the ribs (keeping the old positions over ribs half as long
    stretched the skin so far that the relaxation diverged).

    Args:
        initial: None, a `Solution` or an ``(n_span, n_contour, 3)`` array, m
            (an array is taken as positions, not displacements). A `Solution`
            returned under a JAX transformation (traced nodes) starts from its
            concrete nodes.
        geometry: the bay's `forces.Geometry`.
        params: the solve's kernel parameters (for the rib scales and shapes).

    Raises:
        ValueError: when the shape does not fit the grid.
    """
    if initial is None:
        return mounted_compiled(geometry, params)
    solution = initial if isinstance(initial, Solution) else None
    nodes = initial if solution is None else solution.extra.get("primal_nodes", solution.nodes)
    nodes = jnp.asarray(nodes, dtype=geometry.contour_root.dtype)
    expected = geometry.free.shape + (3,)
    if nodes.shape != expected:
        raise ValueError(f"initial shape has shape {nodes.shape} but this bay's grid needs {expected}; "
                         "interpolate it to the grid or start from the mounted shape (initial=None)")
    if solution is None:
        return _remounted(nodes, geometry, params)
    own = solution.parameters
    shapes = [np.zeros(0) if shape is None else shape for shape in own.rib_shapes]
    return _remounted(nodes, geometry, params, *device_arrays(
        [own.rib_thickness_scale, own.rib_chord_scale, *shapes], nodes.dtype))


@jax.jit
def _remounted(nodes, geometry: fk.Geometry, params: fk.KernelInputs, *own):
    """`initial_nodes` as one program (a warm re-solve's start; eager, it was half of its time):
    ``nodes`` with the held nodes at this solve's mounted shape and, given the rib variables
    ``own`` of the solution they came from, the free nodes moved by the change of mounted shape."""
    mounted = fk.mounted_nodes(geometry, params)
    if own:
        nodes = mounted + (nodes - fk.nominal_nodes(geometry, *own))
    return jnp.where(geometry.free[..., None] > 0, nodes, mounted)


@dataclass(frozen=True)
class BaysSolution:
    """The equilibrium of N >= 1 bays sharing one `Parameters` (`solve_bays`; one bay for `optimise_pressure`).

    Attributes:
        nodes: ``(n_bays, n_span, n_contour, 3)`` m, each bay in its own frame
            (its root rib at y = 0); differentiable in the parameters.
        result: ``(n_bays,)`` `Result` codes.
        residual: ``(n_bays,)`` relative residuals ``||R_free|| / (p A)``.
        steps: ``(n_bays,)`` relaxation steps (the batch runs until its
            slowest bay stops).
        bays: the `Bay` of each.
        parameters: the shared `Parameters`.
        fabric: the skin's `Fabric` (for `bay_solution`).
        tension_only: the scene switch it was solved with.
        mounted: ``(n_bays, n_span, n_contour, 3)`` m, each bay's mounted
            (nominal) shape in this solve (ribs with their scales and shapes).
        rib_shapes: ``(n_ribs, 2 K)`` per-rib shape coefficients it was
            solved with, or None (the ribs take ``parameters.rib_shape``).
        cut_patterns: ``(n_bays, 2 K)`` per-bay cut fields it was solved
            with, or None (every bay takes ``parameters.cut_pattern``).
        solutions: the per-bay `Solution`s of the "loop" strategy (concrete:
            under ``jax.grad`` their primal values, with the factor a warm
            start reuses), or None (the "batch" strategy).
        scenes: the `Scene` of each bay.
    """

    nodes: jnp.ndarray
    result: jnp.ndarray
    residual: jnp.ndarray
    steps: jnp.ndarray
    bays: list
    parameters: Parameters
    fabric: Fabric | None = None
    tension_only: bool = True
    mounted: jnp.ndarray | None = None
    rib_shapes: jnp.ndarray | None = None
    solutions: list | None = None
    scenes: list | None = None
    cut_patterns: jnp.ndarray | None = None

    @property
    def converged(self) -> bool:
        """Whether every bay converged."""
        return bool(np.all(np.asarray(self.result) == Result.converged))

    def failed_bays(self) -> list[int]:
        """Indices of the bays whose solve did not converge (root to tip)."""
        return [int(k) for k in np.flatnonzero(np.asarray(self.result) != Result.converged)]

    def scene(self, bay: int) -> Scene:
        """The `Scene` of bay ``bay`` (its `Bay`, the wing's fabric and switches)."""
        if self.scenes is not None:
            return self.scenes[bay]
        return Scene(self.bays[bay], self.fabric, tension_only=self.tension_only)

    def bay_solution(self, bay: int) -> Solution:
        """Bay ``bay`` as a concrete `Solution` (float64 numpy arrays; tensions of eq. 10 at its nodes).

        Its ``nodes`` are NaN where the bay did not converge (the implicit
        fixed point is undefined there); ``result``, ``steps`` and
        ``residual`` say why. On the "loop" strategy it is that loop's own
        `Solution` (its nodes as solved, its factor).
        """
        if self.solutions is not None:
            return self.solutions[bay]
        if self.fabric is None:
            raise ValueError("this BaysSolution carries no fabric; solve it with solve_wing")
        scene = self.scene(bay)
        parameters = self.bay_parameters(bay)
        with float64_scope():
            nodes = jnp.asarray(np.asarray(self.nodes[bay]), jnp.float64)
            f = static_forces(nodes, scene.bay.geometry(),
                              scene.params(parameters), scene.physics(dynamic=False))
            stop = Stop(np.asarray(self.result[bay]), self.residual[bay])
            return make_solution(stop, f, nodes, self.steps[bay], None, "relax", parameters, scene.bay,
                                 extra={"precision": "float64", "wing_bay": bay})

    def bay_parameters(self, bay: int) -> Parameters:
        """The concrete `Parameters` of bay ``bay``: the shared ones with, for per-rib shapes, its
        root rib's as ``rib_shape`` and its tip rib's as ``rib_shape_tip``, and for per-bay cut fields
        its row as ``cut_pattern``."""
        as_array = (lambda a: None if a is None else np.asarray(a, np.float64))
        return bay_parameters(self.parameters.as_floats(), as_array(self.rib_shapes), bay,
                               as_array(self.cut_patterns))

    def without_factors(self) -> "BaysSolution":
        """This solution with its bays' `Solution.without_factor` (what is kept beside others)."""
        if self.solutions is None:
            return self
        return dataclasses.replace(self, solutions=[s.without_factor() for s in self.solutions])

    def displacements(self) -> np.ndarray:
        """``(n_bays, n_span, n_contour, 3)`` m: the nodes less each bay's mounted shape (a warm start)."""
        return np.asarray(self.nodes) - np.asarray(self.mounted)


class BaysConvergenceError(ConvergenceError):
    """A bay did not converge; ``.bay`` is its index, ``.failed`` every failed bay, ``.solution`` its `Solution`."""

    def __init__(self, wing_solution: BaysSolution, bay: int):
        solution = wing_solution.bay_solution(bay)
        super().__init__(solution)
        failed = wing_solution.failed_bays()
        y0 = sum(b.rib_spacing for b in wing_solution.bays[:bay])
        values = wing_solution.parameters
        self.bay = bay
        self.failed = failed
        self.n_bays = len(wing_solution.bays)
        self.args = (f"bay {bay} (ribs {bay} and {bay + 1}, y = {y0:.4g} to "
                     f"{y0 + wing_solution.bays[bay].rib_spacing:.4g} m; {len(failed)} of "
                     f"{len(wing_solution.bays)} bays failed) at pressure {float(values.pressure):.6g} Pa, "
                     f"prestrain ({float(values.prestrain_span):.6g}, {float(values.prestrain_chord):.6g}): "
                     f"{self.args[0]}",)
