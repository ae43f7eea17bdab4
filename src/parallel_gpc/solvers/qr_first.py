"""QR first: solve by QR, call the QP back end only when the QR solution violates a limit.

Warm start: passed on to the QP back end when it is called.
"""

from __future__ import annotations

import numpy as np

from .problem import LeastSquaresProblem, SolveResult
from .qr import QRSolver

class QRFirst:
    """Solve by QR; call the QP back end only when the QR solution violates a limit."""

    def __init__(self, qp_backend):
        self.qp = qp_backend
        self.qr = QRSolver()
        self.name = f"qr-first:{qp_backend.name}"

    def solve(self, problem: LeastSquaresProblem, warm_start: np.ndarray | None = None) -> SolveResult:
        res = self.qr.solve(problem)
        if not problem.constrained or problem.feasible(res.v):
            res.solver = self.name
            return res
        qp = self.qp.solve(problem, warm_start)
        qp.solve_time += res.solve_time
        qp.solver = self.name
        return qp

