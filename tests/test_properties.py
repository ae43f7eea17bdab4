"""Property-based tests (hypothesis) of the condenser and the QR / QP back ends.

Random stable LTI and LTV systems, horizons and weights: the condensed prediction equals a
step-by-step simulation; QR and every QP back end agree when no limit binds; with binding
limits the QP solutions respect them and agree with each other; nothing returns NaN.
Matrices come from a numpy generator seeded by hypothesis, so the examples are deterministic
(``derandomize=True``) and shrink on the seed and the sizes.
"""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from parallel_gpc.limits import Limits
from parallel_gpc import Horizons, LeastSquaresProblem, Prediction, Weights, build_problem, make_solver
from parallel_gpc.gpc import condense, incremental_prediction
from parallel_gpc.solvers import QRSolver

QP_BACKENDS = ["osqp-direct", "proxqp-direct", "daqp-direct", "qpsolvers:osqp", "qpsolvers:proxqp",
               "qpsolvers:daqp"]
SETTINGS = settings(max_examples=100, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow])


@st.composite
def horizons(draw, max_N: int = 8) -> Horizons:
    N = draw(st.integers(1, max_N))
    return Horizons(N, draw(st.integers(0, N - 1)), draw(st.integers(1, N)))


@st.composite
def systems(draw, time_varying: bool | None = None):
    """(A, B, c, C, x0, horizons): a random stable discrete model, per step if time-varying."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    n, m = draw(st.integers(1, 4)), draw(st.integers(1, 3))
    p = draw(st.integers(1, n))
    H = draw(horizons())
    ltv = draw(st.booleans()) if time_varying is None else time_varying
    count = H.N if ltv else 1

    def stable():
        A = rng.normal(size=(n, n))
        rho = np.max(np.abs(np.linalg.eigvals(A)))
        return A * (rng.uniform(0.2, 0.99) / max(rho, 1e-12))

    A = np.array([stable() for _ in range(count)])
    B = rng.normal(size=(count, n, m))
    c = rng.normal(size=(count, n)) * 0.1
    if not ltv:
        A, B, c = A[0], B[0], c[0]
    return A, B, c, rng.normal(size=(p, n)), rng.normal(size=n), H, rng


def _simulate(A, B, c, C, x0, H: Horizons, v: np.ndarray, hold: bool) -> np.ndarray:
    """Step-by-step outputs y(k+No+1..k+N) for v(0..Nu−1): held after Nu, or zero after Nu."""
    m = B.shape[-1]
    v = v.reshape(H.Nu, m)
    x, out = x0.copy(), []
    for i in range(H.N):
        Ai = A[i] if A.ndim == 3 else A
        Bi = B[i] if B.ndim == 3 else B
        ci = c[i] if c.ndim == 2 else c
        u = v[min(i, H.Nu - 1)] if (i < H.Nu or hold) else np.zeros(m)
        x = Ai @ x + Bi @ u + ci
        if i >= H.No:
            out.append(C @ x)
    return np.concatenate(out)


@SETTINGS
@given(systems(), st.booleans())
def test_condense_equals_step_by_step_simulation(system, hold):
    A, B, c, C, x0, H, rng = system
    f, G = condense(A, B, c, C, x0, H, hold_inputs=hold)
    m = B.shape[-1]
    assert f.shape == (H.n_rows * C.shape[0],) and G.shape == (H.n_rows * C.shape[0], H.Nu * m)
    v = rng.normal(size=H.Nu * m)
    y = _simulate(A, B, c, C, x0, H, v, hold)
    assert np.all(np.isfinite(f)) and np.all(np.isfinite(G))
    np.testing.assert_allclose(f + G @ v, y, rtol=1e-10, atol=1e-10 * (1 + np.abs(y).max()))


@SETTINGS
@given(systems())
def test_incremental_prediction_equals_simulation_of_cumulated_inputs(system):
    A, B, c, C, x0, H, rng = system
    m = B.shape[-1]
    u_prev = rng.normal(size=m)
    pred = incremental_prediction(A, B, c, C, x0, u_prev, H)
    dv = rng.normal(size=H.Nu * m)
    u = (pred.u_base + pred.u_map @ dv).reshape(H.Nu, m)
    np.testing.assert_allclose(u[0], u_prev + dv[:m], atol=1e-12)
    y = _simulate(A, B, c, C, x0, H, u.reshape(-1), hold=True)  # u held at u(Nu−1) after Nu
    np.testing.assert_allclose(pred.outputs(dv), y, rtol=1e-10, atol=1e-10 * (1 + np.abs(y).max()))


@st.composite
def gpc_problems(draw, form: str | None = None):
    """A random GPC least-squares problem (absolute or incremental form) with random weights."""
    A, B, c, C, x0, H, rng = draw(systems())
    p, m = C.shape[0], B.shape[-1]
    Qy = draw(st.one_of(st.floats(0.5, 2.0), st.lists(st.floats(0.5, 2.0), min_size=p, max_size=p)))
    Qu = draw(st.one_of(st.floats(0.05, 1.0), st.lists(st.floats(0.05, 1.0), min_size=m, max_size=m)))
    weights = Weights(np.asarray(Qy), np.asarray(Qu))
    w = rng.normal(size=(H.n_rows, p))
    if (form or draw(st.sampled_from(["absolute", "incremental"]))) == "absolute":
        f, G = condense(A, B, c, C, x0, H, hold_inputs=True)
        size = H.Nu * m
        pred = Prediction(f, G, np.zeros(size), np.eye(size), H, "absolute")
    else:
        pred = incremental_prediction(A, B, c, C, x0, rng.normal(size=m) * 0.1, H)
    return pred, w, weights, p, m


def _solve_all(problem: LeastSquaresProblem) -> dict:
    out = {}
    for name in QP_BACKENDS:
        res = make_solver(name).solve(problem)
        assert res.ok, (name, res.status, res.message)
        assert np.all(np.isfinite(res.v)) and np.isfinite(res.cost), name
        out[name] = res
    return out


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(gpc_problems())
def test_qr_and_qp_back_ends_agree_when_no_limit_binds(case):
    pred, w, weights, p, m = case
    problem = build_problem(pred, w, weights, p, m)
    qr = QRSolver().solve(problem)
    assert np.all(np.isfinite(qr.v))
    u = pred.u_base + pred.u_map @ qr.v
    loose = build_problem(pred, w, weights, p, m, limits=Limits(torque=10.0 * np.max(np.abs(u)) + 1.0))
    scale = max(np.linalg.norm(qr.v), 1e-3)
    for name, res in _solve_all(loose).items():
        assert np.linalg.norm(res.v - qr.v) <= 1e-5 * scale, name
        assert abs(res.cost - qr.cost) <= 1e-6 * max(qr.cost, 1e-6), name


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(gpc_problems(), st.floats(0.2, 0.8))
def test_qp_back_ends_respect_binding_limits_and_agree(case, fraction):
    pred, w, weights, p, m = case
    qr = QRSolver().solve(build_problem(pred, w, weights, p, m))
    u_free = pred.u_base + pred.u_map @ qr.v
    tau = max(fraction * np.max(np.abs(u_free)), 1.2 * np.max(np.abs(pred.u_base), initial=0.0), 1e-3)
    problem = build_problem(pred, w, weights, p, m, limits=Limits(torque=tau))
    sols = _solve_all(problem)
    for name, res in sols.items():
        u = pred.u_base + pred.u_map @ res.v
        assert np.max(np.abs(u)) <= tau * (1 + 1e-6) + 1e-9, name
        assert res.cost >= qr.cost - 1e-9 * max(1.0, qr.cost), name  # limits cannot lower the optimum
    ref = sols["daqp-direct"].v  # active-set: exact up to round-off
    scale = max(np.linalg.norm(ref), 1e-3)
    for name, res in sols.items():
        assert np.linalg.norm(res.v - ref) <= 1e-4 * scale, name


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(gpc_problems(form="incremental"), st.floats(0.01, 0.5))
def test_increment_limits_hold_in_every_back_end(case, fraction):
    pred, w, weights, p, m = case
    qr = QRSolver().solve(build_problem(pred, w, weights, p, m))
    delta = max(fraction * np.max(np.abs(qr.v)), 1e-3)
    problem = build_problem(pred, w, weights, p, m, limits=Limits(du=delta))
    for name, res in _solve_all(problem).items():
        assert np.max(np.abs(res.v)) <= delta * (1 + 1e-6) + 1e-9, name
