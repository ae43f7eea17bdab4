"""KKT check of a QP solution: a back end's "optimal" is reported only when the optimality
conditions hold at the returned point.

Every QP back end solves the scaled QP of a :class:`LeastSquaresProblem`,
``min ½ vᵀP v + qᵀv`` with ``P = s·AᵀA + ρI`` and ``q = −s·Aᵀb`` (s = 1/max diag AᵀA, ρ =
:data:`~parallel_gpc.solvers.problem.QP_REGULARIZATION`), subject to the
stacked limits ``lo ≤ C v ≤ hi`` with ``C = [I; L]`` (box rows first, as
:func:`~parallel_gpc.solvers.problem.stacked_constraints`). A point v with multipliers y (the
convention of OSQP and ProxQP: ``y_i > 0`` pushes on an upper limit, ``y_i < 0`` on a lower one)
is accepted when three relative residuals are within :class:`KKTTolerance`:

* primal — the largest limit violation, each over ``max(1, |its limit|)`` (a torque limit of
  50 N·m broken by 5e-6 N·m gives 1e-7);
* stationarity — ``‖P v + q + Cᵀy‖∞ / max(‖P v‖∞, ‖q‖∞, ‖Cᵀy‖∞)`` (OSQP's relative dual
  residual);
* complementarity — the duality gap ``Σ y⁺(hi − C v) + Σ y⁻(C v − lo)`` over
  ``max(|vᵀP v|, |qᵀv|, Σ |y_i|·max(1, |limit_i|))`` (ProxQP's relative gap, each limit at the
  primal check's scale: at v = 0 held on limits at 0 — u(k) on its torque limit in the delayed
  form — the objective and |limit| vanish and a gap of rounding, 1e-16, would read as 100 %).
  For a convex QP it bounds the suboptimality: ``f(v) − f* ≤ gap + ‖residual‖·‖v − v*‖``.

The multipliers are the back end's own when it gives them; when it gives none, or its own fail
the check, they are estimated from v alone: in closed form for box limits (``y = −∇f`` on the
limits within :data:`ACTIVE_RTOL`, of the right sign), by non-negative least squares on the
nearly active rows when linear limits are among them. Any multipliers that pass certify v, so
the estimate only has to find them when they exist.

:func:`verified` turns a back end's "optimal" into a :class:`SolveResult` with the status from
this check: ``"optimal"`` when it passes, ``"inaccurate"`` (not ``ok``: the controller's visible
fallback takes over) when it does not, with the residuals and tolerances in the message.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

from .problem import LIMIT_TOL, QP_REGULARIZATION, LeastSquaresProblem, SolveResult, scaled_qp, stacked_constraints

#: a limit counts as nearly active for the multiplier estimate when its slack is at most this
#: fraction of max(1, |limit|).
ACTIVE_RTOL = 1e-5


@dataclass(frozen=True)
class KKTTolerance:
    """Tolerances of the KKT check (all relative, see the module docstring).

    Attributes:
        primal: largest limit violation, each over max(1, |its limit|).
        stationarity: ``‖∇f + Cᵀy‖∞`` over the largest of its terms.
        complementarity: duality gap over the largest term of the objective and the limits' part
            (each limit at max(1, |limit|)).
    """

    primal: float = LIMIT_TOL
    stationarity: float = 1e-6
    complementarity: float = 1e-6


#: the tolerance every QP back end's solution is checked against.
KKT_TOL = KKTTolerance()


@dataclass(frozen=True)
class KKTResiduals:
    """Relative KKT residuals of a point (see the module docstring). Infinite when v is not finite.

    Attributes:
        primal, stationarity, complementarity: relative residuals (dimensionless).
        estimated: True when the multipliers were estimated from v (not the back end's).
    """

    primal: float
    stationarity: float
    complementarity: float
    estimated: bool = False

    def passes(self, tol: KKTTolerance = KKT_TOL) -> bool:
        return (self.primal <= tol.primal and self.stationarity <= tol.stationarity
                and self.complementarity <= tol.complementarity)

    def describe(self, tol: KKTTolerance = KKT_TOL) -> str:
        """``primal 2.5e-04 > 1e-07, stationarity 3e-09 ≤ 1e-06, …`` (one line)."""
        parts = []
        for name in ("primal", "stationarity", "complementarity"):
            value, limit = getattr(self, name), getattr(tol, name)
            parts.append(f"{name} {value:.2g} {'≤' if value <= limit else '>'} {limit:.0e}")
        return ", ".join(parts) + (" (multipliers estimated)" if self.estimated else "")


class _Point:
    """The scaled QP's quantities at v, formed once: P v, q, the stacked limits and C v."""

    def __init__(self, problem: LeastSquaresProblem, v: np.ndarray):
        A, b = problem.leading_rows()
        d = None
        if A.shape[0] == problem.A.shape[0] and problem.tail_diag is not None:  # [A_top; diag(d)], b = [b_top; 0]
            top = A.shape[0] - A.shape[1]
            A, b, d = A[:top], b[:top], problem.tail_diag
        col2 = np.einsum("ij,ij->j", A, A)
        Pv = A.T @ (A @ v)
        if d is not None:
            d2 = d * d
            col2 += d2
            Pv += d2 * v
        s = 1.0 / max(float(col2.max(initial=0.0)), 1e-300)
        Pv *= s
        Pv += QP_REGULARIZATION * v
        self.Pv, self.q, self.v = Pv, A.T @ b, v
        self.q *= -s
        if problem.c is not None:  # ‖A v − b‖² + cᵀv (the soft limits' exact penalty): q of problem.scaled_qp
            self.q += 0.5 * s * problem.c
        self.g = self.Pv + self.q
        self.norms = max(float(abs(self.Pv).max()), float(abs(self.q).max())) if v.size else 0.0
        self.objective = max(abs(float(v @ self.Pv)), abs(float(self.q @ v)))
        self.n_box = v.size if problem.lb is not None else 0
        self.L = problem.L
        if self.L is None:
            self.lo, self.hi, self.Cv = (problem.lb, problem.ub, v) if self.n_box else (np.zeros(0),) * 3
        elif not self.n_box:
            self.lo, self.hi, self.Cv = problem.lo, problem.hi, self.L @ v
        else:
            self.lo, self.hi = np.concatenate([problem.lb, problem.lo]), np.concatenate([problem.ub, problem.hi])
            self.Cv = np.concatenate([v, self.L @ v])
        # each limit's scale max(1, |limit|): of its violation (primal), its slack (active) and its gap term
        self.scale_lo, self.scale_hi = np.maximum(1.0, abs(self.lo)), np.maximum(1.0, abs(self.hi))
        self.finite = math.isfinite(float(self.scale_lo.sum()) + float(self.scale_hi.sum()))  # else some are ±inf
        self.slack_hi, self.slack_lo = self.hi - self.Cv, self.Cv - self.lo
        self.gap_hi, self.gap_lo = np.maximum(self.slack_hi, 0.0), np.maximum(self.slack_lo, 0.0)
        worst = min(float(self.slack_hi.min(initial=0.0)), float(self.slack_lo.min(initial=0.0)))
        self.primal = 0.0  # never −0
        if worst < 0.0:  # each violation relative to its own limit: max(1, |limit|)
            self.primal = max(float((-self.slack_hi / self.scale_hi).max()),
                              float((-self.slack_lo / self.scale_lo).max()))

    def Cty(self, y: np.ndarray) -> np.ndarray:
        """Cᵀy, (n,)."""
        if self.L is None:
            return y.copy() if self.n_box else np.zeros_like(self.v)
        out = self.L.T @ y[self.n_box:]
        if self.n_box:
            out += y[:self.n_box]
        return out

    def residuals(self, y: np.ndarray, estimated: bool) -> KKTResiduals:
        Cty = self.Cty(y)
        r = self.g + Cty
        stationarity = _ratio(float(abs(r).max(initial=0.0)), max(self.norms, float(abs(Cty).max(initial=0.0))))
        up = np.maximum(y, 0.0)
        down = up - y
        slack_hi, slack_lo = self.gap_hi, self.gap_lo
        if self.finite:
            gap = float(up @ slack_hi + down @ slack_lo)
            limits = float(up @ self.scale_hi + down @ self.scale_lo)
        else:  # no multiplier on an absent limit: 0·inf counts 0 (a multiplier on one counts inf)
            gap = _products(up, slack_hi) + _products(down, slack_lo)
            limits = _products(up, self.scale_hi) + _products(down, self.scale_lo)
        complementarity = _ratio(gap, max(self.objective, limits))
        return KKTResiduals(self.primal, stationarity, complementarity, estimated)

    def estimate(self) -> np.ndarray:
        """Multipliers from v alone, on the limits within :data:`ACTIVE_RTOL` of v."""
        y = np.zeros(self.lo.size)
        if y.size == 0:
            return y
        near_hi = self.slack_hi <= ACTIVE_RTOL * self.scale_hi
        near_lo = self.slack_lo <= ACTIVE_RTOL * self.scale_lo
        if not self.finite:  # an absent limit (±inf) is never active
            near_hi &= np.isfinite(self.hi)
            near_lo &= np.isfinite(self.lo)
        n, g = self.n_box, self.g
        if not (near_hi[n:].any() or near_lo[n:].any()):  # box rows only: y = −g on them, of the right sign
            if n:
                y[:n] = np.where((near_hi[:n] & (g < 0)) | (near_lo[:n] & (g > 0)), -g, 0.0)
            return y
        rows = np.concatenate([np.flatnonzero(near_hi), np.flatnonzero(near_lo)])
        sign = np.concatenate([np.ones(int(near_hi.sum())), -np.ones(int(near_lo.sum()))])
        cols = np.zeros((self.v.size, rows.size))  # column j: sign_j · (row j of C)ᵀ
        box = rows < n
        cols[rows[box], np.flatnonzero(box)] = sign[box]
        cols[:, ~box] = (self.L[rows[~box] - n] * sign[~box, None]).T
        try:
            lam, _ = nnls(cols, -g, maxiter=50 * rows.size)
        except RuntimeError:  # no estimate: v is then certified only by the back end's own multipliers
            return y
        np.add.at(y, rows, sign * lam)
        return y


def _ratio(num: float, den: float) -> float:
    """num/den, 0 when num is 0, inf when num is not finite."""
    if not math.isfinite(num):
        return math.inf
    return 0.0 if num == 0.0 else num / max(den, 1e-300)


def _products(y: np.ndarray, x: np.ndarray) -> float:
    """Σ y·x over y > 0 (y ≥ 0): an absent limit (x = inf) without a multiplier adds nothing."""
    on = y > 0
    return float(y[on] @ x[on])


def kkt_residuals(problem: LeastSquaresProblem, v: np.ndarray, duals: np.ndarray | None = None,
                  tol: KKTTolerance = KKT_TOL) -> KKTResiduals:
    """Relative KKT residuals of v for ``problem``'s scaled QP.

    Args:
        problem: the least-squares problem with its limits.
        v: (n,) candidate solution.
        duals: (n_box + k,) multipliers of the scaled QP for the stacked limits ``[box; L]``
            (positive on an upper limit, negative on a lower one), or None.
        tol: used to decide whether to try estimated multipliers after the given ones.

    Returns:
        The residuals with the given multipliers when they pass ``tol``, else the smaller of
        those and the ones with multipliers estimated from v.
    """
    v = np.asarray(v, dtype=float)
    if v.shape != (problem.n,) or not np.all(np.isfinite(v)):
        return KKTResiduals(np.inf, np.inf, np.inf)
    point = _Point(problem, v)
    given = None
    if duals is not None:
        duals = np.asarray(duals, dtype=float).reshape(-1)
        if duals.shape == point.lo.shape and np.all(np.isfinite(duals)):
            given = point.residuals(duals, estimated=False)
            if given.passes(tol):
                return given
    estimated = point.residuals(point.estimate(), estimated=True)
    if given is None or estimated.passes(tol):
        return estimated
    return given if _worst(given, tol) <= _worst(estimated, tol) else estimated


def _worst(res: KKTResiduals, tol: KKTTolerance) -> float:
    return max(res.primal / tol.primal, res.stationarity / tol.stationarity, res.complementarity / tol.complementarity)


def verified(problem: LeastSquaresProblem, name: str, v, iterations, dt: float, duals=None, backend_status: str = "",
             tol: KKTTolerance = KKT_TOL) -> SolveResult:
    """A back end's solution with the status from the KKT check.

    Args:
        problem: the solved problem. name: back-end name.
        v: (n,) the back end's solution. iterations: its iteration count or None.
        dt: wall time of the back end's solve, s (the check's time is added).
        duals: the back end's multipliers (see :func:`kkt_residuals`) or None.
        backend_status: the back end's own status (kept in the message), e.g. ``"OSQP status: solved"``.
        tol: the tolerances.

    Returns:
        status ``"optimal"`` when the check passes, else ``"inaccurate"`` with the residuals
        and tolerances in ``message``; cost and active limits on the original problem.
    """
    t0 = time.perf_counter()
    v = np.asarray(v, dtype=float)
    res = kkt_residuals(problem, v, duals, tol)
    ok = res.passes(tol)
    said = f" ({backend_status})" if backend_status else ""
    message = "" if ok else f"{name} returned a solution{said} that fails the KKT check: {res.describe(tol)}"
    dt += time.perf_counter() - t0
    return SolveResult(v, problem.cost(v), "optimal" if ok else "inaccurate", name, iterations, dt,
                       problem.active(v), message)


#: a limit counts as active for :func:`polish` when the back end's point is within this fraction
#: of max(1, |limit|) of it (first-order methods stop ~1e-6 short of an active limit).
POLISH_RTOL = 1e-4


def polish(problem: LeastSquaresProblem, v: np.ndarray, rounds: int = 10) -> np.ndarray | None:
    """The exact minimizer on the limits a first-order back end's point ``v`` (nearly) meets: the
    equality-constrained QP of the scaled problem with those limits as equalities, solved through
    its KKT system, then corrected a few ``rounds`` like a primal active set (a limit whose
    multiplier has the wrong sign is released, a broken one is added); None when v is not finite.

    The result is a candidate only: :func:`verified` decides.
    """
    v = np.asarray(v, dtype=float)
    if not np.all(np.isfinite(v)):
        return None
    P, q, _ = scaled_qp(problem)
    C, lo, hi = stacked_constraints(problem)
    n = P.shape[0]
    Cv = C @ v
    upper = np.isfinite(hi) & (hi - Cv <= POLISH_RTOL * np.maximum(1.0, np.abs(hi)))
    lower = np.isfinite(lo) & (Cv - lo <= POLISH_RTOL * np.maximum(1.0, np.abs(lo))) & ~upper
    x = v
    for _ in range(rounds):
        rows = np.flatnonzero(upper | lower)
        Ca, k = C[rows], len(rows)
        K = np.zeros((n + k, n + k))
        K[:n, :n], K[:n, n:], K[n:, :n] = P, Ca.T, Ca
        sol = np.linalg.lstsq(K, np.concatenate([-q, np.where(upper, hi, lo)[rows]]), rcond=None)[0]
        x, lam = sol[:n], sol[n:]  # P x + q + Caᵀ λ = 0: λ ≥ 0 on an upper limit, ≤ 0 on a lower one
        sign = np.where(upper[rows], 1.0, -1.0)
        wrong = rows[sign * lam < -1e-12 * max(1.0, float(np.abs(lam).max(initial=0.0)))]
        Cx = C @ x
        over = ~(upper | lower) & np.isfinite(hi) & (Cx - hi > LIMIT_TOL * np.maximum(1.0, np.abs(hi)))
        under = ~(upper | lower) & np.isfinite(lo) & (lo - Cx > LIMIT_TOL * np.maximum(1.0, np.abs(lo)))
        if not wrong.size and not over.any() and not under.any():
            break
        upper[wrong] = lower[wrong] = False
        upper |= over
        lower |= under
    return x


def verified_or_polished(problem: LeastSquaresProblem, name: str, v, iterations, dt: float, duals=None,
                         backend_status: str = "") -> SolveResult:
    """:func:`verified`, and when the back end's point fails the KKT check, the :func:`polish` of it
    if that passes (first-order back ends, OSQP and ProxQP, reach the active set long before the
    tolerance the check asks)."""
    first = verified(problem, name, v, iterations, dt, duals, backend_status)
    if first.ok:
        return first
    t0 = time.perf_counter()
    x = polish(problem, v)
    if x is None:
        return first
    second = verified(problem, name, x, iterations, dt + time.perf_counter() - t0, None,
                      f"{backend_status}, polished on its active set")
    return second if second.ok else first
