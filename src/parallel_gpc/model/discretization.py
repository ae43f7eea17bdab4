"""Discretization helpers of the reduced model: matrix exponential, ZOH (eq. (4)), RK4.

* :func:`expm` — scaling and squaring of a Taylor polynomial with error control (the hot path
  of every ZOH discretization, cheaper than ``scipy.linalg.expm`` on the small matrices here);
* :func:`discretize_zoh` — X(k+1) = A_d X(k) + B_d u(k) + c_d of Ẋ = A X + B u + c, eq. (4);
* :func:`rk4_step` — classical Runge–Kutta integration with the input held (the plants).
"""

from __future__ import annotations

import bisect
import math
from functools import lru_cache

import numpy as np

from ..errors import NonFiniteError
from ..validation import positive

__all__ = ["expm", "expm_derivative_action", "discretize_zoh", "rk4_step"]


# ------------------------------------------------------------------ matrix exponential
#: unit roundoff of float64: the Taylor remainder is driven below it.
_UNIT_ROUNDOFF = 2.0 ** -53
#: largest norm handled without scaling (larger matrices are scaled by 2^-s and squared).
_EXPM_THETA = 0.5
_EXPM_MAX_DEGREE = 30


def _taylor_degree(norm: float) -> int:
    """Smallest K whose Taylor remainder bound Σ_{k>K} ‖M‖^k/k! ≤ ‖M‖^(K+1)/(K+1)! / (1 − ‖M‖/(K+2))
    is below u·e^-‖M‖ (u = 2⁻⁵³; e^-‖M‖ ≤ ‖e^M‖, so the bound is relative)."""
    term, k = 1.0, 0
    target = _UNIT_ROUNDOFF * math.exp(-norm)
    while k < _EXPM_MAX_DEGREE:
        k += 1
        term *= norm / k  # ‖M‖^k / k!
        if term * norm / (k + 1) / (1.0 - norm / (k + 2)) <= target:
            return k
    return _EXPM_MAX_DEGREE


def expm(M: np.ndarray) -> np.ndarray:
    """Matrix exponential by scaling and squaring of a Taylor polynomial with error control.

    The degree K is the smallest whose remainder bound ``‖M‖^(K+1)/(K+1)! / (1 − ‖M‖/(K+2))``
    (Frobenius norm, after scaling by 2^-s so that ‖M‖ ≤ 0.5) is below the unit roundoff; for
    the ZOH matrices of a 1–2 ms sample (‖A·Ts‖ ≈ 0.005) that is K ≈ 6 and no squaring. The
    powers M^k are summed with the factorial weights in one product. Agrees with
    ``scipy.linalg.expm`` to ~1e-15 relative (tested).

    Args:
        M: (n, n) or a stack (..., n, n); a stack shares one degree and scaling (its largest norm).

    Returns:
        e^M with the shape of M.
    """
    M = np.asarray(M, dtype=float)
    shape = M.shape
    n = shape[-1]
    if M.ndim == 2:
        flat = M.reshape(-1)
        norm = math.sqrt(flat @ flat)
    else:
        norm = math.sqrt(float(np.einsum("...ij,...ij->...", M, M).max())) if M.size else 0.0
    if not math.isfinite(norm):
        raise NonFiniteError("matrix exponential of a matrix with NaN or inf entries")
    s = 0
    if norm > _EXPM_THETA:
        s = int(math.ceil(math.log2(norm / _EXPM_THETA)))
        M = M * 2.0 ** -s
        norm *= 2.0 ** -s
    K = bisect.bisect_left(DEGREE_NORMS, norm) + 1
    powers = np.empty((K + 1, *shape))  # I, M, M², …, M^K
    powers[0] = cached_identity(n)
    powers[1] = M
    for k in range(2, K + 1):
        np.matmul(powers[k - 1], M, out=powers[k])
    E = (_inverse_factorials(K) @ powers.reshape(K + 1, -1)).reshape(shape)
    for _ in range(s):
        E = E @ E
    return E


