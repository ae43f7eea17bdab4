"""QR back end: square-root least squares by Householder QR, eq. (17)–(19).

Warm start: none (a direct method; the ``warm_start`` argument is accepted and ignored).
Enforces no limits (a problem with limits is refused): use a QP back end, or
:class:`~parallel_gpc.solvers.QRFirst`, when limits are given.
"""

from __future__ import annotations

import math
import time

import numpy as np
import scipy.linalg as sla
from scipy.linalg import lapack

from ..errors import InvalidParameterError
from .problem import FAST_QR_RCOND, RANK_RTOL, LeastSquaresProblem, MinNormOf, SolveResult, refuse_limits

def qr_least_squares(A: np.ndarray, b: np.ndarray, method: str = "lapack") -> tuple[np.ndarray, float, int]:
    """Minimum-norm least-squares solution of A v ≈ b by QR, eq. (17)–(19).

    Column-pivoted Householder QR ``A P = Q R`` (LAPACK geqp3) reveals the rank r. Full rank:
    ``R₁ v = c₁`` by back substitution. Rank-deficient: a complete orthogonal decomposition
    ``[R₁₁ R₁₂] = T Zᵀ`` gives the minimum-norm v. The lost part gives ``J = ‖c_z‖²``.

    Args:
        A: (r, n); b: (r,).
        method: ``"lapack"`` (default): LAPACK drivers called directly — unpivoted Householder
            QR (``geqrf``/``ormqr``/``trtrs``; of Aᵀ when A is wide, giving the minimum-norm
            solution of a full-row-rank system) whenever its triangular factor is well
            conditioned (``trcon`` estimate > :data:`FAST_QR_RCOND`), else the pivoted path;
            ``"pivoted"``: always the rank-revealing pivoted QR / complete orthogonal
            decomposition above; ``"numpy"``: ``numpy.linalg.qr`` and a triangular solve
            (``numpy.linalg.lstsq`` when rank-deficient). All give the same v to rounding.

    Returns:
        (v, J, numerical rank).
    """
    if method == "lapack":
        out = _qr_lapack(A, b)
        return out if out is not None else _qr_pivoted(A, b)
    if method == "pivoted":
        return _qr_pivoted(A, b)
    if method == "numpy":
        return _qr_numpy(A, b)
    raise InvalidParameterError(f"QR method {method!r} is not one of 'lapack', 'pivoted', 'numpy'")


def _qr_pivoted(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float, int]:
    n = A.shape[1]
    Q, R, piv = sla.qr(A, mode="economic", pivoting=True, check_finite=False)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > RANK_RTOL * d[0])) if d.size and d[0] > 0 else 0
    c1 = Q[:, :rank].T @ b
    v = np.zeros(n)
    if rank == n:
        v[piv] = sla.solve_triangular(R, c1, check_finite=False)
    elif rank > 0:
        Z, T = np.linalg.qr(R[:rank].T, mode="reduced")  # R[:rank] = Tᵀ Zᵀ
        v[piv] = Z @ sla.solve_triangular(T, c1, trans="T", check_finite=False)
    return v, max(float(b @ b - c1 @ c1), 0.0), rank


def _qr_lapack(A: np.ndarray, b: np.ndarray):
    """Unpivoted Householder QR through LAPACK; None when the factor is (nearly) singular."""
    r, n = A.shape
    if n == 0 or r == 0:
        return None
    if r >= n:  # tall: A = Q R, v = R⁻¹ (Qᵀ b)[:n], J = ‖(Qᵀ b)[n:]‖²
        qr, tau, _, info = lapack.dgeqrf(A)
        if info != 0:
            return None
        R = qr[:n]
        rcond, info = lapack.dtrcon(R, norm="1", uplo="U", diag="N")
        if info != 0 or not rcond > FAST_QR_RCOND:
            return None
        c, _, info = lapack.dormqr("L", "T", qr, tau, b[:, None], max(1, 64 * n))
        if info != 0:
            return None
        c = c[:, 0]
        v, info = lapack.dtrtrs(R, c[:n])
        if info != 0:
            return None
        tail = c[n:]
        return v, float(tail @ tail), n
    # wide: Aᵀ = Q R, the minimum-norm solution of A v = b is v = Q R⁻ᵀ b (J = 0)
    qr, tau, _, info = lapack.dgeqrf(A.T)
    if info != 0:
        return None
    R = qr[:r]
    rcond, info = lapack.dtrcon(R, norm="1", uplo="U", diag="N")
    if info != 0 or not rcond > FAST_QR_RCOND:
        return None
    y, info = lapack.dtrtrs(R, b, trans=1)
    if info != 0:
        return None
    z = np.zeros((n, 1))
    z[:r, 0] = y
    v, _, info = lapack.dormqr("L", "N", qr, tau, z, max(1, 64 * r), overwrite_c=1)
    if info != 0:
        return None
    return v[:, 0], 0.0, r


#: block size of the triangular-pentagonal QR (``tpqrt``): for the controller's problems
#: (n = 40…160 columns) 8 is ~20 % faster than 32 (interleaved medians, N = 10, 20, 40).
TPQRT_BLOCK = 8


