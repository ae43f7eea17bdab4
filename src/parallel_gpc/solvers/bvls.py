"""Bounded-variable least squares (BVLS): an active set on the square-root (QR) form.

Lawson & Hanson, *Solving Least Squares Problems* (1974), ch. 23, in the form of Stark &
Parker (1995): ``min ‖A v − b‖²`` subject to ``lb ≤ v ≤ ub``. Every variable is free or held at
one of its bounds; each iteration solves the least-squares problem of the free variables by QR
(the bound ones move to the right-hand side), steps towards it as far as the bounds allow, and
frees the bound variable whose gradient points most into the box, until the Karush–Kuhn–Tucker
conditions hold. No Hessian AᵀA is formed (the condition number is not squared).

Warm start: yes — the bound set is the set of variables the (clipped) warm start holds at a
bound; the controller passes the previous solution shifted by one sample, whose active limits
usually stay active, so most steps take one QR solve. Box limits only: a problem with linear
limits ``lo ≤ L v ≤ hi`` (the incremental forms' torque limits) is reported as failed.
"""

from __future__ import annotations

import time

import numpy as np

from .problem import LeastSquaresProblem, SolveResult, _failed
from .qr import _qr_diag_tail, qr_least_squares

#: a bound variable is freed only when its gradient component exceeds this fraction of the
#: largest gradient component of the problem (max |Aᵀ b|): the KKT (dual) tolerance.
DUAL_RTOL = 1e-12


class BVLSSolver:
    """Bounded-variable least squares (Lawson & Hanson ch. 23) on the QR form.

    Args:
        max_iter: largest number of subproblem solves; default 3·n + 10.
    """

    name = "bvls"

    def __init__(self, max_iter: int | None = None):
        self.max_iter = max_iter

    def solve(self, problem: LeastSquaresProblem, warm_start: np.ndarray | None = None) -> SolveResult:
        t0 = time.perf_counter()
        if problem.L is not None:
            return _failed(problem, self.name, "failed", 0, time.perf_counter() - t0,
                           "bvls handles box limits lb ≤ v ≤ ub only; this problem has linear limits "
                           "lo ≤ L v ≤ hi (use daqp-direct or proxqp-direct)")
        _, sub = _subproblem_solver(problem)
        n = problem.n
        lb = np.full(n, -np.inf) if problem.lb is None else problem.lb
        ub = np.full(n, np.inf) if problem.ub is None else problem.ub
        if np.any(lb > ub):
            return _failed(problem, self.name, "infeasible", 0, time.perf_counter() - t0,
                           "lower bound above upper bound")
        x0 = None if warm_start is None or warm_start.shape != (n,) or not np.all(np.isfinite(warm_start)) else warm_start
        x, iterations, ok = bvls(problem, lb, ub, sub, x0, self.max_iter or 3 * n + 10)
        dt = time.perf_counter() - t0
        if not ok:
            return _failed(problem, self.name, "failed", iterations, dt,
                           f"bvls did not converge in {iterations} subproblem solves")
        return SolveResult(x, problem.cost(x), "optimal", self.name, iterations, dt, problem.active(x))


def _subproblem_solver(problem: LeastSquaresProblem):
    """(A, solve) where solve(free, rhs) returns argmin over the free columns of
    ‖A[:, free] z − rhs‖² (the diagonal regularization block kept structured when present)."""
    A, b = problem.leading_rows()
    if problem.tail_positive and problem.tail_diag is not None and A.shape[0] == problem.A.shape[0]:
        top = A.shape[0] - A.shape[1]
        G, d = A[:top], problem.tail_diag

        def solve(free, rhs):  # the tail rows of the free columns are diag(d[free]), their rhs 0
            out = _qr_diag_tail(G[:, free], rhs[:top], d[free])
            return out[0] if out is not None else qr_least_squares(A[:, free], rhs)[0]
        return A, solve

    def solve(free, rhs):
        return qr_least_squares(A[:, free], rhs)[0]
    return A, solve


