"""Riccati recursion (dynamic programming) for unconstrained linear-quadratic output tracking.

The reference (Python) twin of the compiled ``_native.Riccati``; it knows nothing about GPC. The
problem, over stages i = 0..N−1 of a linear time-varying model with an affine term,

    z(i+1) = A_i z(i) + B_i v(i) + c_i          (B_i = 0, no decision, for i ≥ n_decide)
    J = Σ_{j=No+1..N} ‖W_y (C z(j) − r(j))‖² + Σ_{i=0..n_decide−1} ‖W_u v(i)‖²,

is solved backwards with the cost-to-go V_i(z) = zᵀ P_i z − 2 q_iᵀ z + const
(Q = W_yᵀ W_y, R = W_uᵀ W_u ≻ 0):

    P_N = Cᵀ Q C,   q_N = Cᵀ Q r(N)
    H_i = R + B_iᵀ P B_i,   K_i = H_i⁻¹ B_iᵀ P A_i,   k_i = H_i⁻¹ B_iᵀ (P c_i − q)
    P_i = A_iᵀ P A_i − (B_iᵀ P A_i)ᵀ K_i [+ Cᵀ Q C],   q_i = A_iᵀ (q − P c_i) + (B_iᵀ P A_i)ᵀ k_i [+ Cᵀ Q r(i)]

(the bracketed output terms for No < i), and forwards v(i) = −K_i z(i) − k_i. The work grows
linearly with N instead of the cubic cost of a QR of the condensed problem (15)–(16); the
minimizer is the same (R ≻ 0 makes it unique). Accuracy: this (non-square-root) form loses
about eps·‖BᵀPB‖/λ_min(R) relative, against eps·cond for the QR of (15)–(19); on the controllers'
problems (Qu ≥ 1e-8 N·m-scale weights, redundant drives included) it agrees with QR to ≤ 1e-10.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from ..errors import SolverError

__all__ = ["lq_tracking"]


def lq_tracking(A, B, c, C, z0, r, Wy, Wu, No: int, n_decide: int) -> tuple[np.ndarray, float]:
    """Minimize the tracking criterion above by the Riccati recursion.

    Args:
        A: (N, n, n) transition matrices; B: (N, n, m) input matrices (rows i ≥ n_decide unused);
            c: (N, n) affine terms.
        C: (p, n) output matrix; z0: (n,) initial state.
        r: (N − No, p) targets of the outputs at j = No+1..N.
        Wy: (p, p) and Wu: (m, m) square-root weights (Wu nonsingular).
        No: initial insensitivity horizon (0 ≤ No < N). n_decide: number of decision stages (1..N).

    Returns:
        (v, J): v (n_decide·m,) the optimal inputs stacked, J the criterion at v.

    Raises:
        SolverError: H_i = R + B_iᵀ P B_i is not positive definite (R not ≻ 0, or non-finite data).
    """
    A, B, c = np.asarray(A, float), np.asarray(B, float), np.asarray(c, float)
    N, n = A.shape[0], A.shape[1]
    m = B.shape[2]
    Q, R = Wy.T @ Wy, Wu.T @ Wu
    CQC, CQ = C.T @ Q @ C, C.T @ Q
    P, q = CQC.copy(), CQ @ r[-1]
    gains = [None] * n_decide
    for i in range(N - 1, -1, -1):
        PA, s = P @ A[i], P @ c[i] - q
        if i < n_decide:
            Bi = B[i]
            BPA = Bi.T @ PA
            try:
                factor = sla.cho_factor(R + Bi.T @ P @ Bi, check_finite=True)
            except (np.linalg.LinAlgError, ValueError) as exc:
                raise SolverError(f"Riccati recursion: R + BᵀPB at stage {i} is not positive definite ({exc})") from None
            K, k = sla.cho_solve(factor, BPA), sla.cho_solve(factor, Bi.T @ s)
            gains[i] = (K, k)
            P = A[i].T @ PA - BPA.T @ K
            q = BPA.T @ k - A[i].T @ s
        else:
            P = A[i].T @ PA
            q = -A[i].T @ s
        P = 0.5 * (P + P.T)
        if i > No:
            P += CQC
            q += CQ @ r[i - No - 1]
    v = np.empty((n_decide, m))
    z = np.asarray(z0, float)
    J = 0.0
    for i in range(N):
        if i < n_decide:
            K, k = gains[i]
            v[i] = -K @ z - k
            z = A[i] @ z + B[i] @ v[i] + c[i]
            e = Wu @ v[i]
            J += float(e @ e)
        else:
            z = A[i] @ z + c[i]
        if i + 1 > No:
            e = Wy @ (C @ z - r[i - No])
            J += float(e @ e)
    if not np.all(np.isfinite(v)):
        raise SolverError("Riccati recursion: the solution is not finite")
    return v.reshape(-1), J
