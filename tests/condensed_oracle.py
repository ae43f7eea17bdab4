"""The condensed problem of a controller's step and two independent checks of a plan on it (its objective,
an NNLS KKT residual): the oracles the stage-wise tests share."""

from __future__ import annotations

import numpy as np
from scipy.optimize import nnls

from parallel_gpc import GPCController
from parallel_gpc.gpc.constraints import constrain
from parallel_gpc.solvers import make_solver
from parallel_gpc.solvers.problem import UNBOUNDED


def condensed(ctl: GPCController, X, w):
    """The controller's condensed problem (with its state rows) and DAQP's solution [v; s] (None
    when DAQP's answer fails its KKT check)."""
    pred = ctl.predict(X)
    problem = ctl._criterion.problem(pred, w[ctl.horizons.No:], ctl._qp_limits, ctl.u_prev)
    full = constrain(problem, ctl._stage_rows(pred, X, None), ctl._limits)
    result = make_solver("daqp-direct").solve(full)
    return full, result.v if result.ok else None


def condensed_of_state(chk: GPCController, ric: GPCController, X, w):
    """:func:`condensed` of the checking controller ``chk`` put in the state of ``ric``: the condensed
    problem of the step ``ric`` takes next (the same state: the same problem), and DAQP's solution."""
    chk.restore(ric.state)
    chk._update_disturbance(X)
    return condensed(chk, X, w)


def objective(full, x) -> float:
    """‖A x − b‖² + cᵀx of the condensed problem."""
    return float(np.sum((full.A @ x - full.b) ** 2) + (0.0 if full.c is None else full.c @ x))


def kkt_residual(full, x) -> float:
    """max |∇f + Σ λ a| over λ ≥ 0 on the active rows (NNLS), relative to the gradient's scale:
    f = ‖A x − b‖² + cᵀx, rows L x ≤ hi / ≥ lo, boxes lb ≤ x ≤ ub (an independent KKT check)."""
    g = 2.0 * full.A.T @ (full.A @ x - full.b) + (0.0 if full.c is None else full.c)
    normals, tol = [], 1e-7
    if full.L is not None:
        Lx = full.L @ x
        for i in range(full.L.shape[0]):
            scale = 1.0 + abs(full.hi[i] if full.hi[i] < UNBOUNDED else full.lo[i])
            if full.hi[i] < UNBOUNDED and Lx[i] >= full.hi[i] - tol * scale:
                normals.append(full.L[i])
            if full.lo[i] > -UNBOUNDED and Lx[i] <= full.lo[i] + tol * scale:
                normals.append(-full.L[i])
    n = len(x)
    for bound, sign in ((full.ub, 1.0), (full.lb, -1.0)):
        if bound is None:
            continue
        for j in np.flatnonzero(np.abs(bound) < UNBOUNDED):
            if abs(x[j] - bound[j]) <= tol * (1.0 + abs(bound[j])):
                normals.append(sign * np.eye(n)[j])
    if not normals:
        return float(np.max(np.abs(g))) / max(1.0, float(np.max(np.abs(2.0 * full.A.T @ full.b))))
    M = np.array(normals).T
    _, res = nnls(M, -g, maxiter=50 * M.shape[1])
    return res / max(1.0, float(np.linalg.norm(2.0 * full.A.T @ full.b)))
