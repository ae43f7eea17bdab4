"""Bounded-variable least squares (BVLS): an active set on the square-root (QR) form.

Lawson & Hanson, *Solving Least Squares Problems* (1974), ch. 23, in the form of Stark &
Parker (1995): ``min ‖A v − b‖²`` subject to ``lb ≤ v ≤ ub``. Every variable is free or held at
one of its bounds; each iteration solves the least-squares problem of the free variables by QR
(the bound ones move to the right-hand side), steps towards it as far as the bounds allow, and
frees the bound variable whose gradient points most into the box, until the Karush–Kuhn–Tucker
conditions hold. The subproblems are solved by Cholesky of principal submatrices of AᵀA when
its condition estimate guarantees the accuracy (``rcond(AᵀA) ≥ 1e-8``, the test of the
``cholesky`` back end; interlacing carries it to every subproblem), else by QR of the free
columns (the square-root form, the condition number not squared).

Warm start: yes — the bound set is the set of variables the (clipped) warm start holds at a
bound; the controller passes the previous solution shifted by one sample, whose active limits
usually stay active, so most steps take one QR solve. Box limits only: a problem with linear
limits ``lo ≤ L v ≤ hi`` (the incremental forms' torque limits) is reported as failed.
"""

from __future__ import annotations

import time

import numpy as np

from scipy.linalg import lapack

from ..errors import SolverError
from ..validation import all_finite
from .normal import normal_equations_factor
from .kkt import verified
from .problem import LeastSquaresProblem, SolveResult, failed_result
from .qr import qr_diag_tail, qr_least_squares

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
            return failed_result(problem, self.name, "failed", 0, time.perf_counter() - t0,
                           "bvls handles box limits lb ≤ v ≤ ub only; this problem has linear limits "
                           "lo ≤ L v ≤ hi (use daqp-direct or proxqp-direct)")
        n = problem.n
        lb = np.full(n, -np.inf) if problem.lb is None else problem.lb
        ub = np.full(n, np.inf) if problem.ub is None else problem.ub
        if (lb > ub).any():
            return failed_result(problem, self.name, "infeasible", 0, time.perf_counter() - t0,
                           "lower bound above upper bound")
        x0 = None if warm_start is None or warm_start.shape != (n,) or not all_finite(warm_start) else warm_start
        x, iterations, ok = bvls(_subproblem_form(problem), lb, ub, x0, self.max_iter or 3 * n + 10)
        dt = time.perf_counter() - t0
        if not ok:
            return failed_result(problem, self.name, "failed", iterations, dt,
                           f"bvls did not converge in {iterations} subproblem solves")
        return verified(problem, self.name, x, iterations, dt, None, "bvls: KKT met in its own iteration")


class _QRForm:
    """Subproblems by QR of the free columns (the diagonal regularization block kept structured
    by ``tpqrt`` when present): the square-root form, any conditioning."""

    def __init__(self, problem: LeastSquaresProblem):
        self.A, self.b = problem.leading_rows()
        self.top = None
        if problem.tail_positive and problem.tail_diag is not None and self.A.shape[0] == problem.A.shape[0]:
            self.top = self.A.shape[0] - self.A.shape[1]
        self.d = problem.tail_diag
        self.scale = float(np.max(np.abs(self.A.T @ self.b), initial=0.0))

    def solve(self, idx: np.ndarray, x: np.ndarray) -> np.ndarray:
        """argmin over x[idx] of ‖A x − b‖² with the other entries of x held."""
        if idx.size == 0:
            return np.zeros(0)
        A, b = self.A, self.b
        if idx.size < x.size:
            bound = np.ones(x.size, dtype=bool)
            bound[idx] = False
            b = b - A[:, bound] @ x[bound]
        if self.top is not None:  # the tail rows of the free columns are diag(d[idx]), their rhs 0
            out = qr_diag_tail(A[:self.top, idx], b[:self.top], self.d[idx])
            if out is not None:
                return out[0]
        return qr_least_squares(A[:, idx], b)[0]

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """w = Aᵀ(b − A x): minus half the gradient of the cost."""
        return self.A.T @ (self.b - self.A @ x)


class _GramForm:
    """Subproblems by Cholesky of principal submatrices of P = AᵀA, formed once per problem.

    Used only when rcond(P) ≥ :data:`~parallel_gpc.solvers.normal.NORMAL_RCOND`: by Cauchy's
    interlacing theorem every principal submatrix P_FF is then at least as well conditioned,
    so every subproblem keeps the accuracy bound of the normal-equations back end.
    """

    def __init__(self, P: np.ndarray, q: np.ndarray):
        self.P, self.q = P, q  # P full symmetric
        self.scale = float(np.abs(q).max()) if q.size else 0.0

    def solve(self, idx: np.ndarray, x: np.ndarray) -> np.ndarray:
        if idx.size == 0:
            return np.zeros(0)
        rows = self.P[idx]  # (k, n) copy
        held = x.copy()
        held[idx] = 0.0
        rhs = self.q[idx] - rows @ held  # q_F − P_FB x_B
        sub = rows[:, idx].T  # P_FF (symmetric) as a Fortran-ordered array: LAPACK takes it without a copy
        c, info = lapack.dpotrf(sub, lower=1, clean=0, overwrite_a=1)
        z, info2 = lapack.dpotrs(c, rhs, lower=1) if info == 0 else (None, -1)
        if info2 != 0:
            raise SolverError(f"Cholesky of a principal submatrix failed (info {info}, {info2}) although "
                              f"rcond(AᵀA) passed the guard")
        return z

    def gradient(self, x: np.ndarray) -> np.ndarray:
        return self.q - self.P @ x


