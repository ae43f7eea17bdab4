"""Input limits of the controller: the QP's tightened limits, the applied-limit verification and the
visible fallback (the unconstrained QR solution projected on the limits).

A solution is applied only if its first move keeps |u(k)| ≤ τ and |Δu(k)| ≤ δ within
:data:`APPLIED_LIMIT_RTOL`, verified once: by :func:`limit_violation`, or — a stage-wise active
set's plan — by the solver's own KKT verification when the row excess it bounds is within
:func:`limit_gap` of the tightened limits; a failed, infeasible or limit-breaking solve is
replaced by :func:`project_on_limits`, whose result is marked ``fallback`` — never silent.
"""

from __future__ import annotations

import numpy as np

from ..errors import SolverError
from ..limits import Limits
from ..solvers import SolveResult, qr_least_squares
from .prediction import Prediction

__all__ = ["LIMIT_MARGIN", "APPLIED_LIMIT_RTOL", "limit_gap", "limit_violation", "check_applied", "project_on_limits"]

#: the QP is given limits tightened by this relative margin (``limits.scaled(1 − LIMIT_MARGIN)``) so that a solution within the
#: solver's tolerance never exceeds the true limit (|u| ≤ τ exactly, nothing clipped later).
LIMIT_MARGIN = 1e-6
#: every applied input is verified: a solution whose first move exceeds a limit by more than this
#: relative tolerance (|u| > τ·(1 + 1e-9)) counts as a failed solve and the step falls back visibly.
APPLIED_LIMIT_RTOL = 1e-9


def limit_gap(limits: Limits, qp_limits: Limits) -> float:
    """The least distance (N·m) between the QP's tightened input limits and the true ones, over the
    torque and Δu limits of every drive (inf without either): a solver that verified every row of its
    solution within this of the QP's bounds (the stage-wise active set's KKT residual) has verified
    that the first move keeps the true limits — :func:`limit_violation` would find nothing.

    Args:
        limits: the controller's limits, sized to the m drives. qp_limits: the same tightened
            (``limits.scaled(1 − LIMIT_MARGIN)``).
    """
    gaps = [np.min(np.asarray(true) - np.asarray(tight)) for true, tight in
            ((limits.torque, qp_limits.torque), (limits.du, qp_limits.du)) if true is not None]
    return float(min(gaps)) if gaps else np.inf


def limit_violation(pred: Prediction, v: np.ndarray, form: str, u_prev: np.ndarray, limits: Limits) -> str:
    """Why the first move of solution ``v`` breaks the limits, or "" when it keeps them.

    Args:
        pred: the prediction the solution belongs to (u = u_base + u_map v).
        v: (n,) solution of the QP.
        form: the controller's form (the delayed form's first increment is u(k+1) − u(k)).
        u_prev: (m,) u(k−1) (N·m).
        limits: the controller's :class:`~parallel_gpc.limits.Limits`, sized to the m drives.

    Returns:
        A message naming the input and the limit it exceeds (|u(k)| ≤ τ, |Δu(k)| ≤ δ, relative
        tolerance :data:`APPLIED_LIMIT_RTOL`), or "".
    """
    tau, delta = limits.torque, limits.du
    if tau is None and delta is None:
        return ""
    m = len(u_prev)
    u = pred.u_base[:m] + pred.u_map[:m] @ v
    if tau is not None and np.any(np.abs(u) > tau * (1.0 + APPLIED_LIMIT_RTOL)):
        i = int(np.argmax(np.abs(u) / tau))
        return f"|u[{i}]| = {abs(u[i]):.9g} N·m > torque limit {tau[i]:.9g} N·m"
    # the increment of the first constrained input: delayed, u(k+1) − u(k) (u(k) is the base)
    du = u - (pred.u_base[:m] if form == "incremental-delayed" else u_prev)
    if delta is not None and form != "absolute" and np.any(np.abs(du) > delta * (1.0 + APPLIED_LIMIT_RTOL)):
        i = int(np.argmax(np.abs(du) / delta))
        return f"|Δu[{i}]| = {abs(du[i]):.9g} N·m > du limit {delta[i]:.9g} N·m"
    return ""


def check_applied(u: np.ndarray, tau: np.ndarray | None) -> None:
    """Raise :class:`~parallel_gpc.errors.SolverError` if the input about to be applied exceeds the
    torque limit (N·m) by more than :data:`APPLIED_LIMIT_RTOL`; nothing is clipped."""
    if tau is not None and np.any(np.abs(u) > tau * (1.0 + APPLIED_LIMIT_RTOL)):
        raise SolverError(f"the projected fallback input u = {u.tolist()} N·m exceeds the torque limit "
                          f"{tau.tolist()} N·m; nothing applied")


def project_on_limits(problem, pred: Prediction, failed: SolveResult, tau: np.ndarray | None, m: int) -> SolveResult:
    """A failed or infeasible QP: take the unconstrained QR solution and project it on the limits.

    Absolute form: u clipped to ±τ. Incremental forms: step by step along the control
    horizon, Δu(i) clipped to ±δ (the problem's box), then u(i) clipped to ±τ — when both cannot
    hold (an infeasible limit set, e.g. a torque limit lowered below the held u(k−1) − δ) the torque
    limit wins. The result has status ``fallback`` (the back end's status and message are
    kept in ``message``) and the step reports ``StepInfo.fallback``; never silent.

    Args:
        problem: the least-squares problem min ‖A v − b‖² with its box lb ≤ v ≤ ub.
        pred: the prediction (u = u_base + u_map v).
        failed: the back end's failed result (its solver name, status and message are kept).
        tau: (m,) torque limit (N·m) or None.
        m: number of inputs.

    Raises:
        SolverError: the QR solution is not finite.
    """
    v, _, _ = qr_least_squares(problem.A, problem.b)
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
    message = f"{failed.status}: {failed.message}; applied the QR solution projected on the limits"
    return SolveResult(v, problem.cost(v), "fallback", failed.solver, failed.iterations, failed.solve_time,
                       problem.active(v), message)
