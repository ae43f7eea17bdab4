"""Stage-wise primal-dual interior-point method for constrained linear-quadratic problems.

The reference (Python) twin of the compiled ``_native.StagewiseIPM``; it knows nothing about
GPC. The problem, over stages i = 0..N−1 of a linear time-varying model with an affine term
(the structure HPIPM's ``ocp_qp_ipm`` solves; this is an independent implementation),

    z(i+1) = A_i z(i) + B_i v(i) + c_i,   z(0) = z0 given     (v(i) exists for i < n_decide)
    Φ = Σ_{i=0..N} ½ z(i)ᵀ Q_i z(i) + q_iᵀ z(i) + Σ_{i<n_decide} ½ v(i)ᵀ R v(i) + v(i)ᵀ S z(i)
        + Σ_soft (ρ s_j + ½ κ s_j²)
    F_i [z(i); v(i)] ≤ f_i (+ s_j, s_j ≥ 0, on a soft row j),

is solved by Mehrotra's predictor-corrector. Every iteration factorizes ONE Riccati recursion
of the Newton system (the inequalities enter as the diagonal row weights W = Λ T⁻¹, the soft
rows' slacks eliminated row by row) and back-substitutes it for the predictor and the corrector
(plus at most :data:`_REFINE` refinement passes each): the work per iteration grows linearly
with N. The equality (dynamics) rows are satisfied by every iterate (the forward sweep simulates
them), so only the stationarity, inequality and complementarity residuals are driven to zero.
Accuracy: the Newton steps are solved in delta form (their rounding scales with the step, not
with the iterate: W ~ 1/μ would otherwise amplify it into the multipliers), the objective is
scaled to unit curvature in v first, and the converged iterate is polished by Newton steps on
its active rows alone (the inactive rows' barrier no longer bends the plan along the flat
directions of a redundant robot's criterion). The iterations stop at the tolerance or at the
rounding floor (the first iterate that does not improve on the best one below :data:`_FLOOR`,
or :data:`_STALL` iterations without marked progress), never factorizing the stopping iterate;
a Newton system that loses positive definiteness to rounding is shifted and refined
(:func:`_cholesky`). A :class:`StageStart` (a controller's previous solution, shifted) starts
the iterations near the solution.

Newton system (rows t = f + S s − F x ≥ 0 with multipliers λ, slacks s ≥ 0 with π):
    dλ = W F dx + w0,  W = d (hard) or d (κ + π / s) / a = d (1 − d / a) (soft),  d = λ / t,  a = κ + d + π / s,
    (H + Fᵀ W F) x⁺ + g + Fᵀ (λ + w0 − W F x) + Eᵀ ν⁺ = 0     (one LQ problem: Riccati).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from ..errors import SolverError

__all__ = ["StageQP", "StageStart", "StageQPSolution", "solve_stage_qp", "stopped_short", "IPM_TOL", "IPM_MAX_ITER",
           "CROSSOVER"]

#: stopping tolerance, relative to the problem's scale (largest gradient/penalty entry, ≥ 1).
IPM_TOL = 1e-13
#: iteration cap: a problem still not converged is reported (hard limits infeasible, typically).
IPM_MAX_ITER = 60
#: the merit (relative KKT residual) at which a caller that can verify an active set stops the
#: iterations (``crossover`` of :func:`solve_stage_qp`): the stage-wise active set of input rows, started
#: from the set the iterate's multipliers name, settles in 1–5 sweeps from a cold start's iterate at 0.1
#: (planar_4rrr, Qu = 1e-5, N = 160, 637 of 640 inputs on a limit, every form: 10–13 iterations of the
#: 15–21 plus the polish to the tolerance; at 10 the absolute form's set needs 9 sweeps, at 1, 2–4). Not
#: from a warm start: its first iterates sit near the shifted set the active set has just failed to
#: settle from (12 sweeps, unsettled, at every merit down to 1e-3).
CROSSOVER = 0.1
#: fraction of the step to the boundary of the positive orthant.
_TAU = 0.995
#: iterative-refinement passes per Newton step (one back-substitution each, same factorization).
_REFINE = 2
#: a Newton step is refined only while its stationarity residual exceeds this fraction of the
#: iterate's merit (relative to the scale; at least 1e-15): far from the solution no pass is needed.
_REFINE_FORCING = 1e-3
#: a best iterate whose relative KKT residual is at most this is accepted (the rounding floor of
#: a badly scaled problem sits above IPM_TOL); above it the iterations stopped short (:func:`stopped_short`).
_ACCEPT = 1e-6
#: the iterations stop after this many without a markedly better iterate (the rounding floor reached).
_STALL = 3
#: a better iterate is a marked improvement when its merit is below this fraction of the last marked
#: one (creeping at the rounding floor, 5e-11 → 4e-11 over 50 iterations, is not progress).
_PROGRESS = 0.5
#: how far (relative to the largest bound) a polished plan may sit beyond a row: rounding only.
_POLISH_TOL = 1e-9
#: active-set corrections of the polishing step.
_POLISH_ROUNDS = 3
#: the smallest t, s (relative to the bounds) and λ, π (relative to the gradient) a polishing step starts from.
_POLISH_FLOOR = 1e-16
#: Newton steps per polishing round.
_POLISH_STEPS = 2
#: below this relative KKT residual an iterate that does not improve on the best one is the
#: rounding floor: the iterations stop there, and the best iterate is not polished (nothing to gain).
_FLOOR = 1e-9
#: first diagonal shift (relative to the largest diagonal entry) of a Newton system that is not
#: positive definite to working precision, and the largest before giving up.
_SHIFT, _SHIFT_MAX = 1e-14, 1e-8
#: a warm start's slacks t, s (relative to the bounds) and multipliers λ, π (relative to the
#: gradient) are kept at least this far from 0 (the iterations stay centered).
_WARM = 1e-3


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
        S: (m, nz) cross weight of the decision stages, or None (zero).
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
    S: np.ndarray | None = None


@dataclass
class StageStart:
    """A warm start of :func:`solve_stage_qp` (a guess: any one leads to the same solution).

    Attributes:
        v: (n_decide, m) plan, or None (the unconstrained plan). lam: (N, k) row multipliers and
            s: (N, k) soft rows' slacks (the problem's units).
    """

    v: np.ndarray | None
    lam: np.ndarray
    s: np.ndarray


@dataclass
class StageQPSolution:
    """The solution of a :class:`StageQP`.

    Attributes:
        v: (n_decide, m); z: (N + 1, nz); s: (N, k) slacks (0 on hard and unused rows);
        lam: (N, k) row multipliers; nu: (N + 1, nz) costates (nu[0] unused: z0 is given);
        iterations: IPM iterations; status: ``"optimal"``, ``"infeasible"`` (not converged:
        hard rows that cannot all hold) — the message says which —, ``"unconverged"`` (stopped short with
        every hard row holding, :func:`stopped_short`) or ``"crossover"`` (stopped at the caller's
        ``crossover`` merit, see :func:`solve_stage_qp`); residual: the largest KKT residual, relative
        to the scale.
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


