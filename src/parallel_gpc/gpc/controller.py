"""Receding-horizon GPC controller: model update → prediction → solve → u(k).

Three forms (``form=``):

* ``"absolute"`` — eq. (7), v = u, Qu penalizes u;
* ``"incremental"`` — eq. (8)–(9), v = Δu, u(k) = u(k−1) + Δu(k): integral action;
* ``"incremental-delayed"`` — eq. (8)–(9) as printed: state [X(k); u(k)], B̄ = [0; I]; u(k)
  was decided at k−1 and is applied now, the increment computed at k is realized at k+1
  (a one-sample computation delay);
* ``"nonlinear"`` — incremental with nonlinear simulative prediction, eq. (10)–(12): the
  previous optimal sequence, shifted, is pre-simulated with the state-dependent model
  X(i+1) = A_d(X_sim(i)) X_sim(i) + B_d(X_sim(i)) u_sim(i) + c_d(X_sim(i)) and the deviation
  model along that trajectory gives ŷ = ŷ_sim + G Δu.

The model is any :class:`~parallel_gpc.gpc.ControlModel`: a robot's
:class:`~parallel_gpc.model.ReducedModel` (the state-dependent factorization (3), discretized
by ZOH (4)) or a plain :class:`~parallel_gpc.gpc.DiscreteLinearModel`. The settings are a
frozen :class:`~parallel_gpc.gpc.GPCSettings`; what the controller carries between steps is
snapshot by :attr:`GPCController.state` and put back by :meth:`GPCController.restore`.
Only the first move is applied; the rest of the plan warm-starts the next step.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ..errors import InfeasibleLimitsError, InvalidParameterError, NonFiniteError, ShapeError
from ..solvers import QRSolver, SolveResult, make_solver, from_cumulative
from ..validation import all_finite, check_sample_time, finite_vector
from ..limits import Limits
from .constraints import (STATE_TOL, ConstraintReport, DriveKinematics, constrain, hard_violation, report, split,
                          stage_constraints, terminal_rows)
from .criterion import Criterion
from .fallback import APPLIED_LIMIT_RTOL, LIMIT_MARGIN, check_applied, limit_gap, limit_violation, project_on_limits
from .nmpc import IterationReport, NMPCIterations, riccati_steps
from .prediction import Prediction, absolute_prediction, incremental_prediction, simulative_prediction
from .protocol import ControlModel, check_conditioning, condition_function, conditioning_rule
from .redundancy import null_basis, remove_null
from .riccati import RiccatiPath
from .settings import DEFAULT_BOX_SOLVER, DEFAULT_LIMITED_SOLVER, FORMS, ControllerState, GPCSettings, condensed_default

__all__ = ["GPCController", "StepInfo", "FORMS", "DEFAULT_LIMITED_SOLVER", "DEFAULT_BOX_SOLVER", "LIMIT_MARGIN",
           "APPLIED_LIMIT_RTOL"]

# LIMIT_MARGIN and APPLIED_LIMIT_RTOL live in .fallback; re-exported here (tests import them from this module).

#: the iterations' report of a step without them (the paper's single step; frozen: one for every step).
SINGLE_STEP = IterationReport()


@dataclass
class StepInfo:
    """What one control step did.

    Attributes:
        u: (m,) applied drive torques (N·m).
        result: the solver's :class:`SolveResult` (status ``fallback`` if the solve failed).
        model_time, predict_time, solve_time: wall times in s of the three phases (solve_time
            includes the nonlinear form's further iterations).
        fallback: True when the applied u did not come from a successful solve.
        iterations: Gauss–Newton iterations of the nonlinear form (1: the paper's single step;
            ``GPCSettings.iterations``, :mod:`parallel_gpc.gpc.nmpc`).
        residual: relative size of the last Gauss–Newton step (0 at the NMPC optimum; NaN with
            a single iteration).
        budget_hit: True when the time budget stopped the iterations.
        constraints: what the state/output limits did (active kinds, slack used), or None
            without state limits.
        replaced: True when the stage-wise solve failed (or planned beyond a limit) and the
            condensed default of the same settings solved the step instead (``result.solver``
            names it, ``result.message`` says why).
        stop: why the nonlinear form's iterations ended (:attr:`~parallel_gpc.gpc.nmpc.IterationReport.stop`:
            ``"converged"``, ``"iterations"`` — also the paper's single step —, ``"time budget"``,
            ``"line search"``, ``"solve failed"``, ``"jacobian failed"``).
    """

    u: np.ndarray
    result: SolveResult
    model_time: float
    predict_time: float
    solve_time: float
    fallback: bool = False
    iterations: int = 1
    residual: float = float("nan")
    budget_hit: bool = False
    constraints: ConstraintReport | None = None
    replaced: bool = False
    stop: str = "iterations"

    @property
    def step_time(self) -> float:
        return self.model_time + self.predict_time + self.solve_time


class GPCController:
    """State-space GPC of any :class:`~parallel_gpc.gpc.ControlModel` (a robot's reduced model,
    or a plain discrete linear model).

    Args:
        model: the controller's model (may differ from the plant: mismatch studies).
        settings: the frozen, validated :class:`~parallel_gpc.gpc.GPCSettings` (sample time,
            horizons, weights, form, solver, limits, disturbance gain, max_condition).
        u0: (m,) input applied before the first step, u(−1) (N·m); default zero.

    :meth:`build` makes the settings from keywords: ``GPCController.build(model, Ts=0.002,
    horizons=Horizons(20), form="nonlinear", limits=Limits(torque=60.0))``.

    Raises:
        InvalidParameterError: settings that are not a GPCSettings, a model that is not a
            :class:`~parallel_gpc.gpc.ControlModel`, or whose own Ts differs from the settings'.
        ShapeError: weights or per-drive limits that do not fit the model's sizes.
        InfeasibleLimitsError: u0 outside ±(τ + δ) in the incremental forms (no Δu within ±δ
            brings it within ±τ).
    """

    def __init__(self, model: ControlModel, settings: GPCSettings, u0=None):
        if not isinstance(settings, GPCSettings):
            raise InvalidParameterError(f"settings must be a GPCSettings, got {type(settings).__name__}; "
                                        "GPCController.build(model, Ts, horizons, ...) takes keywords")
        self._setup(model, settings, u0)

    @classmethod
    def build(cls, model: ControlModel, *args, u0=None, **kwargs) -> "GPCController":
        """A controller of ``model`` with ``GPCSettings(*args, **kwargs)`` (the fields of
        :class:`~parallel_gpc.gpc.GPCSettings`: Ts, horizons, weights, form, solver, limits,
        disturbance_gain, max_condition) and u(−1) = ``u0``."""
        return cls(model, GPCSettings(*args, **kwargs), u0)

    def _setup(self, model: ControlModel, settings: GPCSettings, u0) -> None:
        needed = ("n_x", "n_y", "n_u", "C", "discrete") + (("simulate_factorized",) if settings.form == "nonlinear" else ())
        for name in needed:
            if not hasattr(model, name):
                raise InvalidParameterError(f"model {type(model).__name__} has no {name!r}: a controller's model "
                                            f"implements parallel_gpc.gpc.ControlModel")
        self.model = model
        # what a model builds at first use (a robot model's compiled update, ReducedModel.prepare) is built here, with
        # the controller, not in its first step (~1.7 ms on planar_4rrr: the first step of a run was the dearest)
        prepare = getattr(model, "prepare", None)  # optional: a user's ControlModel need not have it
        if prepare is not None:
            prepare()
        self.n_y, self.n_u, self.n_x = model.n_y, model.n_u, model.n_x
        check_sample_time(model, settings.Ts, "model", "the controller's", required=False)  # once, here
        self._backend, self._backend_name = None, None
        self._apply(settings)
        self._gain = conditioning_rule(model)
        self._condition = condition_function()  # compiled or not, decided here (checked every step)
        self.reset(u0)

    def _apply(self, settings: GPCSettings) -> None:
        """Check ``settings`` against the model's sizes and make them current."""
        criterion = Criterion(settings.weights, settings.horizons, self.n_y, self.n_u)
        limits = settings.limits.for_drives(self.n_u, self.n_y)
        self._drives = DriveKinematics.needed(self.model, limits)
        self._criterion, self._settings = criterion, settings
        self._limits, self._qp_limits = limits, limits.scaled(1.0 - LIMIT_MARGIN)
        self._limit_gap = limit_gap(limits, self._qp_limits)  # a verified row excess within it keeps the limits
        # the stage-wise steps (the nonlinear iterations': the paper's step stage-wise, not condensed)
        self._riccati = None if settings.step_solver != "riccati" else RiccatiPath(
            criterion, self.model.C, settings.form, limits=self._qp_limits, Ts=settings.Ts)
        if self._backend_name != settings.solver:  # a new back end (the same one kept across limit changes)
            self._backend = None if settings.solver == "riccati" else make_solver(settings.solver)
            self._backend_name = settings.solver
        # the replacement of a failed stage-wise solve: the condensed default of these settings, built on first use
        self._replacement = None
        self._nmpc = None if settings.iterations == 1 else NMPCIterations(
            self.model, criterion, settings.Ts, settings.iterations, settings.tolerance, settings.time_budget, limits,
            self._drives, riccati_steps(settings, criterion, self.model.C), self._qp_limits,
            self._limit_gap, None if self._riccati is None else self._riccati.constrained)

    # ------------------------------------------------------------------ settings (read-only views)
    @property
    def settings(self) -> GPCSettings:
        """The frozen, validated settings."""
        return self._settings

    Ts = property(lambda self: self._settings.Ts, doc="Sample time (s).")
    horizons = property(lambda self: self._settings.horizons, doc="Horizons N, No, Nu.")
    weights = property(lambda self: self._settings.weights, doc="Square-root weights Qy, Qu.")
    form = property(lambda self: self._settings.form, doc="Prediction form.")
    solver = property(lambda self: self._settings.step_solver,
                      doc="What solves the steps (:attr:`~parallel_gpc.gpc.GPCSettings.step_solver`): the back end's "
                          "name, or ``\"riccati\"`` when the nonlinear iterations take the Riccati recursion.")
    disturbance_gain = property(lambda self: self._settings.disturbance_gain, doc="α of the disturbance estimate.")
    max_condition = property(lambda self: self._settings.max_condition, doc="Largest accepted cond(input gain).")

    @property
    def limits(self) -> Limits:
        """The input :class:`~parallel_gpc.limits.Limits`, every value (m,). Assigning new
        limits (a drive derated while running) checks them against the form, the solver and the
        drive count like the settings (a default solver is chosen again for the new limits); the plan
        and estimates are kept."""
        return self._limits

    @limits.setter
    def limits(self, value: Limits) -> None:
        self._apply(self._settings.changed(limits=value))

    # ------------------------------------------------------------------ state
    def reset(self, u_prev=None) -> None:
        """Forget the plan; set u(k−1) (N·m, default zero)."""
        self.u_prev = np.zeros(self.n_u) if u_prev is None else finite_vector("u_prev", u_prev, self.n_u)
        tau, delta = self._limits.torque, self._limits.du
        if self.form != "absolute" and tau is not None and delta is not None and np.any(np.abs(self.u_prev) > tau + delta):
            raise InfeasibleLimitsError(
                f"u(k−1) = {self.u_prev.tolist()} N·m cannot be brought within the torque limit {tau.tolist()} by "
                f"one increment within the du limit {delta.tolist()}; valid: |u(k−1)| ≤ torque + du"
            )
        self.plan = np.tile(self.u_prev, (self.horizons.N, 1))
        self._v_prev = None
        self.disturbance = np.zeros(self.n_x)
        self._x_next = None  # X̂(k+1|k) of the last step, for the disturbance estimate
        self._null = False  # null(B_d) of the current step (see _base), not yet computed

    @property
    def state(self) -> ControllerState:
        """A read-only snapshot of what the controller carries between steps."""
        return ControllerState(self.u_prev, self.plan, self.disturbance, self._x_next, self._v_prev)

    def restore(self, state: ControllerState) -> None:
        """Put the controller back to ``state`` (a snapshot of a controller with the same sizes).

        Raises:
            InvalidParameterError: not a ControllerState. ShapeError: sizes that do not match.
        """
        if not isinstance(state, ControllerState):
            raise InvalidParameterError(f"restore() takes a ControllerState, got {type(state).__name__}")
        shapes = {"u_prev": (self.n_u,), "plan": (self.horizons.N, self.n_u), "disturbance": (self.n_x,),
                  "x_next": (self.n_x,)}
        for name, shape in shapes.items():
            value = getattr(state, name)
            if value is not None and value.shape != shape:
                raise ShapeError(f"state.{name} has shape {value.shape}; this controller needs {shape}")
        self.u_prev, self.plan, self.disturbance = state.u_prev.copy(), state.plan.copy(), state.disturbance.copy()
        self._x_next = None if state.x_next is None else state.x_next.copy()
        self._v_prev = None if state.warm_start is None else state.warm_start.copy()

    # ------------------------------------------------------------------ model + prediction
    def discrete_model(self, X: np.ndarray):
        """(A_d, B_d, c_d) of the model at X, discrete at Ts (a robot: the factorization (3), ZOH (4))."""
        return self.model.discrete(X, self.Ts)

    def predict(self, X: np.ndarray) -> Prediction:
        """Build ŷ = f + G v for the current state with this controller's form.

        Also keeps the one-step model (A_d, B_d, c_d) at X for the disturbance estimate.

        No drive fighting (a redundantly actuated robot): the incremental forms add the
        increments to u(k−1) (delayed: u(k)) without its null(B_d) component, which moves
        nothing in the model; Qu, which penalizes Δu, then keeps the inputs out of null(B_d) at
        any Qu (not with a Δu limit: removing it would change u(k) − u(k−1) by more than the
        increment), and u(k) is applied without its null(B_d(X)) component unless the torque
        limit needs it (see :meth:`step`).
        """
        H, C = self.horizons, self.model.C
        if self.form == "nonlinear":
            return simulative_prediction(*self.presimulate(X), H)
        Ad, Bd, cd, base = self.linear_stages(X)
        if self.form == "absolute":
            return absolute_prediction(Ad, Bd, cd, C, X, H)
        return incremental_prediction(Ad, Bd, cd, C, X, base, H, delayed=self.form == "incremental-delayed")

    def linear_stages(self, X: np.ndarray):
        """(A_d, B_d, c_d + d, base) at X for the absolute and incremental forms; base is the input
        in the augmented state (incremental: u(k−1) without its null(B_d) part; delayed: u(k);
        absolute: None). Keeps the one-step model for the disturbance estimate."""
        Ad, Bd, cd = self.discrete_model(X)
        cd = cd + self.disturbance
        self._one_step = (Ad, Bd, cd)
        self._null = False  # null(B_d) of this step, computed on first use
        if self.form == "absolute":
            return Ad, Bd, cd, None
        if self.form == "incremental-delayed":  # u(k), decided at k−1, is the state's last block
            self._u_now = self._applicable(self._base(self.plan[1]), self.plan[1].copy())
            return Ad, Bd, cd, self._u_now
        return Ad, Bd, cd, self._base(self.u_prev)

    def _base(self, u: np.ndarray) -> np.ndarray:
        """The input the increments add to: u without its null(B_d) component (no drive fighting
        at any Qu: the removed part moves nothing in the model), or u itself with a Δu limit
        (removing it would change u(k) − u(k−1) by more than Δu). B_d is this step's one-step
        model (:meth:`predict`); its null basis is computed once per step."""
        if self._limits.du is not None:
            return u
        if self._null is False:
            self._null = null_basis(np.asarray(self._one_step[1], dtype=float))
        return remove_null(u, self._null)

    def _applicable(self, projected: np.ndarray, decided: np.ndarray) -> np.ndarray:
        """The input without its null(B_d) part if it respects the torque limit, else as decided."""
        tau = self._qp_limits.torque
        if tau is None or (np.abs(projected) <= tau).all():
            return projected
        return decided

    def _update_disturbance(self, X: np.ndarray) -> None:
        """d ← (1 − α) d + α (X(k) − X̂(k|k−1)): the model's one-step prediction error."""
        alpha = float(self.disturbance_gain)
        if alpha > 0.0 and self._x_next is not None:
            self.disturbance = self.disturbance + alpha * (X - self._x_next)

    def presimulate(self, X: np.ndarray, simulate=None):
        """(A_seq, B_seq, C, y_sim, u_sim) of the nonlinear form's pre-simulation (10).

        ``simulate``: what runs it, with the signature and results of the model's
        ``simulate_factorized`` (the default); the Riccati path's compiled step passes one that
        plans along the trajectory in the same call (limited: one that only simulates,
        :meth:`~parallel_gpc.gpc.riccati.RiccatiPath.stages`) and gives null(B_d(X)) as a fifth
        result (:func:`~parallel_gpc.gpc.redundancy.null_basis`; False: not computed).
        """
        C = self.model.C
        u_sim = np.concatenate((self.plan[1:], self.plan[-1:]))  # previous plan, shifted (vstack: 2× the time)
        # X_sim(i+1) = A_d(X_sim(i)) X_sim(i) + B_d(X_sim(i)) u_sim(i) + c_d(X_sim(i)) + d
        if simulate is None:
            A_seq, B_seq, c_seq, X_sim = self.model.simulate_factorized(X, u_sim, self.Ts, self.disturbance)
            null = False
        else:
            A_seq, B_seq, c_seq, X_sim, null = simulate(X, u_sim, self.Ts, self.disturbance)
        self._one_step = (A_seq[0], B_seq[0], c_seq[0] + self.disturbance, u_sim[0])
        y_sim = X_sim[1:] @ C.T
        self._presimulated = (A_seq, B_seq, y_sim)  # the NMPC iterations' first linearization
        self._u_sim = u_sim  # (N, m): the input rows' origin of this step's limited solves
        self._null = null  # null(B_d) of this step (False: computed on first use)
        return A_seq, B_seq, C, y_sim, u_sim

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
        if not all_finite(w):
            bad = w[np.argwhere(~np.isfinite(w))[0][0]]
            raise NonFiniteError(f"reference window contains the pose {bad.tolist()}; poses must be finite")
        return w

    def step(self, X, w) -> StepInfo:
        """One control step.

        Args:
            X: (n_x,) measured state (a robot: [y, ẏ] in m, rad, m/s, rad/s).
            w: (N, n_y) reference outputs at k+1..k+N (a robot: poses in m, rad).

        Returns:
            StepInfo with the applied u(k) (N·m).
        """
        X = finite_vector("measured state X", X, self.n_x)
        w = self._reference_rows(w)
        t0 = time.perf_counter()
        constraint_report, rows, problem = None, None, None
        self._update_disturbance(X)
        stages = None if self._riccati is None else self._riccati.stages(self, X, w)  # no condensing
        # the input rows' bounds of the limited stage-wise solves of this step (the paper's and the iterations')
        bounds = None if stages is None or self._nmpc is None else self._nmpc.step_bounds(self._u_sim, self.u_prev)
        pred = self.predict(X) if stages is None else None
        gain = None if self._gain is None else self._gain(self._one_step[1])
        if gain is not None:  # SingularPoseError at a near-singular pose
            check_conditioning(self.model, self._gain, X, self._condition(gain), self.max_condition, self.Ts)
        t1 = time.perf_counter()
        u_now = self._u_now if self.form == "incremental-delayed" else None
        result = None if stages is None else self._riccati.solve(*stages, warm=self._v_prev is not None, bounds=bounds)
        if result is not None and result.ok:  # checked here: one beyond the limits is replaced like a failed one
            pred = self._riccati.input_map(self, stages)
            if not self._riccati.excess <= self._limit_gap:  # not already verified by the solver (active set's KKT)
                result = self._within_limits(pred, result)
        staged = result is not None and result.ok
        if staged:
            t2, constraint_report = t1, self._riccati.report
        else:  # the dense path (and a failed stage-wise solve's visible replacement, with its reason)
            pred = self.predict(X) if stages is not None else pred  # (a stage-wise pred is the input map only)
            problem = self._criterion.problem(pred, w, self._qp_limits, self.u_prev)
            warm = self._warm_start(pred, problem.n)
            rows = self._stage_rows(pred, X, warm)
            full = constrain(problem, rows, self._limits, terminal_rows(pred, w, self._settings.terminal))
            t2 = time.perf_counter()
            result = self._dense_solve(full, pred, result, warm)
            if rows is not None and result.ok:
                constraint_report = report(full, rows, result.v)
                excess = hard_violation(full, rows, result.v)
                if excess > STATE_TOL:  # a hard row broken beyond the tolerance: never applied
                    result = replace(result, status="limits violated",
                                     message=f"{result.status}, but a hard state limit is exceeded by {excess:.3g}")
            result, _ = split(full, result)
        iterations = SINGLE_STEP
        if self._nmpc is not None:  # iterated to the NMPC optimum (pred: every linearization's input map)
            result, iterations = self._nmpc.run(
                X, w, pred, result, lambda p: self._criterion.problem(p, w, self._qp_limits, self.u_prev),
                self._backend.solve, self.disturbance, t0, rows, self.u_prev, self._presimulated, bounds)
            if iterations.constraints is not None:  # the state limits along the applied plan's trajectory
                constraint_report = iterations.constraints
        if not staged or self._nmpc is not None:  # a dense or iterated solution; a stage-wise one is checked above
            result = self._within_limits(pred, result)
        fallback = not result.ok
        if fallback:
            if problem is None:  # a stage-wise step: its condensed problem only now
                pred = self.predict(X)
                problem = self._criterion.problem(pred, w, self._qp_limits, self.u_prev)
            result = project_on_limits(problem, pred, result, self._limits.torque, self.n_u)
        t3 = time.perf_counter()
        planned = None if self._riccati is None else self._riccati.planned_inputs(result)
        if planned is not None:  # the fused nonlinear step's, computed in its call
            u_seq = planned
        elif pred.kind == "absolute":  # u = v (u_base = 0, u_map = I)
            u_seq = result.v.reshape(-1, self.n_u).copy()
        else:
            u_seq = pred.inputs(result.v).reshape(-1, self.n_u)
        if u_now is not None:  # delayed: u(k) was decided at k−1; the plan starts at k+1
            u_seq = np.vstack([u_now, u_seq])[:self.horizons.N]
        if self.form in ("incremental", "nonlinear"):  # a null(B_d(X)) part of Δu(k) only serves
            # later, re-planned steps (B_d varying along the horizon, a limit ahead): u(k) is applied
            # without it when that respects the torque limit — the same X̂(k+1)
            u_seq[0] = self._applicable(self._base(u_seq[0]), u_seq[0])
        u = u_seq[0].copy()
        if fallback or u_now is not None:  # a solved first move was verified above (within_limits or the solver)
            check_applied(u, self._limits.torque)  # the projected fallback; u(k) decided at k−1 (or restored)
        N = self.horizons.N
        self.plan = u_seq if len(u_seq) == N else np.vstack([u_seq, np.repeat(u_seq[-1:], N - len(u_seq), axis=0)])
        self._v_prev = result.v
        self.u_prev = u
        Ad, Bd, cd = self._one_step[:3]
        self._x_next = Ad @ X + Bd @ u + cd
        return StepInfo(u, result, t1 - t0, t2 - t1, t3 - t2, fallback, iterations.iterations, iterations.residual,
                        iterations.budget_hit, constraint_report, replaced=stages is not None and not staged,
                        stop=iterations.stop)

    def _within_limits(self, pred: Prediction, result: SolveResult) -> SolveResult:
        """``result``, or marked ``limits violated`` (not ok) when it is "optimal" but its first move
        breaks a torque or Δu limit (a loose tolerance): a failure, never applied."""
        violation = limit_violation(pred, result.v, self.form, self.u_prev, self._limits) if result.ok else ""
        return replace(result, status="limits violated", message=f"{result.status}, but {violation}") if violation \
            else result

    def _stage_rows(self, pred: Prediction, X: np.ndarray, warm: np.ndarray | None):
        """The state/output limits' rows for this step (None without them), the drive limits
        linearized along the poses of the previous plan (ŷ at the warm start)."""
        if not self._limits.has_state_limits:
            return None
        y_lin = pred.f if warm is None else pred.outputs(warm)
        return stage_constraints(pred, self._limits, self.Ts, self.model.C @ X, y_lin, self._drives)

    def _dense_solve(self, problem, pred: Prediction, failed: SolveResult | None,
                     warm: np.ndarray | None = None) -> SolveResult:
        """The back end's solve of the condensed problem; after a failed stage-wise solve (``failed``),
        the condensed default's of the same settings (:func:`~parallel_gpc.gpc.settings.condensed_default`:
        QR without limits), with the stage-wise failure in the message. A back end's exception
        becomes a failed result.
        ``warm``: the warm start in the decision variables proper (slack variables start at 0)."""
        if failed is None:
            backend = self._backend
        else:  # a failed stage-wise solve: the condensed default of these limits (QR without any)
            if self._replacement is None:
                self._replacement = make_solver(condensed_default(self.form, self._limits, self._settings.terminal))
            backend = self._replacement
        if warm is not None and problem.n_slack:
            warm = np.concatenate([warm, np.zeros(problem.n_slack)])
        try:
            result = backend.solve(problem, warm)
        except Exception as exc:  # a back end's own exception: report it and fall back, never leak it
            return SolveResult(np.full(problem.n, np.nan), np.inf, "failed", backend.name,
                               message=f"{type(exc).__name__}: {exc}")
        return result if failed is None else replace(
            result, message=f"riccati failed ({failed.message}); solved by "
                            f"{'QR' if isinstance(backend, QRSolver) else backend.name}")

    def _warm_start(self, pred: Prediction, n: int) -> np.ndarray | None:
        """The previous plan shifted by one sample, as v: absolute, v shifted; incremental and
        nonlinear, v = M⁻¹(plan shifted − u_base) (M cumulative: block differences), limits active
        exactly where the plan's were (shifted Δu on a base without its null(B_d) part are off
        them); delayed, the previous Δu shifted."""
        if self._v_prev is None or self._v_prev.shape != (n,):
            return None
        m = self.n_u
        if self.form in ("incremental", "nonlinear"):
            target = np.vstack([self.plan[1:], self.plan[-1:]])[:n // m].reshape(-1)
            return from_cumulative(target - pred.u_base[:n], m)
        tail = self._v_prev[-m:] if self.form == "absolute" else np.zeros(m)
        return np.concatenate([self._v_prev[m:], tail])
