"""Robust design (``objective="robust"``): the shape that holds under the shop's scatter (docs/tolerances.md).

The tolerance analysis (`tolerance`) linearises every normal distance in
the tolerance parameters: ``d = d0 + J e`` with ``e`` of covariance ``S``.
Scaled as the design's residuals are (chord fractions, each bay's rows times
``sqrt(w_k / n_k)``), write ``r`` for the stacked ``d0`` and ``A = J S^1/2``
for the stacked tolerance columns (one column per tolerance parameter that
touches the bay: per bay, per rib, and the pressure), so that the wing's mean
square over the objective's rows is ``ms = |r + A z|^2`` with ``z`` of unit
covariance. Exactly, under the linear model::

    E[ms]   = |r|^2 + |A|_F^2
    Var[ms] = 4 |A^T r|^2 + 2 |A^T A|_F^2        (normal z; uniform z: near it)

What is minimised is the mean square's mean plus `QUANTILE_Z` (1.645) of its
standard deviations::

    q(u) = E[ms] + 1.645 sqrt(Var[ms]),     reported as sqrt(q), mm

``sqrt(q)`` is the linearised 95th percentile of the rms distance in the
normal approximation of the mean square (the rms is monotone in it). Both
parts matter: ``|A|_F^2`` is the scatter's own mean-square growth, and the
cross term ``A^T r`` is the scatter along the nominal's own error, the part
that makes the rms's spread first order (a linearised rms would miss the
first and understate the second; docs/tolerances.md, "First order").

``sqrt(Var)`` is no sum of squares, so the Gauss-Newton loop minimises the
majoriser ``E + (z / 2 s) Var + z s / 2 >= q`` (equal at ``s = sqrt(Var)``):
its residual vector ``[r; vec A; sqrt(z / 2 s) (2 A^T r); sqrt(z / s)
triu(A^T A)]`` is stacked, and ``s`` is set to ``sqrt(Var)`` at every
accepted iterate (`RobustTerms.reweight`), so ``q`` falls with every accepted
step and a fixed point is a stationary point of ``q`` itself
(majorise-minimise).

The tension limits hold at their own quantile, cell by cell: every cell's
fibre tension ``t_i`` with its linearised standard deviation ``sigma_i =
|(J_t S^1/2)_i|`` must meet ``t_i - 1.645 sigma_i >= floor`` and ``t_i + 1.645
sigma_i <= ceiling`` (each cell at its own 5th / 95th percentile: necessary
for the least tension's 5th percentile, not sufficient, since cells do not
move together; the Monte Carlo says how close it comes).

Derivatives in the design variables: ``r`` and ``t`` by forward mode through
the implicit equilibrium (`problem.DesignProblem.linearised`); ``A`` and
``J_t S^1/2`` are themselves first derivatives, so theirs are second ones.
They come from central differences of the analytical tolerance Jacobian
(forward-mode tangents of the equilibrium, `model.ToleranceModel.bay_jacobian`) at ``u
+- ROBUST_STEP`` in each scaled design variable: 2 extra wing solves per
design variable and iterate, warm from the iterate's equilibrium, each with
one back-solve per tolerance parameter and bay. Checked against central
differences of ``q`` itself in tests/design/test_robust.py. Forward over the
implicit forward mode would need the tangent rule of a host LU back-solve,
which the solver does not have.

Where the linearisation stops holding: a cell whose tension reaches zero
within the scatter wrinkles, and the skin's stiffness there changes (the
tension-only clamp): the least tension is then no longer smooth in the
parameters, and the per-cell quantile rows speak of a skin that is not the
one solved. The design keeps every cell's 5th percentile above the floor
(0 by default), so at the robust design the linear model holds for 95% of
each cell's scatter; the samples check the rest.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse

from forward_solver.solution import BaysConvergenceError

from ..constraints import VIOLATION_TOLERANCE, floor_threshold, tension_scale
from ..variables import key_of
from .inputs import DEFAULT_TOLERANCES, as_tolerances
from .model import ToleranceModel

__all__ = ["QUANTILE_Z", "ROBUST_STEP", "RobustTerms", "check_robust_tolerances"]

#: The standard normal's 95th percentile: mean + 1.645 standard deviations.
QUANTILE_Z = 1.6448536269514722
#: Central-difference step of the tolerance Jacobian in the scaled design variables (the pressure in units
#: of its start, prestrains in percent): 1e-4 leaves a truncation error of order 1e-8 relative and, at the
#: solves' residual 1e-11, a rounding error of order 1e-7.
ROBUST_STEP = 1e-4


def check_robust_tolerances(tolerances) -> dict:
    """``{name: Tolerance}`` of a robust design: the given ones (anything `inputs.parse_tolerances`
    takes), or every default when None.

    Raises:
        ValueError: for bad tolerances, or none that scatters (every value 0).
    """
    parsed = as_tolerances(dict(DEFAULT_TOLERANCES) if tolerances is None else tolerances)
    if not any(t.value > 0 for t in parsed.values()):
        raise ValueError("objective='robust' designs for the scatter of the tolerances, and every tolerance "
                         "given is 0: give at least one (e.g. pressure=2%), or leave them out for the defaults "
                         "(docs/tolerances.md)")
    return parsed


class RobustTerms:
    """The robust objective's and limits' terms of a `problem.DesignProblem` (module docstring).

    Args:
        problem: the design problem: its targets (`objectives.WingTargets`), tension limits, fabric,
            tension scale and solver settings, and its `problem.DesignProblem.solve_near` (each side of
            a central difference).
        tolerances: ``{name: Tolerance}`` (`check_robust_tolerances`).
        step: the central-difference step in the scaled design variables.
    """

    def __init__(self, problem, tolerances: dict, step: float = ROBUST_STEP):
        self.problem = problem
        self.tolerances = tolerances
        self.step = step
        self.scale = None  # s: sqrt(Var[ms]) at the last accepted iterate (None: set at the first)
        self.size = 0  # the tolerance parameters (columns), once `columns` has run
        self._raw: dict = {}  # the columns and their derivatives by `variables.key_of`

    # ------------------------------------------------------------ the columns
    def columns(self, sol) -> tuple[list, list, list]:
        """At the concrete `BaysSolution` ``sol``: per bay the scaled distance columns ``A_k`` (``(rows,
        cols_k)``, the design's residual units), the tension columns ``J_t S^1/2`` (``(cells, cols_k)``,
        N/m) and the global indices ``cols_k`` of its tolerance parameters."""
        targets = self.problem.targets
        model = ToleranceModel(sol, targets, self.tolerances)
        nd = model.n_distances
        distances, tensions, touching = [], [], []
        for k in range(model.n_bays):
            start = sol.solutions[k] if sol.solutions is not None else np.asarray(sol.nodes[k])
            _, jac = model.bay_jacobian(k, start, self.problem.solver.rtol)
            cols = model.touching[k]
            jac = jac[:, cols] * model.std[cols][None, :]
            # mm per unit -> chord fractions, then the design's weighting sqrt(w_k / n_k) (`WingTargets.residuals`)
            per_row = np.repeat(1e3 * np.asarray(targets.chords[k], np.float64), targets.bays[k].n_contour)
            distances.append(jac[:nd] / per_row[:, None] * math.sqrt(targets.weights[k] / nd))
            tensions.append(jac[nd:])
            touching.append(cols)
        self.size = model.size
        return distances, tensions, touching

    def raw(self, u, sol, derivatives: bool = True) -> dict:
        """The columns at ``u`` (solved: ``sol``) and, with ``derivatives``, their central differences in
        every scaled design variable (each side a wing solve warm from ``sol``)."""
        key = key_of(u)
        held = self._raw.get(key)
        if held is not None and (held["d_distances"] is not None or not derivatives):
            return held
        distances, tensions, touching = self.columns(sol)
        d_distances = d_tensions = None
        if derivatives:
            u = np.asarray(u, np.float64)
            n_u = u.size
            d_distances = [np.zeros(a.shape + (n_u,)) for a in distances]
            d_tensions = [np.zeros(a.shape + (n_u,)) for a in tensions]
            for j in range(n_u):
                sides = []
                for sign in (1.0, -1.0):
                    v = u.copy()
                    v[j] += sign * self.step
                    side = self.problem.solve_near(v, sol)
                    if not side.converged:
                        raise BaysConvergenceError(side, side.failed_bays()[0])
                    sides.append(self.columns(side)[:2])
                (dp, tp), (dm, tm) = sides
                for k in range(len(distances)):
                    d_distances[k][..., j] = (dp[k] - dm[k]) / (2.0 * self.step)
                    d_tensions[k][..., j] = (tp[k] - tm[k]) / (2.0 * self.step)
        held = {"distances": distances, "tensions": tensions, "touching": touching,
                "d_distances": d_distances, "d_tensions": d_tensions}
        self._raw = {**{k: h for k, h in list(self._raw.items())[-1:]}, key: held}  # (the iterate and its trial)
        return held

    # ------------------------------------------------------------ the statistics
    def moments(self, r, raw: dict) -> tuple[float, float, np.ndarray, np.ndarray]:
        """``(E[ms], Var[ms], A^T r, A^T A)`` of the shape residuals ``r`` and the columns ``raw``."""
        m = self.size
        v, gram, frob = np.zeros(m), np.zeros((m, m)), 0.0
        for a, cols, rows in zip(raw["distances"], raw["touching"], self._bay_rows(r)):
            v[cols] += a.T @ r[rows]
            gram[np.ix_(cols, cols)] += a.T @ a
            frob += float(np.sum(a * a))
        mean = float(r @ r) + frob
        var = 4.0 * float(v @ v) + 2.0 * float(np.sum(gram * gram))
        return mean, var, v, gram

    def quantile(self, r, raw: dict) -> float:
        """``q = E[ms] + 1.645 sqrt(Var[ms])``, the design's residual units squared."""
        mean, var, _, _ = self.moments(r, raw)
        return mean + QUANTILE_Z * math.sqrt(max(var, 0.0))

    def _bay_rows(self, r) -> list:
        n_bays = len(self.problem.targets.bays)
        n = r.size // n_bays
        return [slice(k * n, (k + 1) * n) for k in range(n_bays)]

    def reweight(self, r, raw: dict) -> None:
        """Set the majoriser's ``s`` to ``sqrt(Var[ms])`` at an accepted iterate (module docstring)."""
        _, var, _, _ = self.moments(r, raw)
        self.scale = max(math.sqrt(max(var, 0.0)), np.finfo(float).tiny)

    # ------------------------------------------------------------ what Gauss-Newton sees
    def assemble(self, u, r, jr, g, jg, sol):
        """``(R, dR/du, g', dg'/du)``: the stacked robust residual (``R @ R`` the majoriser of ``q`` less its
        constant) and the tension rows at each cell's quantile, from the nominal ``(r, jr, g, jg)`` of
        `problem.DesignProblem.linearised` at ``u``."""
        raw = self.raw(u, sol)
        if self.scale is None:
            self.reweight(r, raw)
        jr = jr.toarray() if scipy.sparse.issparse(jr) else np.asarray(jr)
        n_u = jr.shape[1]
        m = self.size
        mean, var, v, gram = self.moments(r, raw)
        dv, dgram = np.zeros((m, n_u)), np.zeros((m, m, n_u))
        flat, dflat = [], []
        for a, da, cols, rows in zip(raw["distances"], raw["d_distances"], raw["touching"], self._bay_rows(r)):
            dv[cols] += np.einsum("icj,i->cj", da, r[rows]) + a.T @ jr[rows]
            block = np.einsum("icj,id->cdj", da, a)
            dgram[np.ix_(cols, cols)] += block + block.transpose(1, 0, 2)
            flat.append(a.reshape(-1))
            dflat.append(da.reshape(-1, n_u))
        alpha = math.sqrt(QUANTILE_Z / (2.0 * self.scale))
        upper = np.triu_indices(m)
        weight = np.where(upper[0] == upper[1], 1.0, math.sqrt(2.0))  # |G|_F^2 from its upper triangle
        residual = np.concatenate([r, *flat, alpha * 2.0 * v, alpha * math.sqrt(2.0) * weight * gram[upper]])
        jacobian = np.vstack([jr, *dflat, alpha * 2.0 * dv,
                              alpha * math.sqrt(2.0) * weight[:, None] * dgram[upper[0], upper[1]]])
        g, jg = self._quantile_rows(g, jg, raw, n_u)
        return residual, scipy.sparse.csr_matrix(jacobian), g, jg

    def _tension_limits(self) -> int:
        """How many tension limits the constraint rows begin with (each one row per cell of every bay;
        the rib limits' rows, if any, follow them)."""
        p = self.problem
        return 0 if p.tension is None else len(p.tension.names(p.fabric))

    def _shift(self, sigma, rows: int) -> np.ndarray:
        """``1.645 sigma`` over the tension scale on each tension limit's cell rows, 0 on the rib rows."""
        limits = self._tension_limits()
        shift = np.tile(QUANTILE_Z * sigma / self.problem.tension_scale, limits)
        return np.concatenate([shift, np.zeros(rows - shift.size)])

    def _quantile_rows(self, g, jg, raw: dict, n_u: int):
        """The tension rows ``g >= 0`` with each cell at its own quantile (module docstring)."""
        if g.size == 0 or not raw["tensions"] or not self._tension_limits():
            return g, jg
        at = raw["tensions"]
        sigma = np.concatenate([np.sqrt(np.sum(a * a, axis=1)) for a in at])
        dsigma = np.concatenate([np.einsum("ic,icj->ij", a, da) for a, da in zip(at, raw["d_tensions"])])
        safe = np.where(sigma > 0.0, sigma, 1.0)
        dsigma = np.where(sigma[:, None] > 0.0, dsigma / safe[:, None], 0.0)
        shift = np.vstack([self._shift(dsigma[:, j], g.size) for j in range(n_u)]).T
        jg = scipy.sparse.csr_matrix(jg) - scipy.sparse.csr_matrix(shift)
        return g - self._shift(sigma, g.size), jg.tocsr()

    def at(self, u, r, g, sol) -> dict:
        """The robust measures at ``u`` without derivatives (for the history and the tests): ``quantile``
        (``q``), ``mean`` (``E[ms]``), ``std`` (``sqrt(Var[ms])``) and the quantile tension rows ``g``."""
        raw = self.raw(u, sol, derivatives=False)
        mean, var, _, _ = self.moments(r, raw)
        if g.size and raw["tensions"] and self._tension_limits():
            sigma = np.concatenate([np.sqrt(np.sum(a * a, axis=1)) for a in raw["tensions"]])
            g = g - self._shift(sigma, g.size)
        return {"quantile": mean + QUANTILE_Z * math.sqrt(max(var, 0.0)), "mean": mean,
                "std": math.sqrt(max(var, 0.0)), "g": g}


    def limits_report(self, u) -> tuple[dict, tuple | None]:
        """The tension limits at each cell's own percentile at the design ``u``: ``min_tension_p5`` and
        ``max_tension_p95``, the least ``t - 1.645 sigma`` and the largest ``t + 1.645 sigma`` over the
        cells (N/m), and, where one is broken by more than `constraints.VIOLATION_TOLERANCE` of the
        tension scale, ``({name: {bay: amount}}, [sentence])``."""
        p = self.problem
        values = {}
        if p.tension is None:
            return values, None
        sol = p.nominal_linearised(u)[-1]
        tensions = p.measure(sol, u)["tensions"]
        raw = self.raw(u, sol, derivatives=False)
        where, sentences = {}, []
        scale = tension_scale(sol.parameters, p.chord)
        floor, ceiling = p.tension.min_tension, p.tension.ceiling(p.fabric)
        for k, (t, a) in enumerate(zip(tensions, raw["tensions"])):
            sigma = np.sqrt(np.sum(a * a, axis=1))
            low, high = float(np.min(t - QUANTILE_Z * sigma)), float(np.max(t + QUANTILE_Z * sigma))
            values["min_tension_p5"] = min(values.get("min_tension_p5", math.inf), low)
            values["max_tension_p95"] = max(values.get("max_tension_p95", -math.inf), high)
            at = "" if len(tensions) == 1 else f" in bay {k}"
            if floor is not None and low < floor_threshold(floor, scale):
                where.setdefault("min_tension_p5", {})[k] = floor - low
                sentences.append(f"min_tension_p5 violated{at}: a cell's fibre tension at its 5th percentile is "
                                 f"{low:.4g} N/m, {floor - low:.4g} N/m below the floor {floor:.4g} N/m (1 wing in "
                                 "20 wrinkles there)")
            if math.isfinite(ceiling) and high - ceiling > VIOLATION_TOLERANCE * scale:
                where.setdefault("max_tension_p95", {})[k] = high - ceiling
                sentences.append(f"max_tension_p95 violated{at}: a cell's fibre tension at its 95th percentile is "
                                 f"{high:.4g} N/m, {high - ceiling:.4g} N/m above the ceiling {ceiling:.4g} N/m")
        return values, ((where, sentences) if where else None)