def qr_diag_tail(G: np.ndarray, b: np.ndarray, d: np.ndarray):
    """min ‖G v − b‖² + ‖diag(d) v‖², d > 0, by Householder QR of [diag(d); G] that keeps the
    diagonal block's structure (LAPACK ``tpqrt``/``tpmqrt``: about half the work of a dense QR
    of the stacked matrix); None when the triangular factor is not well conditioned.

    cond₂(R) = cond₂([G; diag(d)]) ≤ ‖[G; diag(d)]‖_F / min(d), and the 1-norm condition that
    ``trcon`` estimates is at most n times cond₂: when n·‖·‖_F / min(d) is below
    1/:data:`FAST_QR_RCOND` the factor is well conditioned without a ``trcon`` call.
    """
    n = G.shape[1]
    R, V, T, info = lapack.dtpqrt(0, min(n, TPQRT_BLOCK), np.diag(d), G)
    if info != 0:
        return None
    flat = G.reshape(-1) if G.flags.c_contiguous else G.ravel()
    with np.errstate(over="ignore"):  # an overflowing norm (a blown-up model) takes the trcon path
        bound = n * math.sqrt(float(flat @ flat) + float(d @ d)) / float(d.min())
    if not bound * FAST_QR_RCOND < 1.0:
        rcond, info = lapack.dtrcon(R, norm="1", uplo="U", diag="N")
        if info != 0 or not rcond > FAST_QR_RCOND:
            return None
    c1, cz, info = lapack.dtpmqrt(0, V, T, np.zeros((n, 1)), b[:, None], trans="T")
    if info != 0:
        return None
    v, info = lapack.dtrtrs(R, c1)
    if info != 0:
        return None
    cz = cz[:, 0]
    return v[:, 0], float(cz @ cz), n


def _qr_numpy(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float, int]:
    """numpy.linalg only: Householder QR and a triangular solve; lstsq (SVD) if rank-deficient."""
    r, n = A.shape
    if r >= n:
        Q, R = np.linalg.qr(A)
        d = np.abs(np.diag(R))
        if d.size and d.min() > 1e3 * RANK_RTOL * d.max():
            c1 = Q.T @ b
            v = np.linalg.solve(R, c1)
            return v, max(float(b @ b - c1 @ c1), 0.0), n
    v, _, rank, _ = np.linalg.lstsq(A, b, rcond=RANK_RTOL)
    res = A @ v - b
    return v, float(res @ res), int(rank)


def _min_norm_of(A: np.ndarray, b: np.ndarray, mn: MinNormOf, method: str) -> tuple[np.ndarray, float, int]:
    """Least squares in s = M v + m0: the minimum-norm s among the minimizers (the same v as
    plain least squares when A has full column rank)."""
    M, m0, m = mn.M, mn.offset, mn.block
    if m:  # M = kron(tri, I_m): A M⁻¹ and M⁻¹ are block differences
        AMinv = A.copy()
        AMinv[:, :-m] -= A[:, m:]
    else:
        AMinv = sla.solve_triangular(M, A.T, trans="T", lower=True, check_finite=False).T
    s, cost, rank = qr_least_squares(AMinv, b + AMinv @ m0, method)
    if m:
        v = s - m0
        v[m:] -= (s - m0)[:-m]
    else:
        v = sla.solve_triangular(M, s - m0, lower=True, check_finite=False)
    return v, cost, rank


class QRSolver:
    """Unconstrained square-root solve by QR (the reference back end).

    :meth:`solve` refuses a problem with limits (it cannot enforce them: a QP back end or
    :class:`~parallel_gpc.solvers.QRFirst` can); :meth:`solve_unconstrained` gives the
    minimizer without them (what QR-first tries first).

    Args:
        method: QR implementation, see :func:`qr_least_squares` (default ``"lapack"``).
    """

    name = "qr"

    def __init__(self, method: str = "lapack"):
        if method not in ("lapack", "pivoted", "numpy"):
            raise InvalidParameterError(f"QR method {method!r} is not one of 'lapack', 'pivoted', 'numpy'")
        self.method = method
        if method != "lapack":
            self.name = f"qr-{method}"

    def solve(self, problem: LeastSquaresProblem, warm_start: np.ndarray | None = None) -> SolveResult:
        """The minimizer of ‖A v − b‖² (status ``unconstrained``).

        Raises:
            InvalidParameterError: the problem has limits.
        """
        refuse_limits(self.name, problem)
        return self.solve_unconstrained(problem)

    def solve_unconstrained(self, problem: LeastSquaresProblem) -> SolveResult:
        """The minimizer of ‖A v − b‖² without the problem's limits (they are not looked at)."""
        t0 = time.perf_counter()
        A, b = problem.leading_rows()  # drops the zero regularization rows (Qu = 0)
        out = None
        if problem.tail_positive and problem.tail_diag is not None and self.method == "lapack":
            # A = [A_top; diag(d)], d > 0: full column rank, one minimizer (no minimum-norm
            # transform needed); QR of the triangular-pentagonal pair [diag(d); A_top]
            top = A.shape[0] - A.shape[1]
            out = qr_diag_tail(A[:top], b[:top], problem.tail_diag)
        if out is not None:
            v, cost, rank = out
        elif problem.min_norm_of is None:
            v, cost, rank = qr_least_squares(A, b, self.method)
        else:
            v, cost, rank = _min_norm_of(A, b, problem.min_norm_of, self.method)
        dt = time.perf_counter() - t0
        return SolveResult(v, cost, "unconstrained", self.name, None, dt, False,
                           f"rank {rank} of {problem.n}" if rank < problem.n else "")


