"""QR square-root solve against QP back ends, min-norm, cost, and GPC → LQR convergence."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are

from parallel_gpc.limits import Limits
from parallel_gpc import GPCController, Horizons, ParallelRobot, ReducedModel, SCurve, Weights, build_problem
from parallel_gpc.gpc import absolute_prediction, incremental_prediction
from parallel_gpc.solvers import LeastSquaresProblem, MinNormOf, QRSolver, available_solvers, make_solver, qr_least_squares

QP_BACKENDS = ["qpsolvers:osqp", "qpsolvers:proxqp", "qpsolvers:daqp", "osqp-direct", "proxqp-direct", "daqp-direct"]


@pytest.fixture(scope="module")
def gpc_problems():
    """Real GPC problems of the default robot along the S-curve (absolute and incremental forms)."""
    robot = ParallelRobot.load()
    model = ReducedModel(robot)
    ref = SCurve()
    H = Horizons(15, 0, 15)
    out = {}
    for form in ("absolute", "incremental"):
        ctrl = GPCController.build(model, 0.005, H, Weights(1.0, 1e-3), form=form)
        t = 0.6
        X = np.concatenate([ref.pose(t), (ref.pose(t + 1e-4) - ref.pose(t)) / 1e-4])
        ctrl.u_prev = np.array([1.0, -2.0, 0.5, 1.5])
        pred = ctrl.predict(X)
        w = ref.window(t, 0.005, H.N)
        out[form] = (pred, w)
    return out


def _problem(gpc_problems, form, torque_limit=None):
    pred, w = gpc_problems[form]
    return build_problem(pred, w, Weights(1.0, 1e-3), 3, 4, limits=Limits(torque=torque_limit))


@pytest.mark.parametrize("form", ["absolute", "incremental"])
@pytest.mark.parametrize("backend", QP_BACKENDS)
def test_qp_backends_equal_qr_when_no_limit_binds(gpc_problems, form, backend):
    problem = _problem(gpc_problems, form, torque_limit=1e4)
    qr = QRSolver().solve_unconstrained(problem)
    qp = make_solver(backend).solve(problem)
    assert qp.ok and not qp.active_limits
    assert np.linalg.norm(qp.v - qr.v) <= 1e-6 * np.linalg.norm(qr.v)


@pytest.mark.parametrize("form", ["absolute", "incremental"])
def test_qp_backends_agree_and_respect_binding_limits(gpc_problems, form):
    unconstrained = QRSolver().solve(_problem(gpc_problems, form)).v
    pred = gpc_problems[form][0]
    peak = np.max(np.abs(pred.u_base + pred.u_map @ unconstrained))
    problem = _problem(gpc_problems, form, torque_limit=0.5 * peak)  # binds
    sols = {}
    for backend in QP_BACKENDS:
        res = make_solver(backend).solve(problem)
        assert res.ok and res.active_limits, backend
        u = pred.u_base + pred.u_map @ res.v
        assert np.max(np.abs(u)) <= 0.5 * peak * (1 + 1e-6), backend
        sols[backend] = res.v
    ref = sols["daqp-direct"]
    for backend, v in sols.items():
        assert np.linalg.norm(v - ref) <= 1e-4 * np.linalg.norm(ref), backend



def test_daqp_solves_the_cumulative_torque_limit_as_bounds(gpc_problems):
    """The incremental torque limit lo ≤ M v ≤ hi (M = kron(tri, I)) goes to DAQP as simple
    bounds on s = M v: the same solution as DAQP with the general constraint rows, within limits."""
    from dataclasses import replace

    from parallel_gpc.solvers.problem import cumulative_block

    unconstrained = QRSolver().solve(_problem(gpc_problems, "incremental")).v
    pred = gpc_problems["incremental"][0]
    tau = 0.5 * np.max(np.abs(pred.u_base + pred.u_map @ unconstrained))
    problem = _problem(gpc_problems, "incremental", torque_limit=tau)
    assert cumulative_block(problem) == 4
    rows = replace(problem, min_norm_of=None)  # not recognised: the general constraint rows
    assert cumulative_block(rows) is None
    warm = np.zeros(problem.n)
    for start in (None, warm):
        box, general = make_solver("daqp-direct").solve(problem, start), make_solver("daqp-direct").solve(rows, start)
        assert box.ok and general.ok and box.active_limits
        assert np.linalg.norm(box.v - general.v) <= 1e-7 * np.linalg.norm(general.v)
        assert problem.violation(box.v) <= 1e-9 * tau

def test_qr_cost_is_norm_of_lost_vector():
    rng = np.random.default_rng(0)
    A, b = rng.normal(size=(40, 12)), rng.normal(size=40)
    v, cost, rank = qr_least_squares(A, b)
    assert rank == 12
    np.testing.assert_allclose(cost, np.sum((A @ v - b) ** 2), rtol=1e-10)
    np.testing.assert_allclose(v, np.linalg.lstsq(A, b, rcond=None)[0], atol=1e-12)


def test_qr_returns_minimum_norm_solution_when_rank_deficient():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(30, 10)) @ np.diag([1, 1, 1, 1, 1, 1, 1, 0, 0, 0]) @ rng.normal(size=(10, 10))
    b = rng.normal(size=30)
    v, cost, rank = qr_least_squares(A, b)
    assert rank == 7
    np.testing.assert_allclose(v, np.linalg.pinv(A) @ b, atol=1e-10)  # the minimum-norm minimizer
    np.testing.assert_allclose(cost, np.sum((A @ v - b) ** 2), rtol=1e-9)


def test_long_horizon_gpc_converges_to_discrete_lqr_gain():
    """Unconstrained GPC with No = 0, Nu = N → the DARE gain with Q = CᵀQyᵀQyC, R = QuᵀQu."""
    Ts = 0.1
    A = np.array([[1.0, Ts, 0.0], [0.0, 1.0, Ts], [0.0, 0.0, 0.9]])
    B = np.array([[0.0, 0.2], [Ts, 0.0], [0.1, Ts]])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    Qy, Qu = np.diag([2.0, 1.0]), np.diag([0.3, 0.5])
    P = solve_discrete_are(A, B, C.T @ Qy.T @ Qy @ C, Qu.T @ Qu)
    K_lqr = np.linalg.solve(Qu.T @ Qu + B.T @ P @ B, B.T @ P @ A)
    N = 150
    H = Horizons(N, 0, N)
    K_gpc = np.empty((2, 3))
    for i in range(3):  # the GPC law is linear in x0: u(k) = −K x0
        x0 = np.eye(3)[i]
        pred = absolute_prediction(A, B, None, C, x0, H)
        prob = build_problem(pred, np.zeros((N, 2)), Weights(Qy, Qu), 2, 2)
        K_gpc[:, i] = -QRSolver().solve(prob).v[:2]
    np.testing.assert_allclose(K_gpc, K_lqr, rtol=1e-6, atol=1e-9)


def test_incremental_min_norm_picks_smallest_absolute_torques():
    """Qu = 0, redundant input: among optimal Δu the one with smallest u = u_prev + cumsum(Δu)."""
    A = np.array([[1.0, 0.1], [0.0, 1.0]])
    B = np.array([[0.0, 0.0], [1.0, 1.0]])  # two identical drives: null(B) = [1, −1]
    C = np.array([[1.0, 0.0]])
    H = Horizons(6, 0, 6)
    u_prev = np.array([3.0, -1.0])  # carries a null-space component
    pred = incremental_prediction(A, B, None, C, np.zeros(2), u_prev, H)
    prob = build_problem(pred, np.ones((6, 1)), Weights(1.0, 0.0), 1, 2)
    v = QRSolver().solve(prob).v
    u = (pred.u_base + pred.u_map @ v).reshape(-1, 2)
    np.testing.assert_allclose(u[:, 0], u[:, 1], atol=1e-9)  # no drive fighting
    assert prob.cost(v) <= prob.cost(np.linalg.lstsq(prob.A, prob.b, rcond=None)[0]) + 1e-12


@pytest.mark.parametrize("qu", [0.0, 1e-3, [1e-3, 2e-3, 1e-3, 5e-4]])
@pytest.mark.parametrize("form", ["absolute", "incremental"])
def test_structure_fields_are_hints_only(gpc_problems, form, qu):
    """The named structure fields (zero rows, diagonal tail, cumulative min-norm map) change the
    route, not the answer: the same A, b without hints (dense min-norm map) give the same v."""
    pred, w = gpc_problems[form]
    prob = build_problem(pred, w, Weights(1.0, qu), 3, 4)
    assert prob.nonzero_rows == (prob.A.shape[0] - prob.n if qu == 0.0 else prob.A.shape[0])
    assert prob.tail_positive == (qu != 0.0)
    bare = LeastSquaresProblem(prob.A.copy(), prob.b.copy())
    if prob.min_norm_of is not None:
        assert prob.min_norm_of.block == 4
        bare.min_norm_of = MinNormOf(np.array(prob.min_norm_of.M), prob.min_norm_of.offset.copy())
    hinted, plain = QRSolver().solve(prob), QRSolver().solve(bare)
    np.testing.assert_allclose(hinted.v, plain.v, rtol=0, atol=1e-9 * np.abs(plain.v).max())
    for backend in ("daqp-direct", "osqp-direct"):
        np.testing.assert_allclose(make_solver(backend).solve(prob).v, make_solver(backend).solve(bare).v,
                                   rtol=0, atol=1e-6 * np.abs(plain.v).max())


def test_back_ends_register_only_when_their_package_imports():
    """qpsolvers-style registry: with daqp unimportable, 'daqp-direct' is not listed and asking
    for it is one clear error (run in a fresh interpreter)."""
    code = (
        "import sys; sys.modules['daqp'] = None\n"
        "from parallel_gpc.solvers import available_solvers, make_solver\n"
        "from parallel_gpc.errors import SolverNotFoundError\n"
        "names = available_solvers()\n"
        "assert 'daqp-direct' not in names and 'qr-first:daqp-direct' not in names, names\n"
        "assert 'osqp-direct' in names and 'qr' in names, names\n"
        "try:\n    make_solver('daqp-direct')\nexcept SolverNotFoundError as e:\n    print('ERR', e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    assert "ERR solver 'daqp-direct' is not installed" in out.stdout


def test_every_listed_solver_can_be_made():
    names = available_solvers()
    assert {"qr", "osqp-direct", "proxqp-direct", "daqp-direct", "qpsolvers:osqp"} <= set(names)
    for name in names:
        assert make_solver(name).name == name
