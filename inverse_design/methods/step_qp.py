"""The Gauss-Newton step's convex QP, sparse, by Clarabel's interior-point method.

`gauss_newton.GaussNewton` steps by the QP (the linearised fit, the box, the
linearised limits with one slack for the largest violation)::

    minimise    0.5 |r + J d|^2 + 0.5 damping |d|^2 + 0.5 qp_penalty s
    subject to  lo <= d <= hi,   g + G d + s >= 0,   s >= 0

with ``J`` the shape residuals' Jacobian and ``G`` the limits' (both
``scipy.sparse``: a bay's rows move with its own variables only,
`blocks`). The limit rows that no step in the box can bring to zero cannot
bind and are dropped (`reachable_rows`); in a trust box of a few units most
rows stay reachable (18,600-19,400 of 20,480 on 10 bays of the 40-cell wing
at 17x64), and Clarabel took 2.4-3.5 s on them, ending "AlmostSolved".
So the QP is solved on a working set of them, as active-set methods do
(`solve_working_set`): first the rows already at or past their limit, then
every row the last step breaks is added and the QP solved again, until the
step breaks none. The step is then the QP's over every reachable row (a
row outside the set holds at the step). Measured on the same ten-bay QPs
(2-core machine, load 2-3): 2 rounds, 426-478 rows, 0.12-0.15 s, and a
model fall as large or larger (1.0-2.1x: the smaller QP is solved closer).
Each step's set starts with the rows that bound at the last step's
(`BINDING_TOLERANCE`): the iterates of a design follow the same limits from
step to step, and each of them would otherwise come back one round, one QP
solve, at a time (on the 40-cell wing with a field per bay and a shape per
rib: 49 QP solves in 15 steps, 20 s of a 63 s design, against 11 s in 13
steps with this start).
The Hessian ``J^T J + damping I`` is formed sparse (its shared columns
dense, the per-bay and per-rib ones banded).

Clarabel (an interior-point solver for conic programs, Rust, Apache-2.0) was
chosen by measurement on a real step QP (6 bays of the 40-cell wing at 17x64,
a field per bay and a shape per rib: 129 variables, 6528 residual rows; with
no limit row reachable, and with 1853 reachable rows) against SLSQP on the
dense QP (the former path), PIQP, HiGHS and OSQP, on the 2-core development
machine at load 13-15 (times inflated alike): Clarabel 0.55 s and 1.63 s,
PIQP 0.20 s and 0.52 s, HiGHS 0.32 s and 1.12 s, SLSQP 15.7 s and 18.4 s,
OSQP 3.6 s and 129 s (ADMM at 1e-8; its fall 4e-3 short). Every interior-point
solver found SLSQP's predicted fall (to 1e-7 relative). PIQP is faster, but a
QP is under 1% of an iterate (a wing solve and its Jacobian take tens of
seconds on 40 bays) and with PIQP's steps the design of three equal bays with
a cut field (tests/wing/test_block_jacobian.py) went on to 100 Pa and ended
0.15 N/m below the wrinkle floor, where Clarabel's met it: Clarabel.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse

__all__ = ["reachable_rows", "solve_step_qp", "solve_working_set", "BINDING_TOLERANCE", "QP_TOLERANCE",
           "WORKING_SET_TOLERANCE", "WORKING_SET_ROUNDS"]

#: Clarabel's relative gap and feasibility tolerances: far below the model falls that
#: `gauss_newton.GaussNewton` compares (1e-3 of the merit at least for a step to count). The QP's
#: objective is scaled to its linear term's largest entry first (`_objective`): unscaled, a late step's
#: objective (about 1e-5 of the starting merit) lay below what Clarabel resolves, and it ran its 200
#: iterations to "AlmostSolved" at every tolerance from 1e-10 (at 1e-8 and 1e-9 "Solved" early), at a
#: feasible step far short of the minimum: on two step QPs of the 40-cell wing with 809 variables, a
#: model fall of 8.1e-6 and 1.9e-6 where the scaled QP finds 2.02e-5 and 8.48e-6 ("Solved" in 113 and 65
#: iterations at 1e-10; at 1e-12 "AlmostSolved").
QP_TOLERANCE = 1e-10
#: A row outside the working set that the step breaks by more than this (the rows' own unit, a
#: fraction of the tension scale; far below `gauss_newton.GN_SLACK`) joins the set.
WORKING_SET_TOLERANCE = 1e-9
#: A row of the working set that the step leaves within this of its limit binds (the rows' unit): the
#: next step's set starts with the binding rows (`solve_working_set`'s ``start``).
BINDING_TOLERANCE = 1e-6
#: Rounds of the working set before every reachable row is taken at once.
WORKING_SET_ROUNDS = 20


def reachable_rows(g, jg, lo, hi) -> np.ndarray:
    """The rows of ``g + jg d >= 0`` that some ``d`` in the box ``[lo, hi]`` can bring to zero or below
    (a boolean mask): ``g - |jg| max(|lo|, |hi|) <= 0``. The others cannot bind in the step."""
    reach = np.maximum(np.abs(lo), np.abs(hi))
    if scipy.sparse.issparse(jg):
        return np.asarray(g - abs(jg) @ reach <= 0.0).reshape(-1)
    return g - np.abs(jg) @ reach <= 0.0


def solve_step_qp(r, jr, g, jg, lo, hi, damping: float, qp_penalty: float):
    """The step ``d`` of the QP in the module docstring and its slack ``s``.

    Args:
        r: ``(m,)`` residuals.
        jr: ``(m, n)`` their Jacobian (sparse or dense).
        g: ``(k,)`` limit rows ``>= 0`` (the reachable ones, `reachable_rows`).
        jg: ``(k, n)`` their Jacobian.
        lo: ``(n,)`` lower end of the step box.
        hi: ``(n,)`` upper end.
        damping: the Levenberg-Marquardt term (absolute).
        qp_penalty: the slack's weight.

    Returns:
        ``(d, s, status)``: the step clipped to the box, the slack and Clarabel's status
        string (``"Solved"``, ``"AlmostSolved"``, ...); ``d`` is None where the solver
        found no usable point.
    """
    return _solve(_objective(r, jr, damping, qp_penalty), g, jg, lo, hi)


def _objective(r, jr, damping: float, qp_penalty: float):
    """Clarabel's ``P`` (the upper triangle of ``J^T J + damping I``, and a zero for the slack) and ``q`` of the
    QP: the same for every working set of a step. Both are divided by the largest entry of ``J^T r``, so that
    the objective is of order one at every step (the same minimiser; `QP_TOLERANCE`)."""
    jr = scipy.sparse.csc_matrix(jr)
    n = jr.shape[1]
    hessian = (jr.T @ jr + damping * scipy.sparse.identity(n, format="csc")).tocsc()
    P = scipy.sparse.block_diag([scipy.sparse.triu(hessian), scipy.sparse.csc_matrix((1, 1))], format="csc")
    linear = np.asarray(jr.T @ r, np.float64)
    scale = float(np.max(np.abs(linear), initial=0.0))
    scale = scale if np.isfinite(scale) and scale > 0.0 else 1.0
    return (P / scale).tocsc(), np.concatenate([linear, [0.5 * qp_penalty]]) / scale


def _solve(objective, g, jg, lo, hi):
    """`solve_step_qp` with its objective's ``(P, q)`` (`_objective`)."""
    import clarabel

    P, q = objective
    jg = scipy.sparse.csc_matrix(jg)
    n = P.shape[0] - 1
    k = jg.shape[0]
    eye = scipy.sparse.identity(n, format="csc")
    zero_column = scipy.sparse.csc_matrix((n, 1))
    # A x + slack = b, slack >= 0: d <= hi, -d <= -lo, -(G d + s) <= g, -s <= 0
    A = scipy.sparse.vstack([
        scipy.sparse.hstack([eye, zero_column]),
        scipy.sparse.hstack([-eye, zero_column]),
        scipy.sparse.hstack([-jg, -np.ones((k, 1))]),
        scipy.sparse.hstack([scipy.sparse.csc_matrix((1, n)), -np.ones((1, 1))]),
    ], format="csc")
    b = np.concatenate([hi, -lo, g, [0.0]])
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.tol_gap_abs = settings.tol_gap_rel = QP_TOLERANCE
    settings.tol_feas = settings.tol_ktratio = QP_TOLERANCE
    solver = clarabel.DefaultSolver(P, q, A, b, [clarabel.NonnegativeConeT(A.shape[0])], settings)
    solution = solver.solve()
    status = str(solution.status)
    x = np.asarray(solution.x, np.float64)
    if x.size != n + 1 or not np.all(np.isfinite(x)):
        return None, 0.0, status
    return np.clip(x[:n], lo, hi), max(float(x[n]), 0.0), status


