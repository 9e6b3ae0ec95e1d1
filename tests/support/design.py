"""What the design tests share that the library does not need: dense references of the sparse design Jacobian
and step QP, each bay's columns of the design vector, and a tolerance sample solved alone.

Each is built on the library's public names only, so that it checks them from outside.
"""

import jax
import numpy as np
import scipy.optimize
import scipy.sparse

from inverse_design.methods.gauss_newton import levenberg_damping, merit_model
from inverse_design.methods.step_qp import reachable_rows
from inverse_design.problem import DesignProblem
from inverse_design.tolerance import SAMPLE_RTOL, ToleranceModel
from inverse_design.tolerance.inputs import as_tolerances
from inverse_design.tolerance.monte_carlo import solve_wing


def bay_columns(variables, n_bays: int) -> list[np.ndarray]:
    """Per bay, root to tip, the sorted columns of the scaled design vector that move it: every shared
    component, the bay's row of a per-bay cut field, its two ribs' rows of per-rib shapes (derived
    from `DesignVariables.slices` apart from `methods.blocks.compressed_seeds`)."""
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
            own.extend(range(per_bay[0] + k * per_bay[1], per_bay[0] + (k + 1) * per_bay[1]))
        if per_rib is not None:
            own.extend(range(per_rib[0] + k * per_rib[1], per_rib[0] + (k + 2) * per_rib[1]))
        columns.append(np.array(sorted(own), dtype=np.int64))
    return columns


def dense_linearised(problem: DesignProblem, u):
    """``problem``'s ``(r, dr/du, g, dg/du)`` of the tension limits (no rib limits) at ``u``, its Jacobians
    dense, one tangent per variable through the whole wing: a twin of the problem whose seeds are the
    identity, warm from the problem's last solve (at ``u``). The reference the compressed blocks are
    checked against."""
    with jax.enable_x64(True):
        twin = DesignProblem(problem.scenes, problem.targets, problem.variables, tension=problem.tension,
                             solver=problem.solver)
        twin.remember(problem.previous, u)
        n = problem.variables.size
        twin.seeds = (np.eye(n), np.tile(np.arange(n), (len(problem.scenes), 1)))
        r, jr, g, jg, _ = twin.nominal_linearised(u)
    return r, jr.toarray(), g, jg.toarray()


def dense_step(r, jr, g, jg, lo, hi, penalty, qp_penalty):
    """`methods.gauss_newton.trust_region_step` by SLSQP on the dense QP (the former path, the reference
    the sparse QP is checked against): ``(d, predicted fall, reachable rows)``.

    The fit is rewritten by a QR factorisation of ``[jr; sqrt(damping) I]`` as ``|c + R d|^2``; in
    ``z = R d`` its Hessian is the identity, SLSQP's own starting Hessian, with one slack ``s >= 0``
    for the largest violation.
    """
    jr = jr.toarray() if scipy.sparse.issparse(jr) else np.asarray(jr)
    jg = jg.toarray() if scipy.sparse.issparse(jg) else np.asarray(jg)
    n = jr.shape[1]
    near = reachable_rows(g, jg, lo, hi)
    g, jg = g[near], jg[near]
    damping = levenberg_damping(jr)
    q, rr = np.linalg.qr(np.vstack([jr, np.sqrt(damping) * np.eye(n)]))
    c = q.T @ np.concatenate([r, np.zeros(n)])
    inverse = np.linalg.inv(rr)  # upper triangular, n x n: d = inverse @ z
    model = merit_model(r, jr, g, jg, penalty)
    # x = (z, s): 0.5 |c + z|^2 + 0.5 penalty s
    cons = [{"type": "ineq", "fun": lambda x: inverse @ x[:n] - lo,
             "jac": lambda x: np.hstack([inverse, np.zeros((n, 1))])},
            {"type": "ineq", "fun": lambda x: hi - inverse @ x[:n],
             "jac": lambda x: np.hstack([-inverse, np.zeros((n, 1))])}]
    if g.size:
        gi = jg @ inverse
        cons.append({"type": "ineq", "fun": lambda x: g + gi @ x[:n] + x[n],
                     "jac": lambda x: np.hstack([gi, np.ones((g.size, 1))])})
    s0 = max(0.0, -float(np.min(g, initial=0.0)))
    x0 = np.concatenate([np.zeros(n), [s0]])
    result = scipy.optimize.minimize(
        lambda x: 0.5 * float((c + x[:n]) @ (c + x[:n])) + 0.5 * qp_penalty * x[n], x0,
        jac=lambda x: np.concatenate([c + x[:n], [0.5 * qp_penalty]]), method="SLSQP",
        bounds=[(None, None)] * n + [(0.0, None)], constraints=cons,
        options={"maxiter": 500, "ftol": 1e-14})
    d = np.clip(inverse @ result.x[:n], lo, hi)
    predicted = model(np.zeros(n)) - model(d)
    if not predicted > 0.0:
        return np.zeros(n), 0.0, int(g.size)
    return d, predicted, int(g.size)


def wing_outputs(result, tolerances, deviations, *, rtol: float = SAMPLE_RTOL) -> tuple[list, list]:
    """The wing at ``deviations`` (``(size,)``, in the units of `ToleranceAnalysis.columns`), every bay
    solved cold: per bay its normal distances (mm, the objective's rows) and cell tensions (N/m), NaN
    where a bay failed. The map of the first-order analysis, for checks (central differences)."""
    with jax.enable_x64(True):
        model = ToleranceModel.of(result, as_tolerances(tolerances))
    d, t, _ = solve_wing(model, np.asarray(deviations, np.float64), None, rtol)
    return d, t


def solve_sample(result, tolerances, values: dict, *, rtol: float = SAMPLE_RTOL) -> dict:
    """One wing solved alone (cold, from its mounted shape) at drawn absolute ``values`` (a CSV row's
    columns: ``{"pressure": Pa, "stiffness_span_bay_0": N/m, ...}``; columns not given stay nominal).

    Returns:
        ``{"rms", "max", "min_tension", "converged"}`` as the sample's CSV row.
    """
    with jax.enable_x64(True):
        model = ToleranceModel.of(result, as_tolerances(tolerances))
    e = np.array([float(values.get(c.name, v)) - v for c, v in zip(model.columns, model.nominal_values)])
    d, t, failed = solve_wing(model, e, None, rtol)
    measured = model.measures([x[None] for x in d], [x[None] for x in t])
    return {key: float(measured[key][0]) for key in ("rms", "max", "min_tension")} | {"converged": not failed}
