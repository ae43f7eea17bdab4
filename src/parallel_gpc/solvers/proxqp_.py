"""Persistent ProxQP dense back end.

Warm start: yes — ProxQP's ``WARM_START_WITH_PREVIOUS_RESULT`` (its own previous primal and
dual solution; the ``warm_start`` argument is not used). A warm-started solve that fails (with
state limits' rows the previous result can make ProxQP report a feasible problem infeasible) is
repeated once cold; after a failed solve the next one starts cold. A point that fails the KKT
check is polished on its active set (:func:`~parallel_gpc.solvers.kkt.polish`) and accepted
only when that passes. Importing this module raises ImportError when ``proxsuite`` is not installed.
"""

from __future__ import annotations

import time

import numpy as np
import proxsuite

from .kkt import verified_or_polished
from .problem import LeastSquaresProblem, PersistentQPBackend, SolveResult, failed_result


class ProxQPBackend(PersistentQPBackend):
    """Persistent ProxQP dense solver, warm-started with the previous solution."""

    name = "proxqp-direct"

    def __init__(self, eps: float = 1e-10, max_iter: int = 10000):
        super().__init__(eps, max_iter)
        self._qp = None
        self._was_warm = False

    def solve(self, problem: LeastSquaresProblem, warm_start: np.ndarray | None = None) -> SolveResult:
        t0 = time.perf_counter()
        result = self._solve(problem)
        if not result.ok and self._was_warm:  # a warm start from the last step's solution can mislead
            # ProxQP (a hard problem reported infeasible, the iteration cap): once more, cold
            self._qp = None
            result = self._solve(problem)
        result.solve_time = time.perf_counter() - t0
        return result

    def _solve(self, problem: LeastSquaresProblem) -> SolveResult:
        t0 = time.perf_counter()
        P, q, C, lo, hi, shape = self.dense_qp(problem)
        self._was_warm = self._qp is not None and self._shape == shape
        if self._qp is None or self._shape != shape:
            self._qp = proxsuite.proxqp.dense.QP(problem.n, 0, C.shape[0])
            s = self._qp.settings
            s.eps_abs, s.eps_rel, s.max_iter, s.verbose = self.eps, 0.0, self.max_iter, False
            s.check_duality_gap, s.eps_duality_gap_abs, s.eps_duality_gap_rel = True, self.eps, 0.0  # else off
            s.initial_guess = proxsuite.proxqp.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT
            self._qp.init(P, q, None, None, C if C.size else None, lo if C.size else None, hi if C.size else None)
            self._shape = shape
        else:
            self._qp.update(P, q, None, None, C if C.size else None, lo if C.size else None, hi if C.size else None)
        self._qp.solve()
        dt = time.perf_counter() - t0
        info = self._qp.results.info
        status = str(info.status)
        v = np.asarray(self._qp.results.x).copy()
        solved = "SOLVED" in status.upper() and "CLOSEST" not in status.upper()
        if "INFEASIBLE" in status.upper() or not np.all(np.isfinite(v)):
            self._qp = None  # its warm start is now meaningless: set up afresh next time
            return failed_result(problem, self.name, "infeasible" if "INFEASIBLE" in status.upper() else "failed",
                                 int(info.iter), dt, f"ProxQP status: {status}")
        duals = np.asarray(self._qp.results.z).copy() if C.size and solved else None
        result = verified_or_polished(problem, self.name, v, int(info.iter), dt, duals, f"ProxQP status: {status}")
        if not result.ok:
            self._qp = None
            if not solved:
                return failed_result(problem, self.name, "failed", int(info.iter), dt, f"ProxQP status: {status}")
        return result

