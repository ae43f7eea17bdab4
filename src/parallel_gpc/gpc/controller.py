"""Receding-horizon GPC controller (DESIGN §3–§5): model update → prediction → solve → u(k).

Three forms (``form=``):

* ``"absolute"`` — eq. (7), v = u, Qu penalizes u;
* ``"incremental"`` — eq. (8)–(9), v = Δu, u(k) = u(k−1) + Δu(k): integral action;
* ``"nonlinear"`` — incremental with nonlinear simulative prediction, eq. (10)–(12): the
  previous optimal sequence, shifted, is pre-simulated with the state-dependent model
  X(i+1) = A_d(X_sim(i)) X_sim(i) + B_d(X_sim(i)) u_sim(i) + c_d(X_sim(i)) and the deviation
  model along that trajectory gives ŷ = ŷ_sim + G Δu.

The model at a state is the state-dependent factorization (3), discretized by ZOH (4).
Only the first move is applied; the rest of the plan warm-starts the next step.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..model.dynamics import ReducedModel
from ..errors import (
    InfeasibleLimitsError,
    InvalidParameterError,
    NonFiniteError,
    ShapeError,
    SingularPoseError,
    SolverError,
)
from .prediction import (
    Horizons,
    Prediction,
    absolute_prediction,
    incremental_prediction,
    simulative_prediction,
)
from ..solvers import SolveResult, make_solver, qr_least_squares
from .criterion import Weights, _limit_vector, build_problem
from ..validation import finite_vector, positive

FORMS = ("absolute", "incremental", "nonlinear")
#: QP back end used when torque limits are given and no solver is named.
DEFAULT_LIMITED_SOLVER = "qr-first:daqp-direct"
#: the QP is given limits tightened by this relative margin so that a solution within the
#: solver's tolerance never exceeds the true limit (|u| ≤ τ exactly, nothing clipped later).
LIMIT_MARGIN = 1e-6


@dataclass
class StepInfo:
    """What one control step did.

    Attributes:
        u: (m,) applied drive torques (N·m).
        result: the solver's :class:`SolveResult` (status ``fallback`` if the solve failed).
        model_time, predict_time, solve_time: wall times in s of the three phases.
        fallback: True when the applied u did not come from a successful solve.
    """

    u: np.ndarray
    result: SolveResult
    model_time: float
    predict_time: float
    solve_time: float
    fallback: bool = False

    @property
    def step_time(self) -> float:
        return self.model_time + self.predict_time + self.solve_time


@dataclass
class GPCController:
    """State-space GPC on the reduced model of a parallel robot.

    Args:
        model: the controller's reduced model (may differ from the plant: mismatch studies).
        Ts: sample time in s.
        horizons: N, No, Nu.
        weights: square-root weights Qy, Qu.
        form: ``"absolute"``, ``"incremental"`` or ``"nonlinear"``.
        solver: back-end name (see :func:`parallel_gpc.solvers.make_solver`); default ``"qr"``
            without limits, ``"qr-first:daqp-direct"`` with limits.
        torque_limit: symmetric drive torque limit (N·m), scalar or (m,), or None.
        du_limit: symmetric increment limit (N·m per sample), incremental forms only.
        u0: (m,) input applied before the first step, u(−1) (N·m); default zero.
        disturbance_gain: α ∈ [0, 1] of the state-disturbance estimate
            d ← (1 − α) d + α (X(k) − X̂(k|k−1)) added to the model's affine term over the
            horizon. It makes the prediction unbiased under model mismatch with a steady load
            (gravity, a constant force), which the incremental forms need to reach zero
            steady-state error. Default: 0.5 for the incremental forms, 0 for the absolute form.
        max_condition: largest accepted condition number of the model's input gain
            g = M_r⁻¹ B_r (discretized) at the measured state; beyond it the step raises
            :class:`~parallel_gpc.errors.SingularPoseError` instead of commanding the unbounded
            torques a (near-)singular pose calls for. Default 1e3: cond(g) is 10–20 along the paper's
            S-curve and A→B on both embedded robots, 1e3 is about 1 cm from a planar_3rrr direct
            singularity.

    Raises:
        InvalidParameterError: bad Ts, form, horizons, weights or limits.
        InfeasibleLimitsError: limits that admit no input (≤ 0, or u0 outside ±(τ + δ) in the
            incremental forms: no Δu within ±δ brings it within ±τ).
    """

    model: ReducedModel
    Ts: float
    horizons: Horizons
    weights: Weights = field(default_factory=Weights)
    form: str = "absolute"
    solver: str | None = None
    torque_limit: object = None
    du_limit: object = None
    u0: object = None
    disturbance_gain: float | None = None
    max_condition: float = 1e3

    def __post_init__(self):
        self.Ts = positive("Ts", self.Ts, " s")
        if self.form not in FORMS:
            raise InvalidParameterError(f"form {self.form!r} is not one of {FORMS}")
        if not isinstance(self.horizons, Horizons):
            raise InvalidParameterError(f"horizons must be a Horizons(N, No, Nu), got {self.horizons!r}")
        self.n_y, self.n_u, self.n_x = self.model.n_y, self.model.n_u, self.model.n_x
        self.weights.blocks(self.n_y, self.n_u)  # validate once, at the boundary
        if self.torque_limit is not None:
            self.torque_limit = _limit_vector("torque_limit", self.torque_limit, self.n_u)
        if self.du_limit is not None:
            self.du_limit = _limit_vector("du_limit", self.du_limit, self.n_u)
        if self.du_limit is not None and self.form == "absolute":
            raise InvalidParameterError("du_limit applies to the incremental forms; form is 'absolute'")
        if self.solver is None:
            self.solver = DEFAULT_LIMITED_SOLVER if self._has_limits else "qr"
        if self.solver == "qr" and self._has_limits:
            raise InvalidParameterError(
                "solver 'qr' cannot enforce torque/Δu limits; use a QP back end such as "
                f"{DEFAULT_LIMITED_SOLVER!r}, 'osqp-direct' or 'qpsolvers:osqp'"
            )
        if self.disturbance_gain is None:
            self.disturbance_gain = 0.0 if self.form == "absolute" else 0.5
        if not 0.0 <= float(self.disturbance_gain) <= 1.0:
            raise InvalidParameterError(f"disturbance_gain = {self.disturbance_gain!r} must lie in [0, 1]")
        self.max_condition = positive("max_condition", self.max_condition)
        self._backend = make_solver(self.solver)
        self.reset(self.u0)

    @property
    def _has_limits(self) -> bool:
        return self.torque_limit is not None or self.du_limit is not None

    def reset(self, u_prev=None) -> None:
        """Forget the plan; set u(k−1) (N·m, default zero)."""
        self.u_prev = np.zeros(self.n_u) if u_prev is None else finite_vector("u_prev", u_prev, self.n_u)
        if self.form != "absolute" and self.torque_limit is not None and self.du_limit is not None:
            reach = _limit_vector("torque_limit", self.torque_limit, self.n_u) + _limit_vector(
                "du_limit", self.du_limit, self.n_u)
            if np.any(np.abs(self.u_prev) > reach):
                raise InfeasibleLimitsError(
                    f"u(k−1) = {self.u_prev.tolist()} N·m cannot be brought within torque_limit "
                    f"{np.broadcast_to(self.torque_limit, (self.n_u,)).tolist()} by one increment within du_limit "
                    f"{np.broadcast_to(self.du_limit, (self.n_u,)).tolist()}; valid: |u(k−1)| ≤ torque_limit + du_limit"
                )
        self.plan = np.tile(self.u_prev, (self.horizons.N, 1))
        self._v_prev = None
        self.disturbance = np.zeros(self.n_x)
        self._x_next = None  # X̂(k+1|k) of the last step, for the disturbance estimate

    # ------------------------------------------------------------------ model + prediction
    def discrete_model(self, X: np.ndarray):
        """(A_d, B_d, c_d) of the factorized model (3) at X, ZOH-discretized at Ts (4)."""
        return self.model.discrete(X, self.Ts)

    def predict(self, X: np.ndarray) -> Prediction:
        """Build ŷ = f + G v for the current state with this controller's form.

        Also keeps the one-step model (A_d, B_d, c_d) at X for the disturbance estimate.
        """
        H, C = self.horizons, self.model.C
        if self.form == "nonlinear":
            return self._simulative(X)
        Ad, Bd, cd = self.discrete_model(X)
        cd = cd + self.disturbance
        self._one_step = (Ad, Bd, cd)
        if self.form == "absolute":
            return absolute_prediction(Ad, Bd, cd, C, X, H)
        return incremental_prediction(Ad, Bd, cd, C, X, self.u_prev, H)

    def _update_disturbance(self, X: np.ndarray) -> None:
        """d ← (1 − α) d + α (X(k) − X̂(k|k−1)): the model's one-step prediction error."""
        alpha = float(self.disturbance_gain)
        if alpha > 0.0 and self._x_next is not None:
            self.disturbance = self.disturbance + alpha * (X - self._x_next)

    def _simulative(self, X: np.ndarray) -> Prediction:
        H, C = self.horizons, self.model.C
        u_sim = np.vstack([self.plan[1:], self.plan[-1:]])  # previous plan, shifted
        # X_sim(i+1) = A_d(X_sim(i)) X_sim(i) + B_d(X_sim(i)) u_sim(i) + c_d(X_sim(i)) + d
        A_seq, B_seq, c_seq, X_sim = self.model.simulate_factorized(X, u_sim, self.Ts, self.disturbance)
        self._one_step = (A_seq[0], B_seq[0], c_seq[0] + self.disturbance, u_sim[0])
        y_sim = X_sim[1:] @ C.T
        return simulative_prediction(A_seq, B_seq, C, y_sim, u_sim, H)

    # ------------------------------------------------------------------ step
    def _reference_rows(self, w) -> np.ndarray:
        H = self.horizons
        w = np.asarray(w, dtype=float)
        if w.shape == (H.N, self.n_y):
            w = w[H.No:]
        elif w.shape != (H.n_rows, self.n_y):
            raise ShapeError(
                f"reference window has shape {w.shape}; expected ({H.N}, {self.n_y}) for steps k+1..k+N "
                f"(or ({H.n_rows}, {self.n_y}) for the penalized steps k+No+1..k+N)"
            )
        if not np.all(np.isfinite(w)):
            bad = w[np.argwhere(~np.isfinite(w))[0][0]]
            raise NonFiniteError(f"reference window contains the pose {bad.tolist()}; poses must be finite")
        return w

    def step(self, X, w) -> StepInfo:
        """One control step.

        Args:
            X: (2·n_y,) measured state [y, ẏ] (m, rad, m/s, rad/s).
            w: (N, n_y) reference poses at k+1..k+N (m, rad).

        Returns:
            StepInfo with the applied u(k) (N·m).
        """
        X = finite_vector("measured state X", X, self.n_x)
        w = self._reference_rows(w)
        t0 = time.perf_counter()
        self._update_disturbance(X)
        pred = self.predict(X)
        self._check_conditioning(X, self._one_step[1])
        t1 = time.perf_counter()
        problem = build_problem(pred, w, self.weights, self.n_y, self.n_u, self._tightened(self.torque_limit),
                                self._tightened(self.du_limit))
        t2 = time.perf_counter()
        try:
            result = self._backend.solve(problem, self._warm_start(problem.n))
        except Exception as exc:  # a back end's own exception: report it and fall back, never leak it
            result = SolveResult(np.full(problem.n, np.nan), np.inf, "failed", self._backend.name,
                                 message=f"{type(exc).__name__}: {exc}")
        fallback = not result.ok
        if fallback:
            result = self._fallback(problem, pred, result)
        t3 = time.perf_counter()
        u_seq = (pred.u_base + pred.u_map @ result.v).reshape(-1, self.n_u)
        u = u_seq[0].copy()
        self.plan = np.vstack([u_seq, np.repeat(u_seq[-1:], self.horizons.N - len(u_seq), axis=0)])
        self._v_prev = result.v
        self.u_prev = u
        Ad, Bd, cd = self._one_step[:3]
        self._x_next = Ad @ X + Bd @ u + cd
        return StepInfo(u, result, t1 - t0, t2 - t1, t3 - t2, fallback)

    def _check_conditioning(self, X: np.ndarray, Bd: np.ndarray) -> None:
        """Raise :class:`SingularPoseError` when the input gain at X is near-singular.

        ``Bd[n_y:]`` ≈ Ts·g with g = M_r⁻¹ B_r of eq. (1); its condition number grows without
        bound at an actuation (direct) singularity and as a leg stretches or folds.
        """
        s = np.linalg.svd(Bd[self.n_y:], compute_uv=False)
        cond = s[0] / s[-1] if s[-1] > 0 else np.inf
        if not cond <= self.max_condition:
            raise SingularPoseError(
                f"near-singular pose {np.round(X[:self.n_y], 6).tolist()}: cond(g) = cond(M_r⁻¹ B_r) = {cond:.3g} "
                f"> max_condition = {self.max_condition:.3g}; the drives cannot move the platform in some "
                f"direction, so the controller stops instead of commanding unbounded torques"
            )

    @staticmethod
    def _tightened(limit):
        return None if limit is None else np.asarray(limit, dtype=float) * (1.0 - LIMIT_MARGIN)

    def _warm_start(self, n: int) -> np.ndarray | None:
        if self._v_prev is None or self._v_prev.shape != (n,):
            return None
        m = self.n_u
        tail = self._v_prev[-m:] if self.form == "absolute" else np.zeros(m)
        return np.concatenate([self._v_prev[m:], tail])

    def _fallback(self, problem, pred: Prediction, failed: SolveResult) -> SolveResult:
        """A failed or infeasible QP: take the unconstrained QR solution and project it on the limits.

        Absolute form: u clipped to ±τ. Incremental forms: step by step along the control
        horizon, Δu(i) clipped to ±δ, then u(i) clipped to ±τ — when both cannot hold (an
        infeasible limit set, e.g. a torque limit lowered below the held u(k−1) − δ) the torque
        limit wins. The result has status ``fallback`` (the back end's status and message are
        kept in ``message``) and the step reports ``StepInfo.fallback``; never silent.
        """
        v, _, _ = qr_least_squares(problem.A, problem.b)
        m = self.n_u
        tau = None if self.torque_limit is None else _limit_vector("torque_limit", self.torque_limit, m)
        if pred.kind == "absolute":
            if tau is not None:
                v = np.clip(v, -np.tile(tau, len(v) // m), np.tile(tau, len(v) // m))
        else:  # walk the horizon: Δu(i) into its box, then u(i) = u_base(i) + Σ Δu into ±τ
            dv = v.reshape(-1, m).copy()
            base = pred.u_base.reshape(-1, m)
            box = None if problem.lb is None else (problem.lb.reshape(-1, m), problem.ub.reshape(-1, m))
            total = np.zeros(m)
            for i in range(len(dv)):
                if box is not None:
                    dv[i] = np.clip(dv[i], box[0][i], box[1][i])
                if tau is not None:  # the torque limit wins when both cannot hold (infeasible set)
                    dv[i] = np.clip(base[i] + total + dv[i], -tau, tau) - base[i] - total
                total += dv[i]
            v = dv.reshape(-1)
        if not np.all(np.isfinite(v)):
            raise SolverError(f"solver {failed.solver} failed ({failed.message}) and the QR fallback is not finite")
        return SolveResult(v, problem.cost(v), "fallback", failed.solver, failed.iterations, failed.solve_time,
                           problem.active(v), f"{failed.status}: {failed.message}; applied the QR solution projected on the limits")