@lru_cache(maxsize=32)
def cached_identity(n: int) -> np.ndarray:
    """Cached read-only n × n identity (shared by the expm and the absolute form's u = v map)."""
    eye = np.eye(n)
    eye.setflags(write=False)
    return eye


@lru_cache(maxsize=64)
def _inverse_factorials(K: int) -> np.ndarray:
    c = np.array([1.0 / math.factorial(k) for k in range(K + 1)])
    c.setflags(write=False)
    return c


def _degree_table() -> list[float]:
    """Largest norm for which :func:`_taylor_degree` returns K, K = 1, 2, …"""
    table, lo = [], 0.0
    for K in range(1, _EXPM_MAX_DEGREE):
        a, b = lo, 1.0
        for _ in range(60):
            mid = 0.5 * (a + b)
            a, b = (mid, b) if _taylor_degree(mid) <= K else (a, mid)
        table.append(a)
        lo = a
    return table


#: ``DEGREE_NORMS[K - 1]`` = largest norm handled by the degree-K Taylor polynomial.
DEGREE_NORMS = _degree_table()


def expm_derivative_action(M_top: np.ndarray, D_top: np.ndarray, xi: np.ndarray):
    """Top rows of e^M and the derivatives of e^M ξ along directions D_k (the Fréchet derivative
    of the exponential applied to one vector).

    M has only its top m rows nonzero (the ZOH matrix [[A, B, c], [0, 0, 0]]·Ts), and so has each
    direction. With the scaling of :func:`expm` (M/2^s, F = e^(M/2^s), so e^M ξ = F^(2^s) ξ) the
    derivative is Σ_r F^(2^s−1−r) dF F^r ξ (Horner over r), and dF u, the derivative of the Taylor
    polynomial, is Σ_(i+l<K) (M/2^s)^i D_k (M/2^s)^l u / (i+l+1)! summed by Horner over i from the
    vectors M^l u: a few matrix–vector products, no exponential of the 2n × 2n block matrix
    [[M, D], [0, M]] (whose upper-right block it equals). Two Taylor degrees above the
    exponential's keep the truncation below the unit roundoff (the derivative's terms decay one
    factorial slower). Where 2^s − 1 > n (:func:`frechet_by_squaring`: a stiff ZOH matrix, light links)
    the derivative goes through the squarings instead: dF on all n columns, then at each squaring of
    E the product rule L ← L E + E L (O(s) small products, not 2^s − 1 vector actions).

    Args:
        M_top: (m, n) top rows of M. D_top: (n_dir, m, n) top rows of the directions. xi: (n,).

    Returns:
        (E_top (m, n) top rows of e^M, dE (m, n_dir) with dE[:, k] = d/dt e^(M + t D_k) ξ at t = 0).
    """
    m, n = M_top.shape
    norm = math.sqrt(float(np.einsum("ij,ij->", M_top, M_top)))
    if not math.isfinite(norm):
        raise NonFiniteError("matrix exponential of a matrix with NaN or inf entries")
    s = 0
    if norm > _EXPM_THETA:
        s = int(math.ceil(math.log2(norm / _EXPM_THETA)))
    scale = 2.0 ** -s
    A, D = M_top * scale, D_top * scale
    K = bisect.bisect_left(DEGREE_NORMS, norm * scale) + 1
    inv_fact = _inverse_factorials(K + 3)
    F = np.zeros((m, n))
    F[:, :m] = np.eye(m)
    P = A
    F += P
    for k in range(2, K + 1):
        P = P[:, :m] @ A
        F += inv_fact[k] * P
    A_top = A[:, :m]
    Kd = K + 2

    def action(u):  # dF u for every direction, (m, n_dir)
        R = [D @ u]  # R[l][k] = D_k M^l u
        w = A @ u
        for _ in range(1, Kd):
            R.append(D[:, :, :m] @ w)
            w = A_top @ w
        Y = inv_fact[Kd] * R[0].T
        for i in range(Kd - 2, -1, -1):
            S = sum(inv_fact[i + l + 1] * R[l] for l in range(Kd - i))
            Y = S.T + A_top @ Y
        return Y

    squaring = frechet_by_squaring(s, n)
    if not squaring:
        u = np.array(xi, dtype=float)
        dE = action(u)
        for _ in range(2 ** s - 1):
            u[:m] = F @ u
            dE = F[:, :m] @ dE + action(u)
    else:  # L_k = dF[D_k] on every column (n actions), then L ← L E + E L at each squaring of E
        L = np.stack([action(e) for e in np.eye(n)], axis=2).transpose(1, 0, 2)  # (n_dir, m, n)
    E = F
    for _ in range(s):  # [[E₁, E₂], [0, I]]² = [[E₁ E₁, E₁ E₂ + E₂], [0, I]]
        E2 = E[:, :m] @ E
        E2[:, m:] += E[:, m:]
        if squaring:  # its derivative: [[L₁, L₂], [0, 0]] → [[L₁ E₁ + E₁ L₁, L₁ E₂ + E₁ L₂ + L₂]]
            L2 = E[:, :m] @ L
            L2[:, :, :m] += L[:, :, :m] @ E[:, :m]
            L2[:, :, m:] += L[:, :, :m] @ E[:, m:] + L[:, :, m:]
            L = L2
        E = E2
    if squaring:
        dE = (L @ xi).T
    return E, dE


