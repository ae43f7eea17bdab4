"""The nonlinear form iterated to the nonlinear MPC optimum (Gauss–Newton with a line search).

The paper's nonlinear form, eq. (10)–(12), linearizes once along the pre-simulated trajectory
and solves one least-squares problem: one Gauss–Newton step of the discrete problem below.
:class:`NMPCIterations` continues from that step to the problem's optimum.

**The discrete problem** (what "converged" means). With u_sim⁰ the previous plan shifted by one
sample (the pre-simulation's inputs), v = [Δu(0) … Δu(Nu−1)] and
u(i) = u_sim⁰(i) + Σ_{l ≤ min(i, Nu−1)} Δu(l), i = 0..N−1 (the nonlinear form's inputs)::

    minimize   J(v) = Σ_{j=No+1..N} ‖Qy (C X(j) − w(j))‖² + Σ_{i<Nu} ‖Qu Δu(i)‖²
    subject to X(0) = X(k),  X(i+1) = Φ(X(i), u(i)) + d,
               |u(i)| ≤ τ (i < N),  |u(i) − u(i−1)| ≤ δ (i < Nu, u(−1) = u(k−1)),

Φ(X, u) = A_d(X) X + B_d(X) u + c_d(X) the state-dependent ZOH model, the very map of the
pre-simulation (:meth:`~parallel_gpc.model.ReducedModel.simulate_factorized`), d the
disturbance estimate, τ and δ the controller's limits (scaled by its margin, like every step's).
Qu weighs the increments over the shifted previous plan as the nonlinear form defines them, so
J is one fixed function of v for the whole step, and ``iterations=1`` is the paper's step.

**The iteration.** Step 1 is the paper's (Jacobian frozen: ∂Φ/∂X ≈ A_d(X_sim)). Every later step
linearizes Φ along the trajectory of the current plan with its true Jacobians — ∂Φ/∂u = B_d(X)
(Φ is affine in u) and ∂Φ/∂X by central differences of Φ (2·n_x evaluations per stage; the
frozen A_d misses ∂A_d/∂X·X + ∂B_d/∂X·u + ∂c_d/∂X, and Gauss–Newton with it stops at a fixed
point that is not the optimum) — and solves the same least-squares/QP problem for the total v,
every limit of the problem included. A backtracking line search on the true J (each trial one
pre-simulation) accepts v + α(v⁺ − v) with sufficient decrease; a convex combination of two
feasible plans is feasible. Stopping: the step ‖v⁺ − v‖∞ ≤ tolerance·(1 + ‖v‖∞) (at a KKT point
of the problem the Gauss–Newton step is zero: the subproblem's KKT conditions at step 0 are the
problem's), the iteration limit, a failed line search or solve (the last accepted plan is
kept; a failed line search whose model decrease is below rounding, 1e-12·J, counts as
converged), or the time budget (the next iteration would end past it).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ..errors import AssemblyError, NonFiniteError, SingularPoseError
from ..solvers import SolveResult
from .criterion import Criterion
from .prediction import Prediction, simulative_prediction

__all__ = ["NMPCIterations", "IterationReport", "state_jacobians", "ARMIJO", "BACKTRACKS"]

#: sufficient-decrease factor of the line search (fraction of the Gauss–Newton model's decrease).
ARMIJO = 1e-4
#: largest number of step halvings before the line search gives up.
BACKTRACKS = 12
#: errors of the model away from its domain (a trial plan beyond the workspace): a shorter step.
MODEL_ERRORS = (AssemblyError, SingularPoseError, NonFiniteError)
#: a Gauss–Newton model decrease below this fraction of J is rounding: the line search cannot see it.
ROUNDING = 1e-12
#: relative step of the central differences of Φ (per state entry, times max(1, |X_k|)).
FD_STEP = 1e-5


@dataclass(frozen=True)
class IterationReport:
    """What the iterations of one step did.

    Attributes:
        iterations: Gauss–Newton iterations used (1 = the paper's single step).
        residual: ‖v⁺ − v‖∞ / (1 + ‖v‖∞) of the last Gauss–Newton step (0 at a KKT point);
            NaN when only the paper's step ran without a second linearization.
        budget_hit: True when the time budget stopped the iterations.
        converged: True when the residual fell to the tolerance.
        cost: J(v) of the applied plan on the nonlinear model (the criterion's units).
        stop: why the iterations ended (``"converged"``, ``"iterations"``, ``"time budget"``,
            ``"line search"``, ``"solve failed"``, ``"jacobian failed"``).
    """

    iterations: int = 1
    residual: float = float("nan")
    budget_hit: bool = False
    converged: bool = False
    cost: float = float("nan")
    stop: str = "iterations"


def state_jacobians(model, X_seq: np.ndarray, u_seq: np.ndarray, Ts: float, step: float = FD_STEP) -> np.ndarray:
    """∂Φ/∂X at each stage of a trajectory, Φ(X, u) = A_d(X) X + B_d(X) u + c_d(X).

    Central differences of the model's own ZOH map (:meth:`discrete`), step h_k =
    ``step``·max(1, |X_k|): truncation O(h²) ≈ 1e-10, rounding ≈ 1e-11 relative.

    Args:
        model: a model with ``discrete(X, Ts)`` (a :class:`~parallel_gpc.model.ReducedModel`).
        X_seq: (≥ K, n_x) states X(0..K−1); u_seq: (K, n_u) inputs (N·m); Ts: sample time (s).

    Returns:
        (K, n_x, n_x) Jacobians.
    """
    K, n = len(u_seq), model.n_x
    J = np.empty((K, n, n))
    for i in range(K):
        x, u = X_seq[i], u_seq[i]
        for k in range(n):
            h = step * max(1.0, abs(x[k]))
            xp, xm = x.copy(), x.copy()
            xp[k] += h
            xm[k] -= h
            Ap, Bp, cp = model.discrete(xp, Ts)
            Am, Bm, cm = model.discrete(xm, Ts)
            J[i, :, k] = (Ap @ xp + Bp @ u + cp - (Am @ xm + Bm @ u + cm)) / (xp[k] - xm[k])
    return J


class NMPCIterations:
    """Gauss–Newton iterations of the nonlinear form to the optimum of its discrete problem.

    Args:
        model: the controller's model (``simulate_factorized``, ``discrete``, ``C``).
        criterion: the controller's :class:`~parallel_gpc.gpc.criterion.Criterion`.
        Ts: sample time (s). iterations: the largest number of iterations (≥ 1).
        tolerance: the step tolerance (relative). time_budget: s per control step, or None.
    """

    def __init__(self, model, criterion: Criterion, Ts: float, iterations: int, tolerance: float,
                 time_budget: float | None):
        self.model, self.criterion, self.Ts = model, criterion, Ts
        self.iterations, self.tolerance, self.time_budget = iterations, tolerance, time_budget

    # -------------------------------------------------------------- the true problem
    def _rollout(self, X, w, u0, u_map, v, d):
        """(trajectory, inputs (N, m), J(v)) on the nonlinear model; trajectory = simulate_factorized's output."""
        H, m = self.criterion.horizons, self.model.n_u
        u = (u0 + u_map @ v).reshape(-1, m)
        traj = self.model.simulate_factorized(X, u, self.Ts, d)
        y = traj[3][1:] @ self.model.C.T
        return traj, u, self._cost(y[H.No:].reshape(-1), w, v)

    def _cost(self, y_rows: np.ndarray, w: np.ndarray, v: np.ndarray) -> float:
        """J = Σ‖Qy (y − w)‖² + ‖kron(I, Qu) v‖² over the penalized rows (stacked, (n_rows·p,))."""
        c = self.criterion
        e = (y_rows - w).reshape(-1, c.n_outputs) @ c.Wy.T
        q = c.Qu_block @ v
        return float(e.reshape(-1) @ e.reshape(-1) + q @ q)

    # -------------------------------------------------------------- the iterations
    def run(self, X, w, pred: Prediction, result: SolveResult, problem_of, solve, disturbance, start: float):
        """Continue from the paper's step (``pred``, its solve ``result``) to the optimum.

        Args:
            X: (n_x,) measured state. w: (n_rows, p) reference rows (m, rad).
            pred: the paper's prediction (frozen Jacobians along the pre-simulation of u_sim⁰).
            result: its solve (v = the paper's increments).
            problem_of: Prediction → LeastSquaresProblem with the controller's limits.
            solve: (problem, warm start v) → SolveResult (the controller's back end).
            disturbance: (n_x,) d of the step. start: time.perf_counter() at the step's start.

        Returns:
            (prediction of the last linearization in the total v, its result with v the accepted
            plan, :class:`IterationReport`).
        """
        w = np.asarray(w, dtype=float).reshape(-1)
        if not result.ok:
            return pred, result, IterationReport(stop="solve failed")
        H, C = self.criterion.horizons, self.model.C
        u0, u_map = pred.u_base, pred.u_map
        v = np.zeros_like(result.v)
        cost = self._cost(pred.f, w, v)
        lin = pred  # the linearization that produced `result`
        report = dict(iterations=0, residual=float("nan"), stop="iterations", budget_hit=False, converged=False)
        last = time.perf_counter()
        while True:
            report["iterations"] += 1
            v_new = result.v
            delta = v_new - v
            decrease = max(self._cost(lin.f + lin.G @ v, w, v) - self._cost(lin.f + lin.G @ v_new, w, v_new), 0.0)
            alpha, accepted = 1.0, None
            for _ in range(BACKTRACKS + 1):
                trial = v + alpha * delta
                try:
                    traj, u_traj, trial_cost = self._rollout(X, w, u0, u_map, trial, disturbance)
                except MODEL_ERRORS:  # the trial plan leaves the model's domain (workspace): shorter step
                    alpha *= 0.5
                    continue
                if trial_cost <= cost - ARMIJO * alpha * decrease:
                    accepted = (trial, traj, u_traj, trial_cost)
                    break
                alpha *= 0.5
            scale = 1.0 + float(np.max(np.abs(v), initial=0.0))
            report["residual"] = float(np.max(np.abs(delta), initial=0.0)) / scale if report["iterations"] > 1 \
                else float("nan")
            if accepted is None:  # no decrease measurable above rounding: as good as converged
                flat = decrease <= ROUNDING * cost
                report.update(stop="converged" if flat else "line search", converged=flat)
                break
            v, traj, u_traj, cost = accepted
            if report["iterations"] > 1 and report["residual"] <= self.tolerance:
                report.update(stop="converged", converged=True)
                break
            if report["iterations"] >= self.iterations:
                break
            now = time.perf_counter()
            if self.time_budget is not None and (now - start) + (now - last) > self.time_budget:
                report.update(stop="time budget", budget_hit=True)
                break
            last = now
            A_seq, B_seq, _, X_seq = traj
            try:
                JX = state_jacobians(self.model, X_seq, u_traj, self.Ts)
            except MODEL_ERRORS:  # a difference step leaves the workspace: keep the accepted plan
                report["stop"] = "jacobian failed"
                break
            y_traj = X_seq[1:] @ C.T
            G = simulative_prediction(JX, B_seq, C, y_traj, u_traj, H).G
            lin = Prediction(y_traj[H.No:].reshape(-1) - G @ v, G, u0, u_map, H, "simulative")
            try:
                new = solve(problem_of(lin), v)
            except Exception as exc:  # a back end's own exception ends the iterations, never leaks
                new = SolveResult(v, np.inf, "failed", "", message=f"{type(exc).__name__}: {exc}")
            if not new.ok:
                report["stop"] = "solve failed"
                break
            result = new
        return lin, replace(result, v=v.copy(), cost=cost), IterationReport(cost=cost, **report)
