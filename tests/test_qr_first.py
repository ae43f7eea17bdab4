"""QR first: the QR result when no limit binds, the QP's otherwise; the QR attempt is skipped
while the limits stay active and resumed once they are inactive."""

from __future__ import annotations

import numpy as np

from parallel_gpc.solvers import DAQPBackend, LeastSquaresProblem, QRSolver, make_solver


class _Counting(QRSolver):
    calls = 0

    def solve_unconstrained(self, problem):
        type(self).calls += 1
        return super().solve_unconstrained(problem)


def _problem(rng, limit):
    A = rng.standard_normal((30, 8))
    b = 5.0 * rng.standard_normal(30)
    return LeastSquaresProblem(A, b, -np.full(8, limit), np.full(8, limit))


def test_qr_first_skips_the_qr_while_limits_stay_active():
    rng = np.random.default_rng(4)
    solver = make_solver("qr-first:daqp-direct")
    solver.qr = _Counting()
    binding = [_problem(rng, 0.05) for _ in range(3)]
    free = _problem(rng, 1e3)
    out = [solver.solve(p) for p in binding]
    assert _Counting.calls == 1  # only the first binding problem tried QR
    for p, res in zip(binding, out):
        assert res.ok and res.active_limits and res.solver == "qr-first:daqp-direct"
        assert np.allclose(res.v, DAQPBackend().solve(p).v, atol=1e-9)
    res = solver.solve(free)  # limits inactive: the QP's solution is the unconstrained one ...
    assert _Counting.calls == 1 and not res.active_limits
    assert np.allclose(res.v, QRSolver().solve_unconstrained(free).v, rtol=1e-6, atol=1e-9)
    res = solver.solve(free)  # ... and the next call is QR first again: the QR result exactly
    assert _Counting.calls == 2
    assert np.array_equal(res.v, QRSolver().solve_unconstrained(free).v) and res.status == "unconstrained"
