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
from .kkt import verified
from .problem import LeastSquaresProblem, SolveResult, failed_result, iterations_from_extras, scaled_qp, quiet_stdout


def installed_qp_solvers() -> list[str]:
    """QP solvers available through qpsolvers on this machine."""
    return sorted(qpsolvers.available_solvers)


class QpsolversBackend:
    """``qpsolvers.solve_problem`` with any installed solver (rebuilt every call).

    Args:
        solver: qpsolvers solver name (``osqp``, ``proxqp``, ``daqp``, …).
        **settings: passed to the solver (default: :data:`SETTINGS`).

    Every solution goes through the KKT check of :mod:`parallel_gpc.solvers.kkt`: the status is
    ``"optimal"`` only when it passes, ``"inaccurate"`` (with the residuals) when it does not.
    """

    #: tolerances that meet :data:`~parallel_gpc.solvers.kkt.KKT_TOL` on the benchmark problems
    #: (hexapod_8ups, N = 20, box and linear limits binding; tests/test_kkt.py) and the random
    #: ones of tests/test_properties.py. ProxQP does not check its duality gap unless told: a
    #: solution 3e-6 inside an active limit passed its residual test. With its defaults
    #: Clarabel's gap tolerance 1e-8 leaves stationarity residuals of 1e-4…1e-2 and SCS's 1e-4
    #: breaks limits by ~1e-4 relative; HiGHS's QP regularization 1e-7 leaves stationarity
    #: residuals of ~5e-7 (measured worst: 4.8e-12 with 1e-12); DAQP's primal tolerance 1e-6
    #: leaves limit violations up to ~1e-6. Solvers not listed run with qpsolvers' defaults and
    #: the KKT check decides.
    SETTINGS = {
        "osqp": dict(eps_abs=1e-10, eps_rel=1e-10, polishing=True, max_iter=20000, verbose=False),
        "proxqp": dict(eps_abs=1e-10, eps_rel=0.0, check_duality_gap=True, eps_duality_gap_abs=1e-10,
                       eps_duality_gap_rel=0.0),
        "clarabel": dict(tol_gap_abs=1e-12, tol_gap_rel=1e-12, tol_feas=1e-12, tol_ktratio=1e-10),
        "scs": dict(eps_abs=1e-9, eps_rel=1e-9, max_iters=100000),
        "highs": dict(qp_regularization_value=1e-12),
        "daqp": dict(primal_tol=1e-9),
    }

    def __init__(self, solver: str, **settings):
        available = installed_qp_solvers()
        if solver not in available:
            raise SolverNotFoundError(f"QP solver {solver!r} is not installed; installed: {available}")
        self.solver = solver
        self.name = f"qpsolvers:{solver}"
        self.settings = {**self.SETTINGS.get(solver, {}), **settings}

    def solve(self, problem: LeastSquaresProblem, warm_start: np.ndarray | None = None) -> SolveResult:
        t0 = time.perf_counter()
        P, q, _ = scaled_qp(problem)
        G = h = None
        if problem.L is not None:
            G = np.vstack([problem.L, -problem.L])
            h = np.concatenate([problem.hi, -problem.lo])
        if self.solver not in qpsolvers.dense_solvers:  # OSQP, Clarabel, HiGHS, SCS: CSC here rather than a warning
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
            return failed_result(problem, self.name, "failed", None, time.perf_counter() - t0, f"{type(exc).__name__}: {exc}")
        dt = time.perf_counter() - t0
        if not sol.found or sol.x is None or not np.all(np.isfinite(sol.x)):
            return failed_result(problem, self.name, "infeasible", None, dt, f"{self.solver} found no solution")
        return verified(problem, self.name, sol.x, iterations_from_extras(sol.extras), dt, _duals(problem, sol),
                        f"{self.solver}: found")


def _duals(problem: LeastSquaresProblem, sol) -> np.ndarray | None:
    """The solution's multipliers stacked as ``[box; L]`` (positive on an upper limit), or None
    when the solver gave none: qpsolvers' ``z_box`` and ``z`` of ``G = [L; −L]``."""
    parts = []
    if problem.lb is not None:
        if sol.z_box is None or np.size(sol.z_box) != problem.n:
            return None
        parts.append(np.asarray(sol.z_box, dtype=float))
    if problem.L is not None:
        k = problem.L.shape[0]
        if sol.z is None or np.size(sol.z) != 2 * k:
            return None
        z = np.asarray(sol.z, dtype=float)
        parts.append(z[:k] - z[k:])
    return np.concatenate(parts) if parts else None