def solve_working_set(r, jr, g, jg, lo, hi, damping: float, qp_penalty: float, start=None):
    """`solve_step_qp` over the rows ``g + jg d >= 0``, by a working set of them (module docstring).

    The set starts with the rows at or past their limit (``g <= 0``) and the rows of ``start``;
    after each solve every row outside it that the step and its slack break by more than
    `WORKING_SET_TOLERANCE` joins, and the QP is solved again. When none does, the step is the
    QP's over all the rows (a row of the set that does not bind changes nothing). After
    `WORKING_SET_ROUNDS` rounds every row is taken.

    Args:
        r, jr, g, jg, lo, hi, damping, qp_penalty: as `solve_step_qp` (``g`` and ``jg``
            every candidate row, the reachable ones of `reachable_rows`).
        start: None, or a boolean mask of the rows to begin with besides those at their limit
            (`gauss_newton.GaussNewton` passes the rows that bound at the last step: along a limit
            that the iterates follow, they break again, each round a solve).

    Returns:
        ``(d, s, status, rows, binding)``: `solve_step_qp`'s step, slack and status, how many rows
        the last working set held, and those of them that bind at the step (`BINDING_TOLERANCE`; a
        boolean mask of the rows).
    """
    g = np.asarray(g, np.float64)
    objective = _objective(r, jr, damping, qp_penalty)  # (formed once: 14% of the QPs' time when it was not)
    working = g <= 0.0
    if start is not None:
        working |= np.asarray(start, bool)
    for _ in range(WORKING_SET_ROUNDS):
        d, s, status = _solve(objective, g[working], jg[working], lo, hi)
        if d is None:
            return d, s, status, int(working.sum()), working
        held = g + jg @ d + s
        broken = ~working & (held < -WORKING_SET_TOLERANCE)
        if not broken.any():
            return d, s, status, int(working.sum()), working & (held <= BINDING_TOLERANCE)
        working |= broken
    d, s, status = _solve(objective, g, jg, lo, hi)
    return d, s, status, int(g.size), np.ones(g.size, bool) if d is None else g + jg @ d + s <= BINDING_TOLERANCE
