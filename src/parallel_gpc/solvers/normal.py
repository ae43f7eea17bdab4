"""Normal-equations back end: Cholesky of AᵀA where its accuracy is shown sufficient, else QR.

``min ‖A v − b‖²`` by ``AᵀA v = Aᵀb``: one symmetric rank-k update (``syrk``), one Cholesky
factorization (``potrf``) and two triangular solves — about half the flops of the QR of the
stacked matrix and fewer LAPACK calls. Forming AᵀA squares the condition number, so the
reciprocal condition of AᵀA decides — bounded by ``min(d)²/(‖A‖_F² + max(d)²)`` when a
positive diagonal regularization block is present, else estimated by ``pocon``: when it is below
:data:`NORMAL_RCOND` (a relative error bound ε/rcond above ~1e-8) the problem goes to the QR
back end instead. Rank-deficient problems (Qu = 0 with redundant drives) always take QR.

Warm start: none (a direct method). Enforces no limits: a problem with limits is refused.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.linalg import blas, lapack

from .problem import LeastSquaresProblem, SolveResult, refuse_limits
from .qr import QRSolver

#: smallest accepted reciprocal condition number (1-norm estimate) of AᵀA: the forward error
#: of the Cholesky solve is about ε_machine / rcond ≈ 2e-8 at this bound.
NORMAL_RCOND = 1e-8


class NormalEquationsSolver:
    """Unconstrained least squares by Cholesky of the normal equations, QR when ill-conditioned.

    ``SolveResult.message`` says ``"qr: ill-conditioned normal equations"`` when QR was used.
    """

    name = "cholesky"

    def __init__(self):
        self._qr = QRSolver()

    def solve(self, problem: LeastSquaresProblem, warm_start: np.ndarray | None = None) -> SolveResult:
        """The minimizer of ‖A v − b‖² (status ``unconstrained``).

        Raises:
            InvalidParameterError: the problem has limits (this back end cannot enforce them).
        """
        refuse_limits(self.name, problem)
        t0 = time.perf_counter()
        v = normal_equations(problem)
        if v is None:
            res = self._qr.solve(problem)
            res.solver, res.message = self.name, "qr: ill-conditioned normal equations"
            res.solve_time = time.perf_counter() - t0
            return res
        return SolveResult(v, problem.cost(v), "unconstrained", self.name, None, time.perf_counter() - t0)


def normal_equations(problem: LeastSquaresProblem) -> np.ndarray | None:
    """(n,) solution of AᵀA v = Aᵀb by Cholesky, or None when rcond(AᵀA) < :data:`NORMAL_RCOND`."""
    out = normal_equations_factor(problem)
    if out is None:
        return None
    _, q, c = out
    v, info = lapack.dpotrs(c, q, lower=0)
    return v if info == 0 else None


def normal_equations_factor(problem: LeastSquaresProblem, factor: bool = True):
    """(P, q, c): P = AᵀA (upper triangle, Fortran-ordered), q = Aᵀb and the upper Cholesky
    factor c of P; None when P is singular or rcond(P) < :data:`NORMAL_RCOND`. With
    ``factor=False`` c may be None (when the condition bound alone accepted P).

    A diagonal regularization block (``problem.tail_diag``) enters as diag(d²) without being
    multiplied out; zero rows (``problem.nonzero_rows``) are skipped.
    """
    A, b = problem.leading_rows()
    tail = None
    if A.shape[0] == problem.A.shape[0] and problem.tail_diag is not None:
        top = A.shape[0] - A.shape[1]
        A, b, tail = A[:top], b[:top], problem.tail_diag
    At = A.T  # a Fortran-ordered view of a C-ordered A: syrk reads it without a copy
    P = blas.dsyrk(1.0, At, trans=0, lower=0)  # upper triangle of Aᵀ A
    if tail is not None:
        P.T.reshape(-1)[::P.shape[0] + 1] += tail * tail  # P is Fortran-ordered: Pᵀ is a C view
    if tail is not None and tail.min() > 0.0:  # λ_min(P) ≥ min d², λ_max(P) ≤ ‖A_top‖_F² + max d²
        flat = A.reshape(-1) if A.flags.c_contiguous else A.ravel()
        with np.errstate(over="ignore"):  # an overflowing norm fails the bound: pocon decides
            top = float(flat @ flat) + float(tail.max()) ** 2
        if top * NORMAL_RCOND < float(tail.min()) ** 2:
            if not factor:
                return P, At @ b, None
            c, info = lapack.dpotrf(P, lower=0, clean=0, overwrite_a=0)
            return (P, At @ b, c) if info == 0 else None
    c, info = lapack.dpotrf(P, lower=0, clean=0, overwrite_a=0)
    if info != 0:
        return None
    absP = np.abs(P)  # upper triangle only (syrk leaves the strict lower triangle zero)
    anorm = float(np.max(absP.sum(axis=0) + absP.sum(axis=1) - absP.T.reshape(-1)[::P.shape[0] + 1], initial=0.0))
    rcond, info = lapack.dpocon(c, anorm, uplo="U")
    if info != 0 or anorm == 0.0 or not rcond >= NORMAL_RCOND:
        return None
    return P, At @ b, c
