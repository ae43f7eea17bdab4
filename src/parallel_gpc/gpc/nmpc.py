"""The nonlinear form iterated to the nonlinear MPC optimum (Gauss–Newton with a line search).

The paper's nonlinear form, eq. (10)–(12), linearizes once along the pre-simulated trajectory
and solves one least-squares problem: one Gauss–Newton step of the discrete problem below.
:class:`NMPCIterations` continues from that step to the problem's optimum.

**The discrete problem** (what "converged" means). With u_sim⁰ the previous plan shifted by one
sample (the pre-simulation's inputs), v = [Δu(0) … Δu(Nu−1)] and
u(i) = u_sim⁰(i) + Σ_{l ≤ min(i, Nu−1)} Δu(l), i = 0..N−1 (the nonlinear form's inputs)::

    minimize   J(v) = Σ_{j=No+1..N} ‖Qy (C X(j) − w(j))‖² + Σ_{i<Nu} ‖Qu Δu(i)‖²   (j = N: diag(Qf) Qy)
    subject to X(0) = X(k),  X(i+1) = Φ(X(i), u(i)) + d,
               |u(i)| ≤ τ (i < N),  |u(i) − u(i−1)| ≤ δ (i < Nu, u(−1) = u(k−1)),
               the state limits (:mod:`~parallel_gpc.gpc.constraints`) on the outputs C X(j),
               j = No+1..N, of this trajectory (soft ones: + ρ s + ε s² in J, s their least slack),

Φ(X, u) = A_d(X) X + B_d(X) u + c_d(X) the state-dependent ZOH model, the very map of the
pre-simulation (:meth:`~parallel_gpc.model.ReducedModel.simulate_factorized`), d the
disturbance estimate, τ and δ the controller's limits (scaled by its margin, like every step's).
Qu weighs the increments over the shifted previous plan as the nonlinear form defines them, so
J is one fixed function of v for the whole step, and ``iterations=1`` is the paper's step.

**The iteration.** Step 1 is the paper's (Jacobian frozen: ∂Φ/∂X ≈ A_d(X_sim)); an exact first
step was measured to save no iteration (the next Gauss–Newton step is still 1e-7…1e-5 relative,
as after the paper's) and to cost one Jacobian more, the dearest part of an iteration. Every later step
linearizes Φ along the trajectory of the current plan with its true Jacobians — ∂Φ/∂u = B_d(X)
(Φ is affine in u) and ∂Φ/∂X, the Fréchet derivative of the ZOH exponential along ∂Z/∂X of the
factor rows (:meth:`~parallel_gpc.model.ReducedModel.stage_jacobians`, exact in ẏ, forward differences
of Z in y, n_y model updates per stage in one compiled call, none at stage 0 whose state is fixed; a
trial that will be linearized if accepted is rolled out with its Jacobians in one call,
:meth:`~parallel_gpc.model.ReducedModel.simulate_linearized`, their stages on the second core while the
rollout goes on; the frozen A_d misses
∂A_d/∂X·X + ∂B_d/∂X·u + ∂c_d/∂X, and Gauss–Newton with it stops at a fixed point that is not the
optimum) — rebuilds the state limits' rows along that trajectory (exact at the current plan: the
drive limits linearized at its poses) and solves the same least-squares/QP problem for the total
v, every limit of the problem included. Where the Riccati recursion gives that problem's minimizer
(:func:`riccati_steps`: the default back end, no state limit, Qu nonsingular, no terminal weight)
every step, the paper's included (the controller's stage-wise path, nothing condensed), is solved
stage-wise on the linearization's stage models (:meth:`NMPCIterations.riccati_step`, no
least-squares factorization; the linearizations' targets and model decrease take G v by one pass
of the deviation model, :func:`~parallel_gpc.gpc.prediction.deviation_response`, not G): by the
recursion without input limits, with torque/Δu limits by the stage-wise active set
(:class:`~parallel_gpc.gpc.stagewise.StagewiseSolver`, the controller's own, which solved the paper's step:
one compiled call per step; the input rows u = u_sim⁰ + u_map v are the same in every step of a control
step: their bounds are computed once, the paper step's included, and every limited step starts from the
last one's active set as it is, the first from the paper step's, which started from the last control
step's converged set shifted — the verifying step, whose set is the last one's, takes one sweep); a
limited step that the active set does not verify within the limits' margin goes to the condensed
problem (G condensed) and the back end, the reference. A
backtracking line search on the true J (each trial one pre-simulation; soft state limits enter J
by their slack cost) accepts v + α(v⁺ − v) with sufficient decrease and a hard state-limit
violation on the trial's nonlinear trajectory no larger than before (or 1e-7, ``STATE_TOL``), or
else a sufficient decrease of that violation; a convex combination of two plans within the input
limits is within them. Stopping: the step ‖v⁺ − v‖∞ ≤ tolerance·(1 + ‖v‖∞) (at a KKT point
of the problem the Gauss–Newton step is zero: the subproblem's KKT conditions at step 0 are the
problem's; the accepted plan v is kept, and v⁺, within the tolerance of it, is not rolled out —
a line search on a step that small only measures rounding), the iteration limit, a failed line
search or solve (the last accepted plan is kept; a failed line search whose model decrease is
below rounding, 1e-12·J, counts as converged: such a line search tries the full step alone, as a shorter
one's J differs from J(v) by rounding only), or the time budget (the next iteration would end
past it).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from functools import partial

import numpy as np

from ..errors import AssemblyError, NonFiniteError, SingularPoseError
from ..limits import SOFT_QUADRATIC, Limits
from ..solvers import SolveResult
from .constraints import (STATE_TOL, ConstraintReport, ConstraintRows, DriveKinematics, constrain, hard_excess,
                          hard_violation, report_at, split, stage_constraints)
from .criterion import Criterion
from .prediction import Prediction, deviation_gain, deviation_response
from .riccati import RiccatiSolver
from .settings import GPCSettings, iterations_by_riccati
from .stagewise import StagewiseSolver, step_bounds

__all__ = ["NMPCIterations", "IterationReport", "riccati_steps", "ARMIJO", "BACKTRACKS"]

#: sufficient-decrease factor of the line search (fraction of the Gauss–Newton model's decrease).
ARMIJO = 1e-4
#: largest number of step halvings before the line search gives up.
BACKTRACKS = 12
#: errors of the model away from its domain (a trial plan beyond the workspace): a shorter step.
MODEL_ERRORS = (AssemblyError, SingularPoseError, NonFiniteError)
#: the decision variables of a trajectory's own state-limit rows (:meth:`NMPCIterations._true_rows`):
#: none, its outputs are fixed.
NO_DECISION = np.zeros(0)
#: a Gauss–Newton model decrease below this fraction of J is rounding: the line search cannot see it.
ROUNDING = 1e-12


def riccati_steps(settings: GPCSettings, criterion: Criterion, C: np.ndarray) -> RiccatiSolver | None:
    """The Riccati recursion that solves every Gauss–Newton step of the iterations, the paper's
    included (:meth:`NMPCIterations.riccati_step`), or None: where
    :func:`~parallel_gpc.gpc.settings.iterations_by_riccati` says it gives the condensed subproblem's
    minimizer (then ``settings.step_solver`` is ``"riccati"``). With torque/Δu limits the steps are
    the stage-wise active set's on the same stage models (:class:`NMPCIterations`).

    Args:
        settings: the controller's settings (iterations > 1). criterion: its criterion.
        C: (p, n_x) output matrix of the model.
    """
    if not iterations_by_riccati(settings):
        return None
    Wy, Wu = criterion.weights.blocks(criterion.n_outputs, criterion.n_inputs)
    return RiccatiSolver(Wy, Wu, C, criterion.horizons, "nonlinear")


@dataclass(frozen=True)
class IterationReport:
    """What the iterations of one step did.

    Attributes:
        iterations: Gauss–Newton iterations used (1 = the paper's single step).
        residual: ‖v⁺ − v‖∞ / (1 + ‖v‖∞) of the last Gauss–Newton step (0 at a KKT point);
            NaN when only the paper's step ran without a second linearization.
        budget_hit: True when the time budget stopped the iterations.
        converged: True when the residual fell to the tolerance.
        cost: J(v) of the applied plan on the nonlinear model (the criterion's units), plus the
            cost of its soft state limits' least slack (ρ s + ε s²; 0 when kept).
        stop: why the iterations ended (``"converged"``, ``"iterations"``, ``"time budget"``,
            ``"line search"``, ``"solve failed"``, ``"jacobian failed"``).
        constraints: the state limits at the applied plan's nonlinear trajectory (active kinds,
            slack of the soft ones), or None without state limits.
    """

    iterations: int = 1
    residual: float = float("nan")
    budget_hit: bool = False
    converged: bool = False
    cost: float = float("nan")
    stop: str = "iterations"
    constraints: ConstraintReport | None = None


class NMPCIterations:
    """Gauss–Newton iterations of the nonlinear form to the optimum of its discrete problem.

    Args:
        model: the controller's model (``simulate_factorized``, ``stage_jacobians``, ``C``).
        criterion: the controller's :class:`~parallel_gpc.gpc.criterion.Criterion`.
        Ts: sample time (s). iterations: the largest number of iterations (≥ 1).
        tolerance: the step tolerance (relative). time_budget: s per control step, or None.
        limits: the controller's limits sized to the model (their state kinds are rebuilt along
            every iteration's trajectory), or None. drives: the robot's drive kinematics (needed
            by drive_position and drive_rate), or None.
        riccati: the form's Riccati recursion for the steps (:func:`riccati_steps`), or None:
            every step's condensed problem goes to the controller's back end.
        qp_limits: the limits the steps' problems hold (``limits`` tightened by the controller's
            margin), or None: with ``riccati`` and a torque or Δu limit, the steps are solved by the
            stage-wise active set (:attr:`stagewise`).
        gap: the controller's :func:`~parallel_gpc.gpc.fallback.limit_gap` of ``limits`` and ``qp_limits``
            (N·m): a limited step whose rows the active set verified within it keeps the true limits
            (default 0: none beyond its bounds; the others go to the condensed problem).
        stagewise: the controller's stage-wise solver of the paper's step
            (:attr:`~parallel_gpc.gpc.riccati.RiccatiPath.constrained`: the same rows), which then solves the
            limited steps too — one solver per controller: its first step's setup is made once, the paper's
            step starts from the last control step's converged set, and the first limited Gauss–Newton
            step from the paper's set — or None: one is made here (with ``riccati`` and a torque or Δu limit).

    Attributes:
        stagewise: the :class:`~parallel_gpc.gpc.stagewise.StagewiseSolver` of the limited steps, or None.
    """

    def __init__(self, model, criterion: Criterion, Ts: float, iterations: int, tolerance: float,
                 time_budget: float | None, limits: Limits | None = None, drives: DriveKinematics | None = None,
                 riccati: RiccatiSolver | None = None, qp_limits: Limits | None = None, gap: float = 0.0,
                 stagewise: StagewiseSolver | None = None):
        self.model, self.criterion, self.Ts = model, criterion, Ts
        self.riccati = riccati
        self.stagewise, self._gap = None, np.inf
        self._shared = False  # the paper's step is solved by self.stagewise (its set starts the first limited step)
        if riccati is not None and qp_limits is not None and qp_limits.needs_qp:
            self._shared = stagewise is not None
            self.stagewise = stagewise if self._shared else StagewiseSolver(
                riccati.Wy, riccati.Wu, model.C, criterion.horizons, "nonlinear", qp_limits, Ts)
            self._gap = gap  # a verified row excess within it keeps the true limits
        self.iterations, self.tolerance, self.time_budget = iterations, tolerance, time_budget
        self.limits = limits if limits is not None and limits.has_state_limits else None
        self.drives = drives
        # what every rollout, cost and step of a control step would otherwise look up again (fixed for the controller)
        self._m, self._p, self._No = model.n_u, criterion.n_outputs, criterion.horizons.No
        self._Ct = model.C.T  # (n_x, p): outputs X C^T of a trajectory's states
        self._wy, self._qu = criterion.wy, criterion.qu_diag  # the diagonal weights as vectors, or None

    def step_bounds(self, u_sim: np.ndarray, u_prev: np.ndarray | None) -> np.ndarray | None:
        """The input rows' bounds of a control step for :attr:`stagewise`
        (:func:`~parallel_gpc.gpc.stagewise.step_bounds` of its pre-simulated inputs u_sim (N, m) and u(k−1) (m,),
        N·m): the same in each of its limited steps, the paper's included when the same solver solves it (the
        controller computes them once and passes them to both, :meth:`run`); None without :attr:`stagewise`."""
        return None if self.stagewise is None else step_bounds(self.stagewise.limits, self.criterion.horizons,
                                                                u_sim, u_prev)

    # -------------------------------------------------------------- the true problem
    def _rollout(self, X, w, u0, u_map, v, d, linearize: bool = False):
        """(trajectory, inputs (N, m), outputs (n_rows·p,), J(v), JX) on the nonlinear model;
        trajectory = simulate_factorized's output; JX: with ``linearize``, the stage Jacobians ∂Φ/∂X at
        stages 1..N−1 of this trajectory ((N − 1, n_x, n_x), the model's ``simulate_linearized``: computed
        on a second core while the rollout goes on, the compiled core's), else None. A trial the line search
        rejects drops its JX: on one core a stage_jacobians call wasted (≈ twice a rollout), on two the
        second core's time and the stages still left when the rollout ends (the calling thread joins them);
        hence ``run`` asks for JX only where the trial is likely kept (not on a flat line search, whose
        full step is mostly rejected). Where the fused call fails the trial is rolled out alone (JX None),
        so that a failing Jacobian stops the iterations as in ``run``."""
        u = (u0 + u_map.dot(v)).reshape(-1, self._m)  # (ndarray.dot: the product of @ without matmul's dispatch)
        JX = None
        fused = getattr(self.model, "simulate_linearized", None) if linearize else None
        try:
            traj = None if fused is None else fused(X, u, self.Ts, d, start=1)
        except MODEL_ERRORS:  # the rollout's or a Jacobian's: tell them apart by the rollout alone
            traj = None
        if traj is None:
            traj = self.model.simulate_factorized(X, u, self.Ts, d)
        else:
            traj, JX = traj[:4], traj[4]
        y = traj[3][1:].dot(self._Ct)[self._No:].reshape(-1)
        return traj, u, y, self._cost(y, w, v), JX

    def _cost(self, y_rows: np.ndarray, w: np.ndarray, v: np.ndarray) -> float:
        """J = Σ‖Qy (y − w)‖² + ‖kron(I, Qu) v‖² over the penalized rows (stacked, (n_rows·p,)), the
        last row weighed diag(Qf) Qy like the condensed problem's
        (:meth:`~parallel_gpc.gpc.criterion.Criterion.problem`); diagonal weights as vectors."""
        r = y_rows - w
        if self._wy is not None:
            e = self._wy * r
        else:
            c, p = self.criterion, self._p
            e = (r.reshape(-1, p) @ c.Wy.T).reshape(-1)
            if c.Wf is not None:
                e[-p:] = c.Wf @ r[-p:]
        q = v * self._qu if self._qu is not None else self.criterion.Qu_block @ v
        return float(e.dot(e)) + float(q.dot(q))  # (the dots of e @ e, q @ q without matmul's dispatch)

    # -------------------------------------------------------------- state limits
    def _rows(self, lin: Prediction, y_lin: np.ndarray, y_now: np.ndarray) -> ConstraintRows | None:
        """The state limits' rows G v ≤ h of the prediction ``lin``, the drive limits linearized at
        the outputs y_lin (n_rows·p,) (m, rad); None without state limits."""
        if self.limits is None:
            return None
        return stage_constraints(lin, self.limits, self.Ts, y_now, y_lin, self.drives)

    def _true_rows(self, y_rows: np.ndarray, y_now: np.ndarray) -> ConstraintRows | None:
        """The state limits at the outputs y_rows (n_rows·p,) of a nonlinear trajectory: rows without
        a column (:data:`NO_DECISION`), h = bound − value (the drive positions at the poses
        themselves)."""
        if self.limits is None:
            return None
        H = self.criterion.horizons
        at = Prediction(y_rows, np.zeros((len(y_rows), 0)), np.zeros(0), np.zeros((0, 0)), H, "simulative")
        return self._rows(at, y_rows, y_now)

    def _slack(self, rows: ConstraintRows, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(violation of each row (k,), the least slack of each soft pair (n_s,)) at v, in the
        limits' units (m, rad, m/s, …)."""
        viol = np.maximum(rows.G @ v - rows.h, 0.0)
        s = np.zeros(rows.n_slack)
        soft = rows.slack_of >= 0
        np.maximum.at(s, rows.slack_of[soft], viol[soft])
        return viol, s

    def _penalty(self, rows: ConstraintRows | None, v: np.ndarray) -> float:
        """The soft state limits' cost at v: ρ s + ε s² per soft pair, s its least slack (the QP's
        slack cost, :func:`~parallel_gpc.gpc.constraints.constrain`)."""
        if rows is None or not rows.n_slack:
            return 0.0
        _, s = self._slack(rows, v)
        rho = self.limits.penalty
        return float(rho * s.sum() + rho * SOFT_QUADRATIC * (s @ s))

    @staticmethod
    def _hard(rows: ConstraintRows | None) -> float:
        """The largest violation of a hard row of a trajectory's own state limits (m, rad, m/s, …;
        0 when kept)."""
        return 0.0 if rows is None else hard_excess(rows, rows.G @ NO_DECISION)

    def _model_merit(self, y_lin: np.ndarray, rows: ConstraintRows | None, w: np.ndarray, v: np.ndarray) -> float:
        """J + penalty of a linearization at v: its outputs y_lin (n_rows·p,) there (m, rad), its rows."""
        return self._cost(y_lin, w, v) + self._penalty(rows, v)

    def _report(self, rows: ConstraintRows | None) -> ConstraintReport | None:
        """The state limits' report at a trajectory (its rows from :meth:`_true_rows`)."""
        if rows is None or not len(rows.h):
            return None
        _, s = self._slack(rows, NO_DECISION)
        return report_at(rows, rows.G @ NO_DECISION, s)

    # -------------------------------------------------------------- the iterations
    def riccati_step(self, X: np.ndarray, JX: np.ndarray, B_seq: np.ndarray, f: np.ndarray, w: np.ndarray,
                     u_sim: np.ndarray, u_prev: np.ndarray | None, start: np.ndarray | None = None,
                     bounds: np.ndarray | None = None, y_now: np.ndarray | None = None) -> SolveResult | None:
        """The Gauss–Newton subproblem of the linearization ŷ = f + G v at X (n_x,) (stage models JX (N, n_x, n_x),
        B_seq (N, n_x, m); the paper's step: the pre-simulation's A_d, B_d; f: (n_rows·p,) its free response,
        m and rad) solved stage-wise when :attr:`riccati` is set: by the Riccati recursion, or with
        torque/Δu limits by the stage-wise active set (:attr:`stagewise`) on the input rows of
        u = u_sim + u_map v (u_sim: (N·m,) or (N, m) the step's pre-simulated inputs, u_prev: (m,)
        u(k−1), N·m); None when it is not set, fails, or a limited solution is not verified within
        the limits' margin (the condensed problem then decides, every limit included).
        w: (n_rows, p) or (n_rows·p,) reference rows (m, rad). start: the active set of this control
        step's last limited step (:attr:`~parallel_gpc.gpc.stagewise.StagewiseSolver.active_set`: the
        paper's for the first when the solver is shared), or None: the solver's last one, shifted by one
        stage. bounds: the input rows' bounds of this control step
        (:func:`~parallel_gpc.gpc.stagewise.step_bounds`: the same in each of its steps), or None:
        computed from u_sim and u_prev. y_now: C X (p,) (m, rad) when the caller has it, else None.
        Without state limits and with Qu nonsingular (:func:`riccati_steps`) the subproblem's minimizer is
        unique: the recursion's, the active set's and the condensed back end's agree to rounding (the back
        ends' tolerances)."""
        if self.riccati is None:
            return None
        targets = (np.asarray(w).reshape(-1) - f).reshape(-1, self._p)  # w − (ŷ(v) − G v): from 0
        if self.stagewise is None:
            new = self.riccati.solve(JX, B_seq, None, X, None, targets)  # (the deviation starts at 0, not X)
            return new if new.ok else None
        y_now = self.model.C @ X if y_now is None else y_now
        new, _ = self.stagewise.solve((JX, B_seq, None, X, None), targets, y_now,
                                      u_sim=np.asarray(u_sim).reshape(-1, self._m), u_prev=u_prev,
                                      warm=start is None, start=start, bounds=bounds)
        return new if new.ok and self.stagewise.excess <= self._gap else None

    def run(self, X, w, pred: Prediction, result: SolveResult, problem_of, solve, disturbance, start: float,
            rows: ConstraintRows | None = None, u_prev: np.ndarray | None = None, presimulated: tuple | None = None,
            bounds: np.ndarray | None = None):
        """Continue from the paper's step (``pred``, its solve ``result``) to the optimum.

        Args:
            X: (n_x,) measured state. w: (n_rows, p) reference rows (m, rad).
            pred: the paper's prediction (frozen Jacobians along the pre-simulation of u_sim⁰), condensed
                (f, G), or only its input map (the stage-wise step: G has no row; ``presimulated`` then
                gives f and G v).
            result: its solve (v = the paper's increments, without slack variables).
            problem_of: Prediction → LeastSquaresProblem with the controller's input limits.
            solve: (problem, warm start) → SolveResult (the controller's back end).
            disturbance: (n_x,) d of the step. start: time.perf_counter() at the step's start.
            rows: the paper's step's state-limit rows (None without state limits).
            u_prev: (m,) u(k−1) (N·m), the Δu rows' origin (needed by the stage-wise limited steps).
            presimulated: (A_seq (N, n_x, n_x), B_seq (N, n_x, m), y_sim (N, p)) of the step's
                pre-simulation (the paper's linearization), needed when ``pred`` is not condensed.
            bounds: the limited steps' input-row bounds of this control step (:meth:`step_bounds` of its
                pre-simulated inputs and ``u_prev``, which the paper's step took too), or None: computed here
                at the first limited step.

        Returns:
            (its result with v the accepted plan, :class:`IterationReport`). Every linearization maps
            v to the inputs as ``pred`` does (u = u_sim⁰ + u_map v): ``pred`` stays the step's input map.
        """
        w = np.asarray(w, dtype=float).reshape(-1)
        if not result.ok:
            return result, IterationReport(stop="solve failed")
        H, C = self.criterion.horizons, self.model.C
        y_now = C @ X
        u0, u_map = pred.u_base, pred.u_map
        v = np.zeros(result.v.shape)
        # the linearization that produced `result`: its outputs at v, x ↦ G x, its rows; whether `result`
        # is a stage-wise solve (its J, the criterion along the stage models, is the model's J at result.v)
        staged = not pred.G.size
        if staged:  # the controller's stage-wise step: G v by the deviation model along the pre-simulation
            A_seq, B_seq, y_sim = presimulated
            y_lin, gain = y_sim[H.No:].reshape(-1), partial(deviation_response, A_seq, B_seq, C, H)
        else:
            y_lin, gain = pred.f, pred.G.__matmul__
        lin_rows = rows
        true_rows = self._true_rows(y_lin, y_now)  # the state limits along the pre-simulation (v = 0)
        merit = self._cost(y_lin, w, v) + self._penalty(true_rows, NO_DECISION)
        excess = self._hard(true_rows)
        report = dict(iterations=0, residual=float("nan"), stop="iterations", budget_hit=False, converged=False)
        # the limited steps' input-row bounds (given or computed at the first); the last one's active set: first the
        # paper step's when it was solved stage-wise by the same solver (else None: the solver's last set, shifted)
        active = self.stagewise.active_set if staged and self._shared else None
        last = time.perf_counter()
        while True:
            report["iterations"] += 1
            v_new = result.v
            delta = v_new - v
            if report["iterations"] > 1:
                report["residual"] = float(np.abs(delta).max(initial=0.0)) / (1.0 + float(np.abs(v).max(initial=0.0)))
                if report["residual"] <= self.tolerance:  # v is converged: v⁺ is not rolled out
                    report.update(stop="converged", converged=True)
                    break
            if lin_rows is None:  # the model's merit at v is the true one (the linearization is exact there)
                model_new = result.cost if staged else self._cost(y_lin + gain(delta), w, v_new)
                decrease = max(merit - model_new, 0.0)
            else:
                decrease = max(self._model_merit(y_lin, lin_rows, w, v)
                               - self._model_merit(y_lin + gain(delta), lin_rows, w, v_new), 0.0)
            # a model decrease below rounding: a rejected full step is not tried shorter (every shorter trial's J
            # differs from J(v) by rounding alone: measured 13 rollouts of the same J to 1e-12 at an active limit)
            flat = decrease <= ROUNDING * merit and excess <= STATE_TOL
            alpha, accepted = 1.0, None
            for _ in range(BACKTRACKS + 1):
                trial = v + alpha * delta
                try:
                    # with its Jacobians unless it is the last allowed iteration's or flat (then mostly rejected)
                    traj, u_traj, y_rows, trial_cost, trial_JX = self._rollout(
                        X, w, u0, u_map, trial, disturbance,
                        linearize=report["iterations"] < self.iterations and not flat)
                    trial_rows = self._true_rows(y_rows, y_now)
                except MODEL_ERRORS:  # the trial plan leaves the model's domain (workspace): shorter step
                    alpha *= 0.5
                    continue
                trial_merit = trial_cost + self._penalty(trial_rows, NO_DECISION)
                trial_excess = self._hard(trial_rows)
                if (trial_excess <= max(excess, STATE_TOL) and trial_merit <= merit - ARMIJO * alpha * decrease) \
                        or (excess > 0.0 and trial_excess <= (1.0 - ARMIJO * alpha) * excess):
                    accepted = (trial, traj, u_traj, y_rows, trial_merit, trial_excess, trial_rows, trial_JX)
                    break
                if flat:
                    break
                alpha *= 0.5
            if accepted is None:  # no decrease measurable above rounding (and feasible): as good as converged
                report.update(stop="converged" if flat else "line search", converged=flat)
                break
            v, traj, u_traj, y_rows, merit, excess, true_rows, JX_tail = accepted
            if report["iterations"] >= self.iterations:
                break
            now = time.perf_counter()
            if self.time_budget is not None and (now - start) + (now - last) > self.time_budget:
                report.update(stop="time budget", budget_hit=True)
                break
            last = now
            A_seq, B_seq, _, X_seq = traj
            try:  # the trial's own when it was rolled out with them (_rollout)
                if JX_tail is None:
                    JX_tail = self.model.stage_jacobians(X_seq, u_traj, self.Ts, start=1)
            except MODEL_ERRORS:  # a difference step leaves the workspace: keep the accepted plan
                report["stop"] = "jacobian failed"
                break
            # X(0) is fixed: ∂Φ/∂X at stage 0 multiplies a zero deviation, never enters G (A_d there stands in)
            JX = np.concatenate((A_seq[:1], JX_tail))
            y_lin, lin = y_rows, None  # ŷ(v + δ) ≈ y_rows + G δ along this plan's trajectory
            result = None
            if self.riccati is not None and self.limits is None:  # stage-wise: G v alone, not G
                gain = partial(deviation_response, JX, B_seq, C, H)
                if self.stagewise is not None and bounds is None:  # u_sim⁰, u(k−1): the same in every step
                    bounds = self.step_bounds(u0.reshape(-1, self._m), u_prev)
                result = self.riccati_step(X, JX, B_seq, y_rows - gain(v), w, u0, u_prev, active, bounds, y_now)
                active = None if self.stagewise is None else self.stagewise.active_set  # the next one's start
            staged = result is not None
            if result is None:  # G itself: the condensed subproblem with every limit, the back end's
                G = deviation_gain(JX, B_seq, C, H)
                gain = G.__matmul__
                lin = Prediction(y_rows - G @ v, G, u0, u_map, H, "simulative")
            try:  # the state limits linearized along this plan's trajectory (exact at v)
                lin_rows = None if lin is None else self._rows(lin, y_rows, y_now)
            except MODEL_ERRORS:
                report["stop"] = "jacobian failed"
                break
            if result is None:  # the condensed subproblem with every limit, by the controller's back end
                problem = constrain(problem_of(lin), lin_rows, self.limits)
                warm = v if not problem.n_slack else np.concatenate([v, np.zeros(problem.n_slack)])
                try:
                    new = solve(problem, warm)
                except Exception as exc:  # a back end's own exception ends the iterations, never leaks
                    new = SolveResult(warm, np.inf, "failed", "", message=f"{type(exc).__name__}: {exc}")
                if not new.ok or hard_violation(problem, lin_rows, new.v) > STATE_TOL:
                    report["stop"] = "solve failed"
                    break
                result, _ = split(problem, new)
        return replace(result, v=v.copy(), cost=merit), IterationReport(cost=merit, constraints=self._report(
            true_rows), **report)
