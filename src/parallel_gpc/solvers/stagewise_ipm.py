"""Stage-wise primal-dual interior-point method for constrained linear-quadratic problems.

The reference (Python) twin of the compiled ``_native.StagewiseIPM``; it knows nothing about
GPC. The problem, over stages i = 0..N−1 of a linear time-varying model with an affine term
(the structure HPIPM's ``ocp_qp_ipm`` solves; this is an independent implementation),

    z(i+1) = A_i z(i) + B_i v(i) + c_i,   z(0) = z0 given     (v(i) exists for i < n_decide)
    Φ = Σ_{i=0..N} ½ z(i)ᵀ Q_i z(i) + q_iᵀ z(i) + Σ_{i<n_decide} ½ v(i)ᵀ R v(i)
        + Σ_soft (ρ s_j + ½ κ s_j²)
    F_i [z(i); v(i)] ≤ f_i (+ s_j, s_j ≥ 0, on a soft row j),

is solved by Mehrotra's predictor-corrector. Every iteration factorizes ONE Riccati recursion
of the Newton system (the inequalities enter as the diagonal row weights W = Λ T⁻¹, the soft
rows' slacks eliminated row by row) and back-substitutes it twice (predictor and corrector):
the work per iteration grows linearly with N. The equality (dynamics) rows are satisfied by
every iterate (the forward sweep simulates them), so only the stationarity, inequality and
complementarity residuals are driven to zero.

Newton system (rows t = f + S s − F x ≥ 0 with multipliers λ, slacks s ≥ 0 with π):
    dλ = W F dx + w0,  W = d (hard) or d (κ + π / s) / a = d (1 − d / a) (soft),  d = λ / t,  a = κ + d + π / s,
    (H + Fᵀ W F) x⁺ + g + Fᵀ (λ + w0 − W F x) + Eᵀ ν⁺ = 0     (one LQ problem: Riccati).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from ..errors import SolverError

__all__ = ["StageQP", "StageQPSolution", "solve_stage_qp", "IPM_TOL", "IPM_MAX_ITER"]

#: stopping tolerance, relative to the problem's scale (largest gradient/penalty entry, ≥ 1).
IPM_TOL = 1e-9
#: iteration cap: a problem still not converged is reported (hard limits infeasible, typically).
IPM_MAX_ITER = 60
#: fraction of the step to the boundary of the positive orthant.
_TAU = 0.995
#: iterative-refinement passes per Newton step (one back-substitution each, same factorization).
_REFINE = 2
#: a best iterate whose relative KKT residual is at most this is accepted (the rounding floor of
#: a badly scaled problem sits above IPM_TOL); above it the problem is reported infeasible.
_ACCEPT = 1e-6
#: the iterations stop after this many without a better iterate (the rounding floor reached).
_STALL = 4


@dataclass
class StageQP:
    """One stage-wise problem (see the module docstring).

    Attributes:
        A: (N, nz, nz); B: (N, nz, m) (stages i ≥ n_decide unused); c: (N, nz); z0: (nz,).
        Q: (N + 1, nz, nz) symmetric positive semi-definite; q: (N + 1, nz).
        R: (m, m) positive definite. n_decide: decision stages (1..N).
        Fz: (N, k, nz); Fv: (N, k, m) (zero on stages ≥ n_decide); f: (N, k), +inf on an unused
            row. soft: (N, k) bool, True on a soft row.
        rho: ρ > 0 and kappa: κ > 0 of the soft rows' slack cost ρ s + ½ κ s².
    """

    A: np.ndarray
    B: np.ndarray
    c: np.ndarray
    z0: np.ndarray
    Q: np.ndarray
    q: np.ndarray
    R: np.ndarray
    n_decide: int
    Fz: np.ndarray
    Fv: np.ndarray
    f: np.ndarray
    soft: np.ndarray
    rho: float = 1.0
    kappa: float = 1.0


@dataclass
class StageQPSolution:
    """The solution of a :class:`StageQP`.

    Attributes:
        v: (n_decide, m); z: (N + 1, nz); s: (N, k) slacks (0 on hard and unused rows);
        lam: (N, k) row multipliers; nu: (N + 1, nz) costates (nu[0] unused: z0 is given);
        iterations: IPM iterations; status: ``"optimal"`` or ``"infeasible"`` (not converged:
        hard rows that cannot all hold) — the message says which; residual: the largest KKT
        residual, relative to the scale.
    """

    v: np.ndarray
    z: np.ndarray
    s: np.ndarray
    lam: np.ndarray
    nu: np.ndarray
    iterations: int
    status: str
    residual: float
    message: str = ""


class _Riccati:
    """The Riccati factorization of one Newton system (row weights W) and its back-substitution."""

    def __init__(self, qp: StageQP, W: np.ndarray):
        N, nd = qp.A.shape[0], qp.n_decide
        self.qp = qp
        self.Pn = [None] * N     # P_{i+1}
        self.fac = [None] * nd   # Cholesky of Hvv_i
        self.Hvz = [None] * nd
        self.K = [None] * nd
        WFz = W[:, :, None] * qp.Fz
        P = qp.Q[N]
        for i in range(N - 1, -1, -1):
            A, Fz = qp.A[i], qp.Fz[i]
            self.Pn[i] = P
            PA = P @ A
            Qi = qp.Q[i] + Fz.T @ WFz[i]
            if i < nd:
                B, Fv = qp.B[i], qp.Fv[i]
                PB = P @ B
                Hvv = qp.R + Fv.T @ (W[i][:, None] * Fv) + B.T @ PB
                Hvz = Fv.T @ WFz[i] + PB.T @ A
                try:
                    self.fac[i] = sla.cho_factor(Hvv, check_finite=True)
                except (np.linalg.LinAlgError, ValueError) as exc:
                    raise SolverError(f"stage-wise IPM: the input Hessian at stage {i} is not positive definite "
                                      f"({exc})") from None
                self.Hvz[i], self.K[i] = Hvz, -sla.cho_solve(self.fac[i], Hvz)
                P = Qi + A.T @ PA + Hvz.T @ self.K[i]
            else:
                P = Qi + A.T @ PA
            P = 0.5 * (P + P.T)
        self.P0 = P

    def solve(self, gz: np.ndarray, gv: np.ndarray, homogeneous: bool = False):
        """(z, v) of the LQ problem with linear terms gz (N + 1, nz) and gv (n_decide, m)
        (``homogeneous``: with z0 = 0 and no affine term, a correction's problem)."""
        qp = self.qp
        c = np.zeros_like(qp.c) if homogeneous else qp.c
        N, nd = qp.A.shape[0], qp.n_decide
        kk = [None] * nd
        p = gz[N]
        for i in range(N - 1, -1, -1):
            w = self.Pn[i] @ c[i] + p
            if i < nd:
                kk[i] = -sla.cho_solve(self.fac[i], gv[i] + qp.B[i].T @ w)
                p = gz[i] + qp.A[i].T @ w + self.Hvz[i].T @ kk[i]
            else:
                p = gz[i] + qp.A[i].T @ w
        z = np.empty((N + 1, qp.A.shape[1]))
        v = np.empty((nd, qp.R.shape[0]))
        z[0] = 0.0 if homogeneous else qp.z0
        for i in range(N):
            if i < nd:
                v[i] = self.K[i] @ z[i] + kk[i]
                z[i + 1] = qp.A[i] @ z[i] + qp.B[i] @ v[i] + c[i]
            else:
                z[i + 1] = qp.A[i] @ z[i] + c[i]
        return z, v


def _rows_times(qp: StageQP, z: np.ndarray, v: np.ndarray) -> np.ndarray:
    """F [z; v] per stage, (N, k)."""
    N, nd = qp.A.shape[0], qp.n_decide
    out = np.einsum("ikn,in->ik", qp.Fz, z[:N])
    out[:nd] += np.einsum("ikm,im->ik", qp.Fv[:nd], v)
    return out


def _rows_transpose(qp: StageQP, y: np.ndarray):
    """(Fzᵀ y (N + 1, nz) with a zero last stage, Fvᵀ y (n_decide, m))."""
    N, nd = qp.A.shape[0], qp.n_decide
    gz = np.zeros((N + 1, qp.A.shape[1]))
    gz[:N] = np.einsum("ikn,ik->in", qp.Fz, y)
    return gz, np.einsum("ikm,ik->im", qp.Fv[:nd], y[:nd])


def costates(qp: StageQP, z, v, lam) -> tuple[np.ndarray, np.ndarray]:
    """The costates ν that make the Lagrangian stationary in z(1..N) (a backward recursion,
    ν_N = Q_N z_N + q_N, ν_i = Q_i z_i + q_i + A_iᵀ ν_{i+1} + F_{z,i}ᵀ λ_i) and the remaining
    gradient in v, R v(i) + B_iᵀ ν_{i+1} + F_{v,i}ᵀ λ_i, (n_decide, m): zero at the optimum.

    Returns:
        (ν (N + 1, nz) with ν_0 = 0, the v-gradient (n_decide, m)).
    """
    N, nd = qp.A.shape[0], qp.n_decide
    gz, gv = _rows_transpose(qp, lam)
    g = np.einsum("inm,im->in", qp.Q, z) + qp.q + gz
    nu = np.zeros_like(z)
    nu[N] = g[N]
    for i in range(N - 1, 0, -1):
        nu[i] = g[i] + qp.A[i].T @ nu[i + 1]
    rv = v @ qp.R.T + gv + np.einsum("imk,im->ik", qp.B[:nd], nu[1:nd + 1])
    return nu, rv


def solve_stage_qp(qp: StageQP, tol: float = IPM_TOL, max_iter: int = IPM_MAX_ITER) -> StageQPSolution:
    """Solve a :class:`StageQP` by Mehrotra's predictor-corrector, one Riccati factorization per iteration.

    Args:
        qp: the problem. tol: stopping tolerance relative to the scale. max_iter: iteration cap.

    Returns:
        The solution (status ``"infeasible"`` when the iterations stop short: its message names the
        largest remaining violation of a hard row).

    Raises:
        SolverError: a Newton system that is not positive definite (R not ≻ 0, non-finite data).
    """
    N, nd = qp.A.shape[0], qp.n_decide
    used = np.isfinite(qp.f)
    soft = qp.soft & used
    f = np.where(used, qp.f, 0.0)
    n_ineq = int(used.sum() + soft.sum())
    scale = max(1.0, float(np.max(np.abs(qp.q), initial=0.0)), qp.rho if soft.any() else 0.0)
    zero_gv = np.zeros((nd, qp.R.shape[0]))
    z, v = _Riccati(qp, np.zeros(used.shape)).solve(qp.q, zero_gv)
    lam = np.zeros(used.shape)
    s = np.zeros(used.shape)
    if not used.any():  # an unconstrained problem: the one Riccati solve
        nu, rv = costates(qp, z, v, lam)
        res = float(np.max(np.abs(rv), initial=0.0)) / scale
        return StageQPSolution(v, z, s, lam, nu, 0, "optimal", res)
    Fx = _rows_times(qp, z, v)
    s = np.where(soft, np.maximum(Fx - f, 0.0) + 1.0, 0.0)
    t = np.where(used, np.maximum(f + s - Fx, 1.0), 1.0)
    lam = np.where(used, 1.0, 0.0)
    pi = np.where(soft, 1.0, 1.0)
    best = None  # (merit, iterate): the iterations stop at the tolerance or at the rounding floor
    res = np.inf
    for it in range(1, max_iter + 1):
        Fx = _rows_times(qp, z, v)
        r_t = np.where(used, Fx - s + t - f, 0.0)
        r_s = np.where(soft, qp.rho + qp.kappa * s - lam - pi, 0.0)
        mu = (float(np.sum(t * lam, where=used)) + float(np.sum(s * pi, where=soft))) / n_ineq
        nu, rv = costates(qp, z, v, lam)
        res = max(float(np.max(np.abs(rv), initial=0.0)), float(np.max(np.abs(r_s)))) / scale
        res_p = float(np.max(np.abs(r_t))) / max(1.0, float(np.max(np.abs(f))))
        merit = max(mu / scale, res, res_p)
        if best is None or merit < best[0]:
            best = (merit, it - 1, (v, z, np.where(soft, s, 0.0), lam, nu))
        if merit <= tol:
            break
        if it - 1 - best[1] >= _STALL and best[0] <= _ACCEPT:
            break  # the Newton steps' rounding (row weights λ/t ~ 1/μ) has taken over: keep the best iterate
        d = np.where(used, lam / t, 0.0)
        sp = np.where(soft, pi / np.where(soft, s, 1.0), 0.0)
        a = np.where(soft, qp.kappa + d + sp, 1.0)
        W = np.where(soft, d * (qp.kappa + sp) / a, d)  # d (1 − d / a) without its cancellation
        ric = _Riccati(qp, W)

        def direction(r_tl, r_sp):
            gam = np.where(used, (-r_tl + lam * r_t) / t, 0.0)
            beta = np.where(soft, -r_s + gam - r_sp / np.where(soft, s, 1.0), 0.0)
            w0 = np.where(soft, (gam * (qp.kappa + sp) + d * (r_s + r_sp / np.where(soft, s, 1.0))) / a, gam)
            gz, gv = _rows_transpose(qp, lam + w0 - W * Fx)
            zp, vp = ric.solve(qp.q + gz, gv)
            for _ in range(_REFINE):  # iterative refinement of the Newton step on its reduced gradient
                Fdx = _rows_times(qp, zp - z, vp - v)
                _, rv1 = costates(qp, zp, vp, lam + W * Fdx + w0)
                if not np.max(np.abs(rv1), initial=0.0) > 1e-3 * tol * scale:
                    break
                cz, cv = ric.solve(np.zeros_like(qp.q), rv1, homogeneous=True)
                zp, vp = zp + cz, vp + cv
            Fdx = _rows_times(qp, zp - z, vp - v)
            ds = np.where(soft, (beta + d * Fdx) / a, 0.0)
            dl = np.where(used, W * Fdx + w0, 0.0)
            dt = np.where(used, -r_t - Fdx + ds, 0.0)
            dp = np.where(soft, (-r_sp - pi * ds) / np.where(soft, s, 1.0), 0.0)
            return zp - z, vp - v, dt, dl, ds, dp

        def max_step(dt, dl, ds, dp, frac):
            alpha = 1.0
            for x, dx, mask in ((t, dt, used), (lam, dl, used), (s, ds, soft), (pi, dp, soft)):
                neg = mask & (dx < 0)
                if neg.any():
                    alpha = min(alpha, frac * float(np.min(-x[neg] / dx[neg])))
            return alpha

        aff = direction(np.where(used, t * lam, 0.0), np.where(soft, s * pi, 0.0))
        dt, dl, ds, dp = aff[2:]
        alpha = max_step(dt, dl, ds, dp, 1.0)
        mu_aff = (float(np.sum((t + alpha * dt) * (lam + alpha * dl), where=used))
                  + float(np.sum((s + alpha * ds) * (pi + alpha * dp), where=soft))) / n_ineq
        sigma = (mu_aff / mu) ** 3
        dz, dv, dt, dl, ds, dp = direction(np.where(used, t * lam + dt * dl - sigma * mu, 0.0),
                                                np.where(soft, s * pi + ds * dp - sigma * mu, 0.0))
        alpha = max_step(dt, dl, ds, dp, _TAU)
        z, v = z + alpha * dz, v + alpha * dv
        t, lam = np.where(used, t + alpha * dt, 1.0), np.where(used, lam + alpha * dl, 0.0)
        s, pi = np.where(soft, s + alpha * ds, 0.0), np.where(soft, pi + alpha * dp, 1.0)
    merit, iterations, (v, z, s, lam, nu) = best
    if merit <= _ACCEPT:
        return StageQPSolution(v, z, s, lam, nu, iterations, "optimal", merit)
    Fx = _rows_times(qp, z, v)
    hard = used & ~soft
    excess = np.where(hard, Fx - f, -np.inf)
    i, j = np.unravel_index(int(np.argmax(excess)), excess.shape)
    message = (f"stage-wise IPM stopped after {iterations} iterations (KKT residual {merit:.3g}); the largest "
               f"hard-row violation is {max(float(excess[i, j]), 0.0):.3g} at stage {i}, row {j}: the hard limits "
               "cannot all hold (infeasible)")
    return StageQPSolution(v, z, s, lam, nu, iterations, "infeasible", merit, message)
