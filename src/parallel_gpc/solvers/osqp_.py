"""Persistent OSQP back end (set up once per problem structure, then updated every step).

Warm start: yes — the given primal warm start (the controller passes its previous solution
shifted by one sample) through ``OSQP.warm_start``; OSQP also keeps its previous iterate.

Accuracy: ADMM reaches the KKT tolerance slowly on problems with general rows (the state limits'
rows and slack variables); a point that fails the check, or stops at the iteration cap, is
polished on the limits it meets (:func:`~parallel_gpc.solvers.kkt.polish`) and accepted only when
that passes the check.
Importing this module raises ImportError when ``osqp`` is not installed (the registry then
leaves ``osqp-direct`` out).
"""

from __future__ import annotations

import time

import numpy as np
import osqp
import scipy.sparse as sp

from .kkt import verified_or_polished
from .problem import LeastSquaresProblem, PersistentQPBackend, SolveResult, failed_result, quiet_stdout


class OSQPBackend(PersistentQPBackend):
    """Persistent OSQP: set up once per problem structure, then updated and warm-started."""

    name = "osqp-direct"

    def __init__(self, eps: float = 1e-10, max_iter: int = 20000):
        super().__init__(eps, max_iter)
        self._solver = None

    def solve(self, problem: LeastSquaresProblem, warm_start: np.ndarray | None = None) -> SolveResult:
        t0 = time.perf_counter()
        P, q, C, lo, hi, shape = self.dense_qp(problem)
        if self._shape != shape:  # dense patterns (upper triangle of P, all of C): updates keep them
            n = P.shape[0]
            self._P_pattern = sp.csc_matrix(np.triu(np.ones((n, n))))
            self._P_take = np.concatenate([np.arange(j + 1) * n + j for j in range(n)])  # column-major upper
            self._C_pattern = sp.csc_matrix(np.ones(C.shape)) if C.size else sp.csc_matrix(C)
        P_up = self._P_pattern.copy()
        P_up.data = P.reshape(-1)[self._P_take]
        C_csc = self._C_pattern.copy()
        if C.size:
            C_csc.data = C.T.reshape(-1)
        if self._solver is None or self._shape != shape:
            self._solver = osqp.OSQP()
            self._solver.setup(P=P_up, q=q, A=C_csc, l=lo, u=hi, eps_abs=self.eps, eps_rel=self.eps,
                               polishing=bool(C.size), max_iter=self.max_iter, verbose=False, warm_starting=True)
            self._shape = shape
        else:
            self._solver.update(q=q, l=lo, u=hi, Px=P_up.data, Ax=C_csc.data if C.size else None)
        if warm_start is not None and np.all(np.isfinite(warm_start)):
            self._solver.warm_start(x=warm_start)
        with quiet_stdout():  # OSQP prints "Polishing not needed ..." even when quiet
            res = self._solver.solve(raise_error=False)
        dt = time.perf_counter() - t0
        status = str(res.info.status)
        if "infeasible" in status or not np.all(np.isfinite(res.x)):
            return failed_result(problem, self.name, "infeasible" if "infeasible" in status else "failed",
                                 int(res.info.iter), dt, f"OSQP status: {status}")
        # "solved inaccurate" or the iteration cap: OSQP has usually found the active set by then;
        # the point, polished on it, is accepted when it passes the KKT check (else a failure)
        result = verified_or_polished(problem, self.name, res.x, int(res.info.iter), dt, res.y if C.size else None,
                                      f"OSQP status: {status}")
        if not result.ok and ("solved" not in status or "inaccurate" in status):
            return failed_result(problem, self.name, "failed", int(res.info.iter), dt, f"OSQP status: {status}")
        return result