def _cholesky(Hvv: np.ndarray, i: int, W: np.ndarray, regularize: bool):
    """The Cholesky factor of stage i's input Hessian Hvv = R + Fvᵀ W Fv + BᵀPB.

    ``regularize`` (an interior-point iterate): a matrix that is not positive definite to working
    precision (the row weights W = λ/t grow like 1/μ as rows become active, and BᵀPB loses the
    digits of R next to them) is shifted by :data:`_SHIFT` · its largest diagonal entry, growing
    tenfold up to :data:`_SHIFT_MAX`, and factorized again: the step's iterative refinement
    against the unshifted system removes the shift.

    Raises:
        SolverError: non-finite entries; or a matrix that stays singular (the message says which:
            the unconstrained problem's R + BᵀPB not ≻ 0, or an ill-conditioned Newton system).
    """
    if not np.all(np.isfinite(Hvv)):
        raise SolverError(f"stage-wise IPM: the Newton system at stage {i} has non-finite entries (NaN or inf in "
                          "the model, the weights or the limits)")
    shift, top = 0.0, float(np.max(np.abs(np.diag(Hvv))))
    while True:
        try:
            return sla.cho_factor(Hvv + shift * np.eye(len(Hvv)) if shift else Hvv, check_finite=False)
        except np.linalg.LinAlgError:
            if not regularize:
                raise SolverError(f"stage-wise IPM: the input Hessian R + BᵀPB at stage {i} is not positive "
                                  "definite (the input weight Qu must be nonsingular)") from None
            shift = _SHIFT * top if shift == 0.0 else 10.0 * shift
            if shift > _SHIFT_MAX * top:
                raise SolverError(f"stage-wise IPM: the Newton system at stage {i} is singular to working "
                                  f"precision (row weights λ/t up to {float(np.max(W, initial=0.0)):.3g}, the "
                                  f"input Hessian's diagonal up to {top:.3g}): an ill-conditioned iterate, "
                                  "not the input weight") from None


