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

from .dynamics import ReducedModel, discretize_zoh
from .errors import InvalidParameterError, ShapeError, SolverError
from .prediction import Horizons, Prediction, absolute_prediction, incremental_prediction, simulative_prediction
from .solvers import SolveResult, Weights, build_problem, make_solver, qr_least_squares
from .validation import finite_vector, positive

FORMS = ("absolute", "incremental", "nonlinear")
#: QP back end used when torque limits are given and no solver is named.
DEFAULT_LIMITED_SOLVER = "qr-first:proxqp-direct"


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
            without limits, ``"qr-first:proxqp-direct"`` with limits.
        torque_limit: symmetric drive torque limit (N·m), scalar or (m,), or None.
        du_limit: symmetric increment limit (N·m per sample), incremental forms only.
        u0: (m,) input applied before the first step, u(−1) (N·m); default zero.
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

    def __post_init__(self):
        self.Ts = positive("Ts", self.Ts, " s")
        if self.form not in FORMS:
            raise InvalidParameterError(f"form {self.form!r} is not one of {FORMS}")
        if not isinstance(self.horizons, Horizons):
            raise InvalidParameterError(f"horizons must be a Horizons(N, No, Nu), got {self.horizons!r}")
        self.n_y, self.n_u, self.n_x = self.model.n_y, self.model.n_u, self.model.n_x
        self.weights.blocks(self.n_y, self.n_u)  # validate once, at the boundary
        if self.du_limit is not None and self.form == "absolute":
            raise InvalidParameterError("du_limit applies to the incremental forms; form is 'absolute'")
        if self.solver is None:
            self.solver = DEFAULT_LIMITED_SOLVER if self._has_limits else "qr"
        if self.solver == "qr" and self._has_limits:
            raise InvalidParameterError(
                "solver 'qr' cannot enforce torque/Δu limits; use a QP back end such as "
                f"{DEFAULT_LIMITED_SOLVER!r}, 'osqp-direct' or 'qpsolvers:osqp'"
            )
        self._backend = make_solver(self.solver)
        self.reset(self.u0)

    @property
    def _has_limits(self) -> bool:
        return self.torque_limit is not None or self.du_limit is not None

    def reset(self, u_prev=None) -> None:
        """Forget the plan; set u(k−1) (N·m, default zero)."""
        self.u_prev = np.zeros(self.n_u) if u_prev is None else finite_vector("u_prev", u_prev, self.n_u)
        self.plan = np.tile(self.u_prev, (self.horizons.N, 1))
        self._v_prev = None

    # ------------------------------------------------------------------ model + prediction
    def discrete_model(self, X: np.ndarray):
        """(A_d, B_d, c_d) of the factorized model (3) at X, ZOH-discretized at Ts (4)."""
        A, B, c = self.model.factorize(X)
        return discretize_zoh(A, B, c, self.Ts)

    def predict(self, X: np.ndarray) -> Prediction:
        """Build ŷ = f + G v for the current state with this controller's form."""
        H, C = self.horizons, self.model.C
        if self.form == "nonlinear":
            return self._simulative(X)
        Ad, Bd, cd = self.discrete_model(X)
        if self.form == "absolute":
            return absolute_prediction(Ad, Bd, cd, C, X, H)
        return incremental_prediction(Ad, Bd, cd, C, X, self.u_prev, H)

    def _simulative(self, X: np.ndarray) -> Prediction:
        H, C = self.horizons, self.model.C
        u_sim = np.vstack([self.plan[1:], self.plan[-1:]])  # previous plan, shifted
        A_seq = np.empty((H.N, self.n_x, self.n_x))
        B_seq = np.empty((H.N, self.n_x, self.n_u))
        y_sim = np.empty((H.N, self.n_y))
        x = np.asarray(X, dtype=float)
        for i in range(H.N):
            Ad, Bd, cd = self.discrete_model(x)
            A_seq[i], B_seq[i] = Ad, Bd
            x = Ad @ x + Bd @ u_sim[i] + cd
            y_sim[i] = C @ x
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
            raise InvalidParameterError("reference window contains NaN or inf")
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
        pred = self.predict(X)
        t1 = time.perf_counter()
        problem = build_problem(pred, w, self.weights, self.n_y, self.n_u, self.torque_limit, self.du_limit)
        t2 = time.perf_counter()
        result = self._backend.solve(problem, self._warm_start(problem.n))
        fallback = not result.ok
        if fallback:
            result = self._fallback(problem, pred, result)
        t3 = time.perf_counter()
        u_seq = (pred.u_base + pred.u_map @ result.v).reshape(-1, self.n_u)
        u = u_seq[0].copy()
        self.plan = np.vstack([u_seq, np.repeat(u_seq[-1:], self.horizons.N - len(u_seq), axis=0)])
        self._v_prev = result.v
        self.u_prev = u
        return StepInfo(u, result, t1 - t0, t2 - t1, t3 - t2, fallback)

    def _warm_start(self, n: int) -> np.ndarray | None:
        if self._v_prev is None or self._v_prev.shape != (n,):
            return None
        m = self.n_u
        tail = self._v_prev[-m:] if self.form == "absolute" else np.zeros(m)
        return np.concatenate([self._v_prev[m:], tail])

    def _fallback(self, problem, pred: Prediction, failed: SolveResult) -> SolveResult:
        """A failed QP: take the unconstrained QR solution and project its inputs onto the limits.

        The projection is explicit and recorded (status ``fallback``), never silent.
        """
        v, _, _ = qr_least_squares(problem.A, problem.b)
        u_seq = pred.u_base + pred.u_map @ v
        if self.torque_limit is not None:
            tau = np.tile(np.broadcast_to(np.asarray(self.torque_limit, dtype=float), (self.n_u,)),
                          len(u_seq) // self.n_u)
            u_seq = np.clip(u_seq, -tau, tau)
        v = np.linalg.lstsq(pred.u_map, u_seq - pred.u_base, rcond=None)[0]
        if not np.all(np.isfinite(v)):
            raise SolverError(f"solver {failed.solver} failed ({failed.message}) and the QR fallback is not finite")
        return SolveResult(v, problem.cost(v), "fallback", failed.solver, failed.iterations, failed.solve_time,
                           True, f"{failed.status}: {failed.message}; applied QR solution projected on the limits")
