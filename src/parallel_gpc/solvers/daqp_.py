"""DAQP dual active-set back end through its direct API.

Warm start: yes — the working set: the limits active at the given primal warm start, else
the previous solve's active set. Importing this module raises ImportError when ``daqp`` is
not installed.

Cumulative limits as bounds: the incremental forms' torque limit is ``lo ≤ M v ≤ hi`` with M
the cumulative-sum map kron(tri, I_m) (square when the limits cover the control horizon). In
s = M v it is a box, and DAQP's simple bounds cost far less than general constraint rows (no
constraint matrix to factor against the Hessian): the QP is passed in s, with
P_s = M⁻ᵀ P M⁻¹ and q_s = M⁻ᵀ q (M⁻¹ is a block difference, M⁻ᵀ likewise on the rows) — the same
QP, ridge included, in other coordinates — and v = M⁻¹ s is returned.
"""

from __future__ import annotations

import time

import daqp
import numpy as np

from .kkt import verified
from .problem import LeastSquaresProblem, SolveResult, failed_result, scaled_qp, cumulative_block, from_cumulative


#: DAQP's primal feasibility tolerance (limit units; its default 1e-6 leaves violations that fail
#: the KKT check's 1e-7, e.g. 6.5e-7 N·m in tests/test_errors.py's derated drive).
PRIMAL_TOL = 1e-9


class DAQPBackend:
    """DAQP dual active-set solver through its direct API.

    Warm start: the initial working set is the set of limits (nearly) active at the given warm
    start (the controller passes the previous solution shifted by one sample); without one,
    the previous solve's active set. Box limits are passed as DAQP's simple bounds.
    """

    name = "daqp-direct"

    def __init__(self):
        self._sense = None

    def solve(self, problem: LeastSquaresProblem, warm_start: np.ndarray | None = None) -> SolveResult:
        t0 = time.perf_counter()
        P, q, _ = scaled_qp(problem)
        block = cumulative_block(problem)
        parts_lo, parts_hi = [], []
        if problem.lb is not None:  # simple bounds come first
            parts_lo.append(problem.lb)
            parts_hi.append(problem.ub)
        A_in = np.zeros((0, problem.n))
        if block:  # lo ≤ M v ≤ hi: simple bounds on s = M v, P ← M⁻ᵀ P M⁻¹, q ← M⁻ᵀ q
            P[:, :-block] -= P[:, block:]
            P[:-block] -= P[block:]
            q[:-block] -= q[block:]
            if warm_start is not None and warm_start.shape == (problem.n,):
                warm_start = np.cumsum(warm_start.reshape(-1, block), axis=0).reshape(-1)
        elif problem.L is not None:
            A_in = problem.L if problem.L.flags.writeable else problem.L.copy()  # DAQP wants a writable buffer
        if problem.L is not None:
            parts_lo.append(problem.lo)
            parts_hi.append(problem.hi)
        lo = np.concatenate(parts_lo) if parts_lo else np.zeros(0)
        hi = np.concatenate(parts_hi) if parts_hi else np.zeros(0)
        kwargs = {}
        if warm_start is not None and warm_start.shape == (problem.n,) and np.all(np.isfinite(warm_start)):
            kwargs["primal_start"] = np.asarray(warm_start, dtype=float)
            sense = np.zeros(lo.shape, dtype=np.int32)
        elif self._sense is not None and self._sense.shape == lo.shape:
            sense = self._sense
        else:
            sense = np.zeros(lo.shape, dtype=np.int32)
        x, _, flag, info = daqp.solve(P, q, A_in, hi, lo, sense, primal_tol=PRIMAL_TOL, **kwargs)
        dt = time.perf_counter() - t0
        if flag != 1 or not np.all(np.isfinite(x)):
            kind = "infeasible" if flag == -1 else "failed"
            return failed_result(problem, self.name, kind, int(info.get("iterations", 0)), dt, f"DAQP exit flag {flag}")
        lam = np.asarray(info["lam"], dtype=float) if "lam" in info else None
        self._sense = None if lam is None else (np.abs(lam) > 0).astype(np.int32)
        if block:  # the multipliers of the box on s = M v are those of the rows lo ≤ M v ≤ hi
            x = from_cumulative(x, block)
        return verified(problem, self.name, x, int(info.get("iterations", 0)), dt, lam, f"DAQP exit flag {flag}")

