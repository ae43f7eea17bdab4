"""Cholesky of the normal equations against the QR reference; the condition guard falls back to QR."""

from __future__ import annotations

import numpy as np
import pytest

from parallel_gpc.limits import Limits
from parallel_gpc import GPCController, Horizons, ReducedModel, SCurve, Weights, build_problem
from parallel_gpc.errors import InvalidParameterError
from parallel_gpc.solvers import LeastSquaresProblem, NormalEquationsSolver, QRSolver, make_solver


@pytest.mark.parametrize("form", ["absolute", "incremental"])
@pytest.mark.parametrize("N", [10, 40])
def test_cholesky_equals_qr_on_the_controllers_problems(robot, form, N):
    """Qu = 1e-5 (the benchmark's weight): the absolute form has cond(A) ≈ 1e2 and takes the
    Cholesky path; the incremental form at N = 40 (cumulative sums) may be sent to QR by the guard."""
    ref, Ts, W = SCurve(), 0.002, Weights(1.0, 1e-5)
    ctl = GPCController.build(ReducedModel(robot), Ts, Horizons(N), W, form=form)
    for t in (0.4, 0.9):
        X = np.concatenate([ref.pose(t), (ref.pose(t + 1e-4) - ref.pose(t)) / 1e-4])
        p = build_problem(ctl.predict(X), ref.window(t, Ts, N), W, robot.n_y, robot.n_u)
        qr, ch = QRSolver().solve(p), NormalEquationsSolver().solve(p)
        assert ch.ok
        if form == "absolute" or np.linalg.cond(p.A) ** 2 < 1e6:  # well within the guard's rcond ≥ 1e-8
            assert ch.message == ""  # the Cholesky path was taken
        assert np.linalg.norm(ch.v - qr.v) <= 1e-9 * np.linalg.norm(qr.v)
        assert ch.cost == pytest.approx(qr.cost, rel=1e-9, abs=1e-300)


def test_cholesky_falls_back_to_qr_when_ill_conditioned():
    rng = np.random.default_rng(2)
    U, _ = np.linalg.qr(rng.standard_normal((30, 6)))
    V, _ = np.linalg.qr(rng.standard_normal((6, 6)))
    A = U @ np.diag(np.logspace(0, -6, 6)) @ V.T  # cond(A) = 1e6: cond(AᵀA) = 1e12
    x = rng.standard_normal(6)
    p = LeastSquaresProblem(A, A @ x)
    res = NormalEquationsSolver().solve(p)
    assert res.message == "qr: ill-conditioned normal equations"
    assert np.linalg.norm(res.v - x) <= 1e-8 * np.linalg.norm(x)
    rank_deficient = LeastSquaresProblem(np.hstack([A, A[:, :1]]), A @ x)  # a repeated column
    res = NormalEquationsSolver().solve(rank_deficient)
    assert res.message.startswith("qr:")
    assert np.allclose(res.v, QRSolver().solve(rank_deficient).v, atol=1e-10)


def test_cholesky_is_registered_and_refuses_limits(robot4):
    assert make_solver("cholesky").name == "cholesky"
    with pytest.raises(InvalidParameterError, match="cannot enforce"):
        GPCController.build(ReducedModel(robot4), 0.005, Horizons(5), solver="cholesky", limits=Limits(torque=1.0))