class _Riccati:
    """The Riccati factorization of one Newton system (row weights W) and its back-substitution."""

    def __init__(self, qp: StageQP, W: np.ndarray, regularize: bool = False):
        N, nd = qp.A.shape[0], qp.n_decide
        self.qp = qp
        self.Pn = [None] * N     # P_{i+1}
        self.fac = [None] * nd   # Cholesky of Hvv_i
        self.Hvz = [None] * nd
        self.K = [None] * nd
        self.h_max = 0.0  # the largest diagonal entry of the input Hessians R + BᵀPB (+ rows)
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
                if qp.S is not None:
                    Hvz = Hvz + qp.S
                self.h_max = max(self.h_max, float(np.max(np.diag(Hvv))))
                self.fac[i] = _cholesky(Hvv, i, W, regularize)
                self.Hvz[i], self.K[i] = Hvz, -sla.cho_solve(self.fac[i], Hvz, check_finite=False)
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
                kk[i] = -sla.cho_solve(self.fac[i], gv[i] + qp.B[i].T @ w, check_finite=False)
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


def costates(qp: StageQP, z, v, lam, linear: bool = True, active: tuple | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
    """The costates ν that make the Lagrangian stationary in z(1..N) (a backward recursion,
    ν_N = Q_N z_N + q_N, ν_i = Q_i z_i + q_i + A_iᵀ ν_{i+1} + F_{z,i}ᵀ λ_i) and the remaining
    gradient in v, R v(i) + B_iᵀ ν_{i+1} + F_{v,i}ᵀ λ_i, (n_decide, m): zero at the optimum.
    ``linear=False``: without q (the change of both along a step (dz, dv, dλ)).

    ``active`` = (comp (N, k), sign (N, k), fixed (n_decide, m)): the active set of
    :mod:`~parallel_gpc.solvers.stagewise_active` (rows σ_r v_j + Fz_r z ≤ f_r, ``fixed[i, j]`` the row
    fixing component j of v(i) or −1): the multipliers of those rows are not given but solved for in
    the recursion, stage by stage (the row's component of the v-gradient vanishes: λ_r = −σ_r g_j,
    g = R v + S z + Bᵀ ν_{i+1}) and written into ``lam`` (zero on entry); the v-gradient is then zero
    on the fixed components.

    Returns:
        (ν (N + 1, nz) with ν_0 = 0, the v-gradient (n_decide, m)).
    """
    N, nd = qp.A.shape[0], qp.n_decide
    gz, gv = _rows_transpose(qp, lam)
    g = np.einsum("inm,im->in", qp.Q, z) + gz
    if linear:
        g += qp.q
    if qp.S is not None:
        g[:nd] += v @ qp.S
    rv = v @ qp.R.T + gv
    if qp.S is not None:
        rv += z[:nd] @ qp.S.T
    nu = np.zeros_like(z)
    nu[N] = g[N]
    if active is None:
        for i in range(N - 1, 0, -1):
            nu[i] = g[i] + qp.A[i].T @ nu[i + 1]
    else:
        comp, sign, fixed = active
        for i in range(N - 1, -1, -1):
            nxt = qp.A[i].T @ nu[i + 1]
            if i < nd:
                fix = fixed[i] >= 0
                r = fixed[i][fix]
                lam[i, r] = -sign[i, r] * (rv[i, fix] + qp.B[i][:, fix].T @ nu[i + 1])
                nxt += qp.Fz[i, r].T @ lam[i, r]
            if i > 0:
                nu[i] = g[i] + nxt
        rv += _rows_transpose(qp, lam)[1]  # the fixed components' gradient: zero by construction
    rv += np.einsum("imk,im->ik", qp.B[:nd], nu[1:nd + 1])
    return nu, rv


def solve_stage_qp(qp: StageQP, tol: float = IPM_TOL, max_iter: int = IPM_MAX_ITER,
                   start: StageStart | None = None, crossover: float = 0.0) -> StageQPSolution:
    """Solve a :class:`StageQP` by Mehrotra's predictor-corrector, one Riccati factorization per iteration.

    The objective is first divided by the largest diagonal entry σ of the unconstrained input
    Hessians R + BᵀPB (the plan's curvature: a controller's ŷ moves by ~Ts² per N·m, so Φ's
    curvature in v can be 1e-10 while its gradient in z is O(1)); the tolerances are relative
    to the reduced gradient at v = 0 and to the rows' bounds. The multipliers are returned in
    the problem's own units.

    Args:
        qp: the problem. tol: stopping tolerance relative to the scale. max_iter: iteration cap.
        start: a guess of the solution (the previous step's, shifted), or None: the iterations
            start from the unconstrained plan.
        crossover: a relative KKT residual (the iterations' merit) at which to stop early, or 0
            (never): the first iterate at or below it is returned as it is (not polished), status
            ``"crossover"``: its multipliers name the active set for a method that verifies it
            (:data:`CROSSOVER`; gpc/stagewise.py hands it to the active set).

    Returns:
        The solution (status ``"infeasible"`` or ``"unconverged"`` when the iterations stop short,
        :func:`stopped_short`: the message names the largest remaining violation of a hard row, or says
        that every hard row holds; ``"crossover"``: see ``crossover``).

    Raises:
        SolverError: a Newton system that is not positive definite (R not ≻ 0, non-finite data).
    """
    N, nd = qp.A.shape[0], qp.n_decide
    used = np.isfinite(qp.f)
    zero_gv = np.zeros((nd, qp.R.shape[0]))
    free = _Riccati(qp, np.zeros(used.shape))
    z, v = free.solve(qp.q, zero_gv)
    sigma = free.h_max if free.h_max > 0.0 and np.isfinite(free.h_max) else 1.0
    if not used.any():  # an unconstrained problem: the one Riccati solve
        nu, rv = costates(qp, z, v, np.zeros(used.shape))
        res = float(np.max(np.abs(rv), initial=0.0)) / max(sigma * float(np.max(np.abs(v), initial=0.0)), 1e-300)
        return StageQPSolution(v, z, np.zeros(used.shape), np.zeros(used.shape), nu, 0, "optimal", res)
    scaled = StageQP(qp.A, qp.B, qp.c, qp.z0, qp.Q / sigma, qp.q / sigma, qp.R / sigma, nd, qp.Fz, qp.Fv, qp.f,
                     qp.soft, qp.rho / sigma, qp.kappa / sigma, None if qp.S is None else qp.S / sigma)
    if start is not None and start.v is not None:
        v = np.asarray(start.v, float).reshape(v.shape)
        z = simulate(qp, v)
    sol = _solve_scaled(scaled, z, v, tol, max_iter, None if start is None else (start.lam / sigma, start.s),
                        crossover)
    sol.lam *= sigma
    sol.nu *= sigma
    return sol


class _Newton:
    """One Newton system of the iterate (z, v, t, λ, s, π) on the rows ``used`` (soft ones ``soft``):
    its residuals, merit and Riccati factorization; :meth:`direction` solves it in delta form."""

    def __init__(self, qp: StageQP, point: tuple, used, soft, scale: float, f_scale: float, factor: bool = True):
        self.qp, self.used, self.soft, self.scale = qp, used, soft, scale
        z, v, t, lam, s, pi = point
        self.point = point
        self.f = f = np.where(used, qp.f, 0.0)
        Fx = _rows_times(qp, z, v)
        self.r_t = r_t = np.where(used, Fx - s + t - f, 0.0)
        self.r_s = np.where(soft, qp.rho + qp.kappa * s - lam - pi, 0.0)
        n_ineq = max(int(used.sum() + soft.sum()), 1)
        self.mu = (float(np.sum(t * lam, where=used)) + float(np.sum(s * pi, where=soft))) / n_ineq
        self.nu, self.rv = costates(qp, z, v, lam)
        res = max(float(np.max(np.abs(self.rv), initial=0.0)), float(np.max(np.abs(self.r_s)))) / scale
        self.merit = max(self.mu / (scale * f_scale), float(np.max(np.abs(r_t))) / f_scale, res)
        # an inexact Newton step: its error need only be small against the residual it removes
        self.refine_above = max(1e-15, _REFINE_FORCING * self.merit) * scale
        if factor:
            self.factor()

    def factor(self, regularize: bool = False) -> None:
        """Factorize the Newton system (its row weights W and their Riccati recursion); ``regularize``:
        as in :class:`_Riccati` (the direction's refinement removes the shift)."""
        qp, used, soft = self.qp, self.used, self.soft
        _, _, t, lam, s, pi = self.point
        self.d = np.where(used, lam / t, 0.0)
        self.sp = np.where(soft, pi / np.where(soft, s, 1.0), 0.0)
        self.a = np.where(soft, qp.kappa + self.d + self.sp, 1.0)
        self.W = np.where(soft, self.d * (qp.kappa + self.sp) / self.a, self.d)  # d (1 − d / a), no cancellation
        self.ric = _Riccati(qp, self.W, regularize)

    def direction(self, r_tl, r_sp):
        """(dz, dv, dt, dλ, ds, dπ) for the complementarity targets t λ − r_tl and s π − r_sp."""
        qp, used, soft, W, d, a, sp = self.qp, self.used, self.soft, self.W, self.d, self.a, self.sp
        z, v, t, lam, s, pi = self.point
        s_safe = np.where(soft, s, 1.0)
        gam = np.where(used, (-r_tl + lam * self.r_t) / t, 0.0)
        beta = np.where(soft, -self.r_s + gam - r_sp / s_safe, 0.0)
        w0 = np.where(soft, (gam * (qp.kappa + sp) + d * (self.r_s + r_sp / s_safe)) / a, gam)
        # delta form: the step's errors scale with the step (not with the iterate), so the
        # multipliers' rounding (row weights W ~ 1/μ) vanishes as the iterations converge
        gz, gv = _rows_transpose(qp, w0)
        dz, dv = self.ric.solve(gz, gv + self.rv, homogeneous=True)
        for _ in range(_REFINE):  # iterative refinement on the Newton system's own residual
            Fdx = _rows_times(qp, dz, dv)
            _, rv1 = costates(qp, dz, dv, W * Fdx + w0, linear=False)
            rv1 += self.rv
            if not np.max(np.abs(rv1), initial=0.0) > self.refine_above:
                break
            cz, cv = self.ric.solve(np.zeros_like(qp.q), rv1, homogeneous=True)
            dz, dv = dz + cz, dv + cv
        Fdx = _rows_times(qp, dz, dv)
        ds = np.where(soft, (beta + d * Fdx) / a, 0.0)
        dl = np.where(used, W * Fdx + w0, 0.0)
        dt = np.where(used, -self.r_t - Fdx + ds, 0.0)
        dp = np.where(soft, (-r_sp - pi * ds) / s_safe, 0.0)
        return dz, dv, dt, dl, ds, dp

    def max_step(self, dt, dl, ds, dp, frac: float) -> float:
        """The largest step ≤ 1 keeping t, λ, s, π positive (a fraction ``frac`` of the way to the boundary)."""
        _, _, t, lam, s, pi = self.point
        alpha = 1.0
        for x, dx, mask in ((t, dt, self.used), (lam, dl, self.used), (s, ds, self.soft), (pi, dp, self.soft)):
            neg = mask & (dx < 0)
            if neg.any():
                alpha = min(alpha, frac * float(np.min(-x[neg] / dx[neg])))
        return alpha

    def moved(self, step: tuple, alpha: float) -> tuple:
        """The iterate moved by alpha along ``step``."""
        z, v, t, lam, s, pi = self.point
        dz, dv, dt, dl, ds, dp = step
        used, soft = self.used, self.soft
        return (z + alpha * dz, v + alpha * dv, np.where(used, t + alpha * dt, 1.0),
                np.where(used, lam + alpha * dl, 0.0), np.where(soft, s + alpha * ds, 0.0),
                np.where(soft, pi + alpha * dp, 1.0))


def _deemed_active(point: tuple, used: np.ndarray, scale: float, f_scale: float) -> np.ndarray:
    """(N, k) the used rows that the iterate ``point`` deems active: λ/scale > t/f_scale, λ and the row's
    slack t each against its own scale (the polish's first set, the crossover's multipliers)."""
    return used & (point[3] * f_scale > point[2] * scale)


def _polish(qp: StageQP, point: tuple, used, soft, scale: float, f_scale: float, merit: float):
    """Newton steps (σ = 0, full length) with the rows that are inactive at ``point`` dropped
    (λ/scale < t/f_scale): their barrier no longer pushes the plan along the problem's flat
    directions. A kept row whose multiplier turns negative is dropped, a dropped row that the
    plan breaks is kept, and the step is retaken (at most :data:`_POLISH_ROUNDS` times). The
    result is kept when every row holds, the multipliers are ≥ 0 and the KKT residual of the full
    problem does not grow; else None."""
    active = _deemed_active(point, used, scale, f_scale)
    f = np.where(used, qp.f, 0.0)
    for _ in range(_POLISH_ROUNDS):
        keep_soft = soft & active
        current = point
        for _ in range(_POLISH_STEPS):  # Newton steps on the kept rows (their weights grow as t → 0)
            z, v, t, lam, s, pi = current
            tf, lf = _POLISH_FLOOR * f_scale, _POLISH_FLOOR * scale  # row weights λ/t stay finite
            start = (z, v, np.where(active, np.maximum(t, tf), 1.0), np.where(active, np.maximum(lam, lf), 0.0),
                     np.where(keep_soft, np.maximum(s, tf), 0.0), np.where(keep_soft, np.maximum(pi, lf), 1.0))
            try:
                newton = _Newton(qp, start, active, keep_soft, scale, f_scale)
            except SolverError:
                break
            newton.refine_above = 1e-15 * scale  # the polish is the last word: refined to the rounding floor
            step = newton.direction(np.where(active, start[2] * start[3], 0.0),
                                    np.where(keep_soft, start[4] * start[5], 0.0))
            current = newton.moved(step, 1.0)
        z, v, t, lam, s, pi = current
        gap = f + s - _rows_times(qp, z, v)  # the full problem's row slacks at the polished plan
        broken = used & ~active & (gap < -_POLISH_TOL * f_scale)
        negative = active & ((lam < -_POLISH_TOL * scale) | (keep_soft & (s < -_POLISH_TOL * f_scale)))
        if not broken.any() and not negative.any():
            break
        active = (active & ~negative) | broken
    else:
        return None
    if np.any(used & (gap < -_POLISH_TOL * f_scale)):
        return None
    t = np.where(used, np.maximum(gap, 0.0), 1.0)
    pi = np.where(soft & ~keep_soft, qp.rho + qp.kappa * s - lam, pi)  # dropped soft rows: s = 0, λ = 0
    point = (z, v, t, np.maximum(lam, 0.0), np.maximum(s, 0.0), np.where(soft, np.maximum(pi, 0.0), 1.0))
    polished = _Newton(qp, point, used, soft, scale, f_scale, factor=False)
    return (polished.merit, point, polished.nu) if polished.merit <= max(merit, IPM_TOL) else None


def simulate(qp: StageQP, v: np.ndarray) -> np.ndarray:
    """The states z (N + 1, nz) of the plan v (n_decide, m): the dynamics rows held exactly."""
    N, nd = qp.A.shape[0], qp.n_decide
    z = np.empty((N + 1, qp.A.shape[1]))
    z[0] = qp.z0
    for i in range(N):
        z[i + 1] = qp.A[i] @ z[i] + qp.c[i] + (qp.B[i] @ v[i] if i < nd else 0.0)
    return z


def _solve_scaled(qp: StageQP, z, v, tol: float, max_iter: int, start=None, crossover: float = 0.0
                  ) -> StageQPSolution:
    """The interior-point iterations on a scaled problem from the plan (z, v) (the unconstrained one,
    or a warm start whose row multipliers and slacks are ``start`` = (λ, s), scaled); ``crossover``:
    see :func:`solve_stage_qp`."""
    used = np.isfinite(qp.f)
    soft = qp.soft & used
    f = np.where(used, qp.f, 0.0)
    n_ineq = int(used.sum() + soft.sum())
    _, rv0 = costates(qp, z, np.zeros_like(v), np.zeros(used.shape))  # the gradient's scale at v = 0
    scale = max(float(np.max(np.abs(rv0), initial=0.0)), qp.rho if soft.any() else 0.0, 1e-300)
    f_scale = max(float(np.max(np.abs(f[used]))), 1e-12)
    Fx = _rows_times(qp, z, v)
    s = np.where(soft, np.maximum(Fx - f, 0.0) + f_scale, 0.0)
    # the rows' multipliers start at scale·N²: a row of stage i balances the criterion of the stages
    # after it, which grows like N² in a controller's problem (measured: the multipliers reach
    # ~1e4·scale at N = 80; starting at scale, the iterations crawl towards them with steps ~1e-2,
    # 35–40 iterations at N = 80 against 11–15 from scale·N², and the same ~12 at N = 20)
    lam0 = scale * float(qp.A.shape[0]) ** 2
    point = (z, v, np.where(used, np.maximum(f + s - Fx, f_scale), 1.0), np.where(used, lam0, 0.0), s,
             np.where(soft, scale, 1.0))
    if start is not None:
        lam_w, s_w = start
        th_t, th_l = _WARM * f_scale, _WARM * scale
        s = np.where(soft, np.maximum(np.maximum(s_w, Fx - f), 0.0) + th_t, 0.0)
        lam = np.where(used, np.maximum(lam_w, th_l), 0.0)
        pi = np.where(soft, np.maximum(qp.rho + qp.kappa * s - lam, th_l), 1.0)
        point = (z, v, np.where(used, np.maximum(f + s - Fx, th_t), 1.0), lam, s, pi)
    best = None  # (merit, iterations, point, ν): the iterations stop at the tolerance or at the rounding floor
    marked = (np.inf, 0)  # (merit, iteration) of the last marked improvement
    for it in range(max_iter + 1):
        newton = _Newton(qp, point, used, soft, scale, f_scale, factor=False)
        if newton.merit <= crossover:  # the caller's crossover: this iterate, λ kept on the rows it deems active
            z, v, _, lam, s, _ = point
            lam = np.where(_deemed_active(point, used, scale, f_scale), lam, 0.0)
            return StageQPSolution(v, z, np.where(soft, s, 0.0), lam, newton.nu, it, "crossover", newton.merit)
        improved = best is None or newton.merit < best[0]
        if improved:
            best = (newton.merit, it, point, newton.nu)
        if newton.merit < _PROGRESS * marked[0]:
            marked = (newton.merit, it)
        if newton.merit <= tol or it == max_iter:
            break
        if (it - marked[1] >= _STALL and best[0] <= _ACCEPT) or (not improved and best[0] <= _FLOOR):
            break  # the rounding floor: keep the best iterate (the stopping iterate is never factorized)
        try:
            newton.factor(regularize=True)
        except SolverError:
            if best[0] <= _ACCEPT:  # row weights beyond the factorization's precision
                break
            raise
        t, lam, s, pi = point[2:]
        aff = newton.direction(np.where(used, t * lam, 0.0), np.where(soft, s * pi, 0.0))
        dt, dl, ds, dp = aff[2:]
        alpha = newton.max_step(dt, dl, ds, dp, 1.0)
        mu_aff = (float(np.sum((t + alpha * dt) * (lam + alpha * dl), where=used))
                  + float(np.sum((s + alpha * ds) * (pi + alpha * dp), where=soft))) / n_ineq
        sigma = (mu_aff / newton.mu) ** 3
        step = newton.direction(np.where(used, t * lam + dt * dl - sigma * newton.mu, 0.0),
                                np.where(soft, s * pi + ds * dp - sigma * newton.mu, 0.0))
        point = newton.moved(step, newton.max_step(*step[2:], _TAU))
    merit, iterations, point, nu = best
    if merit <= _ACCEPT:
        polished = _polish(qp, point, used, soft, scale, f_scale, merit)
        if polished is not None:
            merit, point, nu = polished
    z, v, t, lam, s, _ = point
    if merit <= _ACCEPT:
        return StageQPSolution(v, z, np.where(soft, s, 0.0), lam, nu, iterations, "optimal", merit)
    status, message = stopped_short(qp, z, v, iterations, merit)
    return StageQPSolution(v, z, np.where(soft, s, 0.0), lam, nu, iterations, status, merit, message)


def stopped_short(qp: StageQP, z: np.ndarray, v: np.ndarray, iterations: int, merit: float) -> tuple[str, str]:
    """(status, message) of interior-point iterations that stopped short of the tolerance at the plan
    (z (N + 1, nz), v (n_decide, m)) with relative KKT residual ``merit`` (the Python iterations' and the
    compiled ``_native.stagewise_ipm``'s): ``"infeasible"`` when a hard row is exceeded by more than
    1e-6 of the largest bound (at least 1e-6 in the rows' units; the message names the row: typically
    limits that cannot all hold, though a cap reached early stops at such an iterate too), else
    ``"unconverged"``: every hard row holds, the iterations stalled above the tolerance (a badly scaled or
    degenerate problem), and nothing shows the limits infeasible."""
    used = np.isfinite(qp.f)
    f = np.where(used, qp.f, 0.0)
    excess = np.where(used & ~qp.soft, _rows_times(qp, z, v) - f, -np.inf)
    i, j = np.unravel_index(int(np.argmax(excess)), excess.shape)
    worst = max(float(excess[i, j]), 0.0)
    head = f"stage-wise IPM stopped after {iterations} iterations (KKT residual {merit:.3g})"
    if worst > _ACCEPT * max(1.0, float(np.max(np.abs(f), initial=0.0))):
        return "infeasible", (f"{head}; the largest hard-row violation is {worst:.3g} at stage {i}, row {j}: "
                              "the hard limits cannot all hold (infeasible), or not within the iterations")
    return "unconverged", (f"{head} with every hard row within its bound (largest excess {worst:.3g}): "
                           "not converged, and not shown infeasible")
