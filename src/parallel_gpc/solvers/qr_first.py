"""QR first: solve by QR, call the QP back end only when the QR solution violates a limit.

While limits stay active (the QP's last solution had an active limit) the QR attempt is skipped
and the QP is called directly: along a receding horizon a binding limit binds for many samples,
and each skipped QR saves one factorization. The first QP solution without an active limit
switches back to QR first.

Warm start: passed on to the QP back end when it is called.
"""

from __future__ import annotations

import numpy as np

from .problem import LeastSquaresProblem, SolveResult
from .qr import QRSolver


class QRFirst:
    """Solve by QR; call the QP back end only when the QR solution violates a limit (or, after
    a solve with an active limit, directly until the limits are inactive again)."""

    def __init__(self, qp_backend):
        self.qp = qp_backend
        self.qr = QRSolver()
        self.name = f"qr-first:{qp_backend.name}"
        self._limits_active = False

    def solve(self, problem: LeastSquaresProblem, warm_start: np.ndarray | None = None) -> SolveResult:
        qr_time = 0.0
        if not (self._limits_active and problem.constrained):
            # rows added to a problem (state limits, slack variables costing c ≥ 0): QR solves the
            # problem without them; with zero slack that keeps every row it is this one's minimizer
            inner = problem.base if problem.base is not None else problem
            res = self.qr.solve_unconstrained(inner)
            if inner is not problem:
                res.v = np.concatenate([res.v, np.zeros(problem.n - inner.n)])
                res.cost = problem.cost(res.v)
            if not problem.constrained or problem.feasible(res.v):
                self._limits_active = False
                res.solver = self.name
                return res
            qr_time = res.solve_time
        qp = self.qp.solve(problem, warm_start)
        qp.solve_time += qr_time
        qp.solver = self.name
        self._limits_active = qp.ok and qp.active_limits
        return qp
