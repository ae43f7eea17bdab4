"""Bounded-variable least squares against scipy's BVLS, DAQP and the controller's default back end."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from parallel_gpc.limits import Limits
from parallel_gpc import GPCController, Horizons, ParallelRobot, ReducedModel, SCurve, Weights
from parallel_gpc.solvers import BVLSSolver, DAQPBackend, LeastSquaresProblem, make_solver


def _random_problem(rng, tail: bool):
    r, n = int(rng.integers(n_min := 4, 30)), int(rng.integers(2, n_min + 16))
    r = max(r, n) if not tail else r  # without the regularization block: full column rank
    A = rng.standard_normal((r, n))
    b = 3.0 * rng.standard_normal(r)
    d = None
    if tail:
        d = rng.uniform(0.05, 0.5, n)
        A, b = np.vstack([A, np.diag(d)]), np.concatenate([b, np.zeros(n)])
    lb, ub = -rng.uniform(0.05, 1.0, n), rng.uniform(0.05, 1.0, n)
    return LeastSquaresProblem(A, b, lb, ub, tail_diag=d, tail_positive=tail)


@pytest.mark.parametrize("tail", [False, True])
def test_bvls_equals_scipy_bvls_cold_and_warm(tail):
    rng = np.random.default_rng(3)
    binding = 0
    for _ in range(60):
        p = _random_problem(rng, tail)
        ref = lsq_linear(p.A, p.b, (p.lb, p.ub), method="bvls", tol=1e-14).x
        scale = max(1.0, np.linalg.norm(ref))
        cold = BVLSSolver().solve(p)
        assert cold.ok and p.violation(cold.v) == 0.0
        assert np.linalg.norm(cold.v - ref) <= 1e-10 * scale
        start = np.clip(ref + 0.05 * rng.standard_normal(p.n), p.lb, p.ub)  # a wrong active set, mostly
        warm = BVLSSolver().solve(p, start)
        assert np.linalg.norm(warm.v - ref) <= 1e-10 * scale
        binding += int(cold.active_limits)
    assert binding >= 30  # the bounds really bind in most problems


def test_bvls_matches_daqp_on_the_controllers_limited_problems():
    """The absolute controller along the S-curve with a binding torque limit: bvls, the default
    back end and DAQP alone give the same torques."""
    robot = ParallelRobot.load("planar_4rrr")
    ref, Ts, H, W = SCurve(), 0.005, Horizons(12), Weights(1.0, 1e-3)
    ctls = {name: GPCController.build(ReducedModel(robot), Ts, H, W, solver=name, limits=Limits(torque=0.5))
            for name in ("bvls", "qr-first:bvls", "daqp-direct")}
    active = 0
    for k in range(8):
        t = 0.3 + 0.1 * k
        X = np.concatenate([ref.pose(t), (ref.pose(t + 1e-4) - ref.pose(t)) / 1e-4])
        w = ref.window(t, Ts, H.N)
        infos = {name: c.step(X, w) for name, c in ctls.items()}
        assert not any(i.fallback for i in infos.values())
        u_ref = infos["daqp-direct"].u
        for name in ("bvls", "qr-first:bvls"):
            assert np.allclose(infos[name].u, u_ref, atol=1e-6 * 0.5, rtol=0), (name, t)
            assert np.all(np.abs(infos[name].u) <= 0.5)
        active += int(infos["bvls"].result.active_limits)
    assert active >= 4


def test_bvls_refuses_linear_limits_with_a_reported_failure():
    rng = np.random.default_rng(0)
    p = LeastSquaresProblem(rng.standard_normal((6, 3)), rng.standard_normal(6), L=np.eye(3), lo=-np.ones(3),
                            hi=np.ones(3))
    res = BVLSSolver().solve(p)
    assert not res.ok and "box limits" in res.message and np.all(np.isnan(res.v))
    daqp = DAQPBackend().solve(p)
    assert daqp.ok  # the same problem is fine for a QP back end


def test_bvls_reports_an_exhausted_iteration_limit():
    rng = np.random.default_rng(5)
    p = LeastSquaresProblem(rng.standard_normal((20, 10)), 10 * rng.standard_normal(20), -0.01 * np.ones(10),
                            0.01 * np.ones(10))
    assert BVLSSolver().solve(p).ok
    res = BVLSSolver(max_iter=1).solve(p)
    assert res.status == "failed" and "did not converge" in res.message


def test_bvls_is_registered():
    assert make_solver("bvls").name == "bvls"
    assert make_solver("qr-first:bvls").name == "qr-first:bvls"


def test_bvls_with_the_incremental_torque_limit_is_refused_at_construction():
    from parallel_gpc.errors import InvalidParameterError

    robot = ParallelRobot.load("planar_4rrr")
    with pytest.raises(InvalidParameterError, match="box limits only"):
        GPCController.build(ReducedModel(robot), 0.005, Horizons(5), form="incremental", solver="bvls", limits=Limits(torque=1.0))
    ctl = GPCController.build(ReducedModel(robot), 0.005, Horizons(5), form="incremental", solver="bvls", limits=Limits(du=1.0))
    assert ctl.solver == "bvls"  # Δu limits are a box: accepted