def frechet_by_squaring(s: int, n: int) -> bool:
    """Whether :func:`expm_derivative_action` (and its compiled twin) takes the Fréchet derivative through the
    squarings (the Taylor polynomial's derivative on all n columns, then one recurrence per squaring: O(s) work)
    rather than along the vector (2^s − 1 more derivative actions, Horner over the powers of F: fewer when
    2^s − 1 ≤ n). A robot with light links at a 2 ms sample needs s ≈ 10 squarings (‖Ts·Z‖ ≈ 400: 1023 actions
    per stage Jacobian along the vector)."""
    return 2 ** s - 1 > n


def zoh_split(E: np.ndarray, n: int, m: int):
    """(A_d, B_d, c_d) blocks of exp([[A, B, c], [0, 0, 0]]·Ts) (or of a stack of them)."""
    return E[..., :n, :n], E[..., :n, n:n + m], E[..., :n, n + m]


def discretize_zoh(A: np.ndarray, B: np.ndarray, c: np.ndarray | None, Ts: float):
    """Zero-order-hold discretization of ``Ẋ = A X + B u + c``, eq. (4).

    Uses the matrix exponential (:func:`expm`) of the augmented matrix [[A, B, c], [0, 0, 0]] · Ts.

    Args:
        A: (n, n), B: (n, m), c: (n,) or None; Ts: sample time in s (> 0).

    Returns:
        (A_d, B_d, c_d): X(k+1) = A_d X(k) + B_d u(k) + c_d.
    """
    Ts = positive("Ts", Ts, " s")
    n, m = B.shape
    aug = np.zeros((n + m + 1, n + m + 1))
    aug[:n, :n] = A
    aug[:n, n:n + m] = B
    if c is not None:
        aug[:n, n + m] = c
    aug *= Ts
    return zoh_split(expm(aug), n, m)


def rk4_step(deriv, X: np.ndarray, u: np.ndarray, Ts: float, substeps: int = 1) -> np.ndarray:
    """Integrate Ẋ = deriv(X, u) over Ts with u held, by ``substeps`` classical RK4 steps."""
    h = Ts / substeps
    X = np.asarray(X, dtype=float)
    for _ in range(substeps):
        k1 = deriv(X, u)
        k2 = deriv(X + 0.5 * h * k1, u)
        k3 = deriv(X + 0.5 * h * k2, u)
        k4 = deriv(X + h * k3, u)
        X = X + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
    return X