def bvls(problem: LeastSquaresProblem, lb: np.ndarray, ub: np.ndarray, sub, x0: np.ndarray | None,
         max_iter: int) -> tuple[np.ndarray, int, bool]:
    """The BVLS iteration.

    Args:
        problem: the least-squares problem (its leading rows are used).
        lb, ub: (n,) bounds (±inf where unbounded).
        sub: subproblem solver from :func:`_subproblem_solver`.
        x0: (n,) warm start or None (start at the projection of 0 on the box, all free).
        max_iter: largest number of subproblem solves.

    Returns:
        (v, number of subproblem solves, converged).
    """
    A, b = problem.leading_rows()
    n = A.shape[1]
    x = np.clip(np.zeros(n) if x0 is None else x0, lb, ub)
    at_lb, at_ub = x <= lb, x >= ub
    if x0 is None:  # a cold start: everything free
        at_lb[:], at_ub[:] = False, False
    tol = DUAL_RTOL * max(float(np.max(np.abs(A.T @ b), initial=0.0)), 1e-300)
    solves, z = 0, None
    while solves < max_iter:
        idx = np.flatnonzero(~(at_lb | at_ub))
        if z is None:
            z, solves = _free_solution(A, b, x, idx, sub), solves + 1
        if _step_to_bounds(x, z, idx, lb, ub, at_lb, at_ub):
            z = None  # a variable hit its bound: solve again with it held
            continue
        x[idx] = z
        z, solves, done = _free_one(A, b, x, lb, ub, at_lb, at_ub, sub, tol, solves, max_iter)
        if done:
            return x, solves, True
    return x, solves, False


def _free_solution(A, b, x, idx, sub) -> np.ndarray:
    """Least-squares values of the free variables ``idx`` with the others held at x."""
    if idx.size == 0:
        return np.zeros(0)
    if idx.size == x.size:
        return sub(idx, b)
    bound = np.ones(x.size, dtype=bool)
    bound[idx] = False
    return sub(idx, b - A[:, bound] @ x[bound])


def _step_to_bounds(x, z, idx, lb, ub, at_lb, at_ub) -> bool:
    """When z leaves the box: move x[idx] towards z until the first bound is hit, hold the
    variables that hit theirs (in place) and return True; else return False."""
    xf, lf, uf = x[idx], lb[idx], ub[idx]
    below, above = z < lf, z > uf
    out = below | above
    if not np.any(out):
        return False
    step = z - xf
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(below, (lf - xf) / step, (uf - xf) / step)
    ratio = np.where(out, np.maximum(ratio, 0.0), np.inf)
    alpha = float(min(np.min(ratio), 1.0))
    hit = out & (ratio <= alpha * (1 + 1e-12))
    x[idx] = np.clip(xf + alpha * step, lf, uf)
    x[idx[hit & below]] = lf[hit & below]
    x[idx[hit & above]] = uf[hit & above]
    at_lb[idx[hit & below]] = True
    at_ub[idx[hit & above]] = True
    return True


def _free_one(A, b, x, lb, ub, at_lb, at_ub, sub, tol, solves, max_iter):
    """KKT check at x; when a bound variable's gradient w = Aᵀ(b − A x) points into the box,
    free the one with the largest such component and return the new free set's solution.

    Stark & Parker: when the freed variable's subproblem value lies beyond the bound it was
    freed from, the choice was spoiled by rounding; it is held again and the next one tried.

    Returns:
        (z or None, solves, optimal).
    """
    w = A.T @ (b - A @ x)
    viol = np.where(at_lb, w, 0.0) - np.where(at_ub, w, 0.0)
    while solves < max_iter:
        j = int(np.argmax(viol))
        if viol[j] <= tol:
            return None, solves, True
        was_lb = bool(at_lb[j])
        at_lb[j] = at_ub[j] = False
        idx = np.flatnonzero(~(at_lb | at_ub))
        z, solves = _free_solution(A, b, x, idx, sub), solves + 1
        zj = z[np.searchsorted(idx, j)]
        if not ((was_lb and zj < lb[j]) or (not was_lb and zj > ub[j])):
            return z, solves, False
        (at_lb if was_lb else at_ub)[j] = True
        viol[j] = 0.0
    return None, solves, False