def _subproblem_form(problem: LeastSquaresProblem):
    """The Gram form when the normal equations are well conditioned, else the QR form."""
    out = normal_equations_factor(problem, factor=False)
    if out is None:
        return _QRForm(problem)
    P, q, _ = out
    full = P + P.T  # P holds the upper triangle (zero below): the symmetric matrix, diagonal doubled
    np.fill_diagonal(full, np.diagonal(P))
    return _GramForm(full, q)


def bvls(form, lb: np.ndarray, ub: np.ndarray, x0: np.ndarray | None, max_iter: int) -> tuple[np.ndarray, int, bool]:
    """The BVLS iteration.

    Args:
        form: the subproblem form (:class:`_GramForm` or :class:`_QRForm`).
        lb, ub: (n,) bounds (±inf where unbounded).
        x0: (n,) warm start or None (start from the unconstrained solution projected on the
            box: the variables it clips are held at their bounds).
        max_iter: largest number of subproblem solves.

    Returns:
        (v, number of subproblem solves, converged).
    """
    n = lb.size
    solves = 0
    if x0 is None:  # a cold start: the unconstrained solution projected on the box
        x0, solves = form.solve(np.arange(n), np.zeros(n)), 1
    x = np.minimum(np.maximum(x0, lb), ub)  # np.clip, without its dispatch overhead
    at_lb, at_ub = x <= lb, x >= ub
    tol = DUAL_RTOL * max(form.scale, 1e-300)
    z = None
    while solves < max_iter:
        idx = (~(at_lb | at_ub)).nonzero()[0]
        if z is None:
            z, solves = form.solve(idx, x), solves + 1
        if _step_to_bounds(x, z, idx, lb, ub, at_lb, at_ub):
            z = None  # a variable hit its bound: solve again with it held
            continue
        x[idx] = z
        z, solves, done = _free_one(form, x, lb, ub, at_lb, at_ub, tol, solves, max_iter)
        if done:
            return x, solves, True
    return x, solves, False


def _step_to_bounds(x, z, idx, lb, ub, at_lb, at_ub) -> bool:
    """When z leaves the box: move x[idx] towards z until the first bound is hit, hold the
    variables that hit theirs (in place) and return True; else return False."""
    xf, lf, uf = x[idx], lb[idx], ub[idx]
    below, above = z < lf, z > uf
    out = below | above
    if not out.any():
        return False
    step = z - xf  # nonzero where z is out of the box (x is in it)
    ratio = np.full(idx.size, np.inf)
    ratio[out] = np.maximum((np.where(below, lf, uf)[out] - xf[out]) / step[out], 0.0)
    alpha = float(min(np.min(ratio), 1.0))
    hit = out & (ratio <= alpha * (1 + 1e-12))
    x[idx] = np.clip(xf + alpha * step, lf, uf)
    x[idx[hit & below]] = lf[hit & below]
    x[idx[hit & above]] = uf[hit & above]
    at_lb[idx[hit & below]] = True
    at_ub[idx[hit & above]] = True
    return True


def _free_one(form, x, lb, ub, at_lb, at_ub, tol, solves, max_iter):
    """KKT check at x; when a bound variable's gradient w = Aᵀ(b − A x) points into the box,
    free the one with the largest such component and return the new free set's solution.

    Stark & Parker: when the freed variable's subproblem value lies beyond the bound it was
    freed from, the choice was spoiled by rounding; it is held again and the next one tried.

    Returns:
        (z or None, solves, optimal).
    """
    w = form.gradient(x)
    viol = np.where(at_lb, w, 0.0) - np.where(at_ub, w, 0.0)
    while solves < max_iter:
        j = int(viol.argmax())
        if viol[j] <= tol:
            return None, solves, True
        was_lb = bool(at_lb[j])
        at_lb[j] = at_ub[j] = False
        idx = np.flatnonzero(~(at_lb | at_ub))
        z, solves = form.solve(idx, x), solves + 1
        zj = z[np.searchsorted(idx, j)]
        if not ((was_lb and zj < lb[j]) or (not was_lb and zj > ub[j])):
            return z, solves, False
        (at_lb if was_lb else at_ub)[j] = True
        viol[j] = 0.0
    return None, solves, False
