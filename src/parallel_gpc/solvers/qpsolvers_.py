"""qpsolvers back end: ``qpsolvers.solve_problem`` with any installed solver (rebuilt every call).

Warm start: the given primal warm start is passed as ``initvals``; solvers that accept an
initial guess use it, the others ignore it (qpsolvers' rule). No solver state is kept between
calls. Importing this module raises ImportError when ``qpsolvers`` is not installed.
"""

from __future__ import annotations

import time

import numpy as np
import qpsolvers

from ..errors import SolverNotFoundError
from .problem import LeastSquaresProblem, SolveResult, _failed, _iterations_from_extras, _scaled_qp, _solved, quiet_stdout


def installed_qp_solvers() -> list[str]:
    """QP solvers available through qpsolvers on this machine."""
    return sorted(qpsolvers.available_solvers)


class QpsolversBackend:
    """``qpsolvers.solve_problem`` with any installed solver (rebuilt every call).

    Args:
        solver: qpsolvers solver name (``osqp``, ``proxqp``, ``daqp``, …).
        **settings: passed to the solver (default: tight tolerances for OSQP/ProxQP).
    """

    _DEFAULTS = {
        "osqp": dict(eps_abs=1e-10, eps_rel=1e-10, polishing=True, max_iter=20000, verbose=False),
        "proxqp": dict(eps_abs=1e-10, eps_rel=0.0),
    }

    def __init__(self, solver: str, **settings):
        available = installed_qp_solvers()
        if solver not in available:
            raise SolverNotFoundError(f"QP solver {solver!r} is not installed; installed: {available}")
        self.solver = solver
        self.name = f"qpsolvers:{solver}"
        self.settings = {**self._DEFAULTS.get(solver, {}), **settings}

    def solve(self, problem: LeastSquaresProblem, warm_start: np.ndarray | None = None) -> SolveResult:
        t0 = time.perf_counter()
        P, q, _ = _scaled_qp(problem)
        G = h = None
        if problem.L is not None:
            G = np.vstack([problem.L, -problem.L])
            h = np.concatenate([problem.hi, -problem.lo])
        if self.solver == "osqp":  # OSQP takes CSC matrices; convert here rather than warn
            import scipy.sparse as sp

            P = sp.csc_matrix(P)
            G = None if G is None else sp.csc_matrix(G)
        qp = qpsolvers.Problem(P, q, G, h, None, None, problem.lb, problem.ub)
        settings = self.settings
        if self.solver == "osqp" and not problem.constrained:  # nothing to polish (and OSQP 1.1 says so on stdout)
            settings = {**settings, "polishing": False}
        try:
            with quiet_stdout():  # OSQP prints "Polishing not needed ..." on stdout even when quiet
                sol = qpsolvers.solve_problem(qp, solver=self.solver, initvals=warm_start, **settings)
        except Exception as exc:  # a solver's own exception becomes a reported failure
            return _failed(problem, self.name, "failed", None, time.perf_counter() - t0, f"{type(exc).__name__}: {exc}")
        dt = time.perf_counter() - t0
        if not sol.found or sol.x is None or not np.all(np.isfinite(sol.x)):
            return _failed(problem, self.name, "infeasible", None, dt, f"{self.solver} found no solution")
        return _solved(problem, self.name, sol.x, _iterations_from_extras(sol.extras), dt)

