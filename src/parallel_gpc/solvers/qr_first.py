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
        if not (self._limits_active and problem.constrained) and problem.c is None:  # (QR takes no linear term)
            res = self.qr.solve_unconstrained(problem)
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
