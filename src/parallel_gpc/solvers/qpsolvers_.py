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
from .kkt import verified, verified_or_polished
from .problem import UNBOUNDED, LeastSquaresProblem, SolveResult, failed_result, iterations_from_extras, scaled_qp, quiet_stdout


def installed_qp_solvers() -> list[str]:
    """QP solvers available through qpsolvers on this machine."""
    return sorted(qpsolvers.available_solvers)


class QpsolversBackend:
    """``qpsolvers.solve_problem`` with any installed solver (rebuilt every call).

    Args:
        solver: qpsolvers solver name (``osqp``, ``proxqp``, ``daqp``, …).
        polish: when the solver's point fails the KKT check, try it polished on its active set
            (:func:`~parallel_gpc.solvers.kkt.polish`; accepted only when that passes).
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
        "clarabel": dict(tol_gap_abs=1e-10, tol_gap_rel=1e-10, tol_feas=1e-10, tol_ktratio=1e-8),
        "scs": dict(eps_abs=1e-9, eps_rel=1e-9, max_iters=100000),
        "highs": dict(qp_regularization_value=1e-12),
        "daqp": dict(primal_tol=1e-9),
    }

    def __init__(self, solver: str, polish: bool = True, **settings):
        available = installed_qp_solvers()
        if solver not in available:
            raise SolverNotFoundError(f"QP solver {solver!r} is not installed; installed: {available}")
        self.solver, self.polish = solver, polish
        self.name = f"qpsolvers:{solver}"
        self.settings = {**self.SETTINGS.get(solver, {}), **settings}

    def solve(self, problem: LeastSquaresProblem, warm_start: np.ndarray | None = None) -> SolveResult:
        t0 = time.perf_counter()
        P, q, _ = scaled_qp(problem)
        G, h, Aeq, beq = _rows(problem)
        if self.solver not in qpsolvers.dense_solvers:  # OSQP, Clarabel, HiGHS, SCS: CSC here rather than a warning
            import scipy.sparse as sp

            P = sp.csc_matrix(P)
            G = None if G is None else sp.csc_matrix(G)
            Aeq = None if Aeq is None else sp.csc_matrix(Aeq)
        qp = qpsolvers.Problem(P, q, G, h, Aeq, beq, problem.lb, problem.ub)
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
        check = verified_or_polished if self.polish else verified
        return check(problem, self.name, sol.x, iterations_from_extras(sol.extras), dt, _duals(problem, sol),
                     f"{self.solver}: found")


def _sides(problem: LeastSquaresProblem):
    """Masks of the rows of L: equalities (lo = hi), finite upper and finite lower sides of the others."""
    lo, hi = problem.lo, problem.hi
    eq = lo == hi
    return eq, ~eq & (hi < UNBOUNDED), ~eq & (lo > -UNBOUNDED)


def _rows(problem: LeastSquaresProblem):
    """(G, h, A, b) of ``lo ≤ L v ≤ hi`` for qpsolvers: ``G v ≤ h`` the finite sides of the ranges,
    ``A v = b`` the rows with lo = hi (an equality as two opposite inequalities makes ProxQP report
    the problem infeasible); None where there are none."""
    if problem.L is None:
        return None, None, None, None
    eq, up, down = _sides(problem)
    L = problem.L
    G = np.vstack([L[up], -L[down]])
    h = np.concatenate([problem.hi[up], -problem.lo[down]])
    if not len(h):
        G = h = None
    return G, h, (L[eq] if eq.any() else None), (problem.hi[eq] if eq.any() else None)


def _duals(problem: LeastSquaresProblem, sol) -> np.ndarray | None:
    """The solution's multipliers stacked as ``[box; L]`` (positive on an upper limit), or None
    when the solver gave none: qpsolvers' ``z_box``, ``z`` of G (upper sides, then lower ones) and
    ``y`` of the equalities."""
    parts = []
    if problem.lb is not None:
        if sol.z_box is None or np.size(sol.z_box) != problem.n:
            return None
        parts.append(np.asarray(sol.z_box, dtype=float))
    if problem.L is not None:
        eq, up, down = _sides(problem)
        n_up, n_down = int(up.sum()), int(down.sum())
        if (n_up + n_down and (sol.z is None or np.size(sol.z) != n_up + n_down)) or \
                (eq.any() and (sol.y is None or np.size(sol.y) != int(eq.sum()))):
            return None
        y = np.zeros(problem.L.shape[0])
        if n_up + n_down:
            z = np.asarray(sol.z, dtype=float)
            y[up] += z[:n_up]
            y[down] -= z[n_up:]
        if eq.any():
            y[eq] = np.asarray(sol.y, dtype=float)
        parts.append(y)
    return np.concatenate(parts) if parts else None

