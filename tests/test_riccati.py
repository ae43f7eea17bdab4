"""solver="riccati": the Riccati recursion (Python reference and compiled) against the QR back end on
the controller's own problems, against scipy's DARE over a long horizon, in closed loop, and the
clear errors of the cases it does not cover."""

from __future__ import annotations

import os
from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are

from parallel_gpc.limits import Limits
from parallel_gpc import ConstrainedPlant, DiscreteLinearModel, GPCController, Horizons, ParallelRobot, ReducedModel
from parallel_gpc import SCurve, Weights
from parallel_gpc.errors import InvalidParameterError, SolverNotFoundError
from parallel_gpc.gpc.redundancy import null_basis
from parallel_gpc.gpc.riccati import RiccatiPath, RiccatiSolver
from parallel_gpc.model.native import native_module
from parallel_gpc.solvers import QRSolver, make_solver

TS = 0.002
FORMS = ["absolute", "incremental", "incremental-delayed", "nonlinear"]
HAS_COMPILED = native_module() is not None and hasattr(native_module(), "Riccati")
if not HAS_COMPILED and os.environ.get("CI"):
    raise RuntimeError("CI must test the compiled Riccati solve (parallel_gpc._native.Riccati)")
IMPLEMENTATIONS = [False, True] if HAS_COMPILED else [False]
# (N, No, Nu, Qy, Qu): the paper's setting, insensitivity + short control horizon, long horizons,
# per-channel and full (non-diagonal) weights
CASES = [(20, 0, 20, 1.0, 1e-5), (10, 2, 4, 1.0, 1e-3), (40, 0, 40, 1.0, 1e-5), (20, 3, 20, "channels", 1e-4),
         (15, 1, 7, 2.0, "full")]


@pytest.fixture(scope="module", params=["planar_4rrr", "delta_3rus", "hexapod_8ups"])
def robot(request) -> ParallelRobot:
    return ParallelRobot.load(request.param)


def _weights(robot, Qy, Qu) -> Weights:
    p, m = robot.n_y, robot.n_u
    if Qy == "channels":
        Qy = np.linspace(1.0, 3.0, p)
    if Qu == "full":
        Qu = 1e-4 * (np.diag(np.linspace(1.0, 3.0, m)) + 0.3 * (np.eye(m, k=1) + np.eye(m, k=-1)))  # ≻ 0
    return Weights(Qy, Qu)


def _qr_and_riccati(ctl: GPCController, X, w, native: bool):
    """v of the controller's condensed problem by QR, and v of the same step by the Riccati path."""
    H = ctl.horizons
    path = RiccatiPath(ctl._criterion, ctl.model.C, ctl.form, native=native)
    assert path.solver.native is native
    result = path.solve(*path.stages(ctl, X, w[H.No:]))
    pred = ctl.predict(X)  # the same one-step model and base (the controller is not stepped in between)
    reference = QRSolver().solve(ctl._criterion.problem(pred, w[H.No:]))
    return reference, result


@pytest.mark.parametrize("native", IMPLEMENTATIONS)
@pytest.mark.parametrize("form", FORMS)
def test_riccati_equals_qr_on_the_controllers_problems(robot, form, native):
    model = ReducedModel(robot)
    rng = np.random.default_rng(3)
    X = np.concatenate([robot.home_pose + 0.002 * rng.standard_normal(robot.n_y), 0.05 * rng.standard_normal(robot.n_y)])
    for N, No, Nu, Qy, Qu in CASES:
        ctl = GPCController.build(model, TS, Horizons(N, No, Nu), _weights(robot, Qy, Qu), form=form)
        ctl.u_prev = rng.standard_normal(robot.n_u)
        ctl.plan = rng.standard_normal((N, robot.n_u))
        ctl.disturbance = 1e-4 * rng.standard_normal(model.n_x)
        w = robot.home_pose + 0.005 * rng.standard_normal((N, robot.n_y))
        reference, result = _qr_and_riccati(ctl, X, w, native)
        assert result.ok and result.solver == "riccati"
        err = np.linalg.norm(result.v - reference.v) / np.linalg.norm(reference.v)
        assert err <= 1e-9, (N, No, Nu, Qy, Qu, err)
        assert result.cost == pytest.approx(reference.cost, rel=1e-9)


# a lightly damped, open-loop unstable 4-state system with 2 inputs (as in test_linear_model)
A = np.array([[1.0, 0.1, 0.0, 0.0], [0.05, 1.0, 0.02, 0.0], [0.0, 0.0, 1.0, 0.1], [0.0, 0.03, -0.04, 0.98]])
B = np.array([[0.005, 0.0], [0.1, 0.01], [0.0, 0.005], [0.02, 0.1]])
QY = np.array([[2.0, 0.3, 0.0, 0.0], [0.3, 1.0, 0.0, 0.1], [0.0, 0.0, 1.5, 0.0], [0.0, 0.1, 0.0, 0.5]])
QU = np.array([[0.4, 0.05], [0.05, 0.2]])


@pytest.mark.parametrize("native", IMPLEMENTATIONS)
def test_long_horizon_gain_is_scipys_lqr_gain(native, monkeypatch):
    """Full-state output, w = 0: u(k) = −K x with K → the infinite-horizon LQR gain of the DARE."""
    if not native:
        monkeypatch.setenv("PARALLEL_GPC_NATIVE", "0")
    P = solve_discrete_are(A, B, QY.T @ QY, QU.T @ QU)
    K_lqr = np.linalg.solve(QU.T @ QU + B.T @ P @ B, B.T @ P @ A)
    N = 150
    ctl = GPCController.build(DiscreteLinearModel(A, B, np.eye(4), Ts=0.1), 0.1, Horizons(N), Weights(QY, QU),
                        solver="riccati")
    assert ctl._riccati.solver.native is native
    K = np.empty((2, 4))
    for i in range(4):  # the law is linear in x
        ctl.reset()
        info = ctl.step(np.eye(4)[i], np.zeros((N, 4)))
        assert info.result.solver == "riccati"
        K[:, i] = -info.u
    np.testing.assert_allclose(K, K_lqr, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("name", ["planar_4rrr", "hexapod_8ups"])
@pytest.mark.parametrize("form", FORMS)
def test_closed_loop_inputs_and_plans_match_qr(name, form):
    robot = ParallelRobot.load(name)
    ref = SCurve(duration=0.2) if name == "planar_4rrr" else None
    pose0 = robot.home_pose if ref is None else ref.pose(0.0)
    runs, plans = [], []
    for solver in ("qr", "riccati"):
        ctl = GPCController.build(ReducedModel(robot), TS, Horizons(20, 1, 12), Weights(1.0, 1e-5), form=form,
                            solver=solver)
        plant = ConstrainedPlant(robot, np.concatenate([pose0, np.zeros(robot.n_y)]), Ts=TS)
        us = []
        for k in range(40):
            window = ref.window(k * TS, TS, 20) if ref is not None else np.tile(pose0 + 0.01, (20, 1))
            info = ctl.step(plant.X, window)
            assert info.result.solver == solver and not info.fallback
            us.append(info.u)
            plant.step(info.u)
        runs.append(np.array(us))
        plans.append(ctl.state.plan)
    scale = np.abs(runs[0]).max()
    assert np.abs(runs[1] - runs[0]).max() <= 1e-8 * scale
    assert np.abs(plans[1] - plans[0]).max() <= 1e-8 * np.abs(plans[0]).max()


def test_uncovered_cases_are_clear_errors():
    model = DiscreteLinearModel(A, B, np.eye(4), Ts=0.1)
    with pytest.raises(InvalidParameterError, match="riccati.*drive limits"):  # torque, du: tests/test_stagewise.py
        GPCController.build(model, 0.1, Horizons(10), Weights(1.0, 0.1), solver="riccati",
                            limits=Limits(drive_position=[0.0, 1.0]))
    with pytest.raises(InvalidParameterError, match="nonsingular input weight Qu"):
        GPCController.build(model, 0.1, Horizons(10), Weights(1.0, 0.0), solver="riccati")  # the paper's Qu = 0
    with pytest.raises(InvalidParameterError, match="nonsingular input weight Qu"):
        GPCController.build(model, 0.1, Horizons(10), Weights(1.0, [0.1, 0.0]), solver="riccati")
    ctl = GPCController.build(model, 0.1, Horizons(10), Weights(1.0, 0.1), solver="riccati")
    with pytest.raises(InvalidParameterError, match="riccati.*drive limits"):
        ctl.limits = Limits(drive_rate=2.0)  # a limit added later is refused the same way
    ctl.limits = Limits(torque=2.0)  # a torque limit added later: the stage-wise interior point
    assert ctl._riccati.constrained is not None
    with pytest.raises(InvalidParameterError, match="form"):
        RiccatiSolver(np.eye(4), np.eye(2), np.eye(4), Horizons(10), "bogus")
    with pytest.raises(SolverNotFoundError, match="path of the GPC controller.*use 'qr' here"):
        make_solver("riccati")  # the planner and the benchmark's condensed problems


def test_a_failed_riccati_solve_is_replaced_by_qr_visibly(monkeypatch):
    model = DiscreteLinearModel(A, B, np.eye(4), Ts=0.1)
    ctl = GPCController.build(model, 0.1, Horizons(10), Weights(1.0, 0.1), solver="riccati")
    qr = GPCController.build(model, 0.1, Horizons(10), Weights(1.0, 0.1), solver="qr")
    X, w = np.array([0.1, 0.0, -0.2, 0.05]), np.zeros((10, 4))
    failed = replace(ctl._riccati.solver.solve(A, B, None, X, None, w), v=np.full(20, np.nan), status="failed",
                     message="R + BᵀPB is not positive definite")
    monkeypatch.setattr(ctl._riccati, "solve", lambda *args, **kwargs: failed)
    info, expected = ctl.step(X, w), qr.step(X, w)
    assert info.result.solver == "qr" and "riccati failed (R + BᵀPB is not positive definite)" in info.result.message
    np.testing.assert_allclose(info.u, expected.u, rtol=1e-12)


HAS_FUSED = HAS_COMPILED and hasattr(native_module(), "riccati_presimulated")


@pytest.mark.skipif(not HAS_FUSED, reason="the compiled core has no riccati_presimulated")
def test_fused_nonlinear_step_is_the_two_call_path(robot):
    """The nonlinear form's one compiled call (pre-simulation + recursion) against its references:
    the model's simulate_factorized, then the compiled Riccati solve and the Python lq_tracking."""
    model = ReducedModel(robot)
    rng = np.random.default_rng(5)
    X = np.concatenate([robot.home_pose + 0.002 * rng.standard_normal(robot.n_y),
                        0.05 * rng.standard_normal(robot.n_y)])
    for N, No, Nu, Qy, Qu in CASES:
        ctl = GPCController.build(model, TS, Horizons(N, No, Nu), _weights(robot, Qy, Qu), form="nonlinear")
        ctl.plan = rng.standard_normal((N, robot.n_u))
        ctl.disturbance = 1e-4 * rng.standard_normal(model.n_x)
        w = robot.home_pose + 0.005 * rng.standard_normal((N - No, robot.n_y))
        path = RiccatiPath(ctl._criterion, model.C, "nonlinear", native=True)
        assert path.solver.fuses_presimulation
        stages = path.stages(ctl, X, w)
        assert path._planned is not None and path._planned[0] is stages[0]  # planned in the pre-simulation's call
        fused = path.solve(*stages)
        assert path._planned is None and fused.ok
        pred = path.input_map(ctl, stages)  # the inputs and null(B_d(X)) of the same call
        np.testing.assert_allclose(path.planned_inputs(fused).reshape(-1), pred.u_base + pred.u_map @ fused.v, rtol=0,
                                   atol=1e-12 * np.abs(pred.u_base).max())
        basis = null_basis(stages[1][0], native=False)
        assert (ctl._null is None) == (basis is None)
        if basis is not None:  # the same subspace (the rows may differ by sign or a rotation)
            np.testing.assert_allclose(ctl._null.T @ ctl._null, basis.T @ basis, rtol=0, atol=1e-10)
        A_seq, B_seq, c_seq, X_seq = model.simulate_factorized(X, np.concatenate((ctl.plan[1:], ctl.plan[-1:])), TS,
                                                                ctl.disturbance)
        np.testing.assert_allclose(stages[0], A_seq, rtol=0, atol=1e-9 * np.abs(A_seq).max())
        np.testing.assert_allclose(stages[1], B_seq, rtol=0, atol=1e-9 * np.abs(B_seq).max())
        for native in (True, False):  # the same stages, solved by the two-call paths
            reference = RiccatiSolver(*ctl._criterion.weights.blocks(robot.n_y, robot.n_u), model.C, ctl.horizons,
                                      "nonlinear", native=native).solve(*stages)
            err = np.linalg.norm(fused.v - reference.v) / np.linalg.norm(reference.v)
            assert err <= 1e-9, (N, No, Nu, native, err)
            assert fused.cost == pytest.approx(reference.cost, rel=1e-9)


@pytest.mark.skipif(not HAS_FUSED, reason="the compiled core has no riccati_presimulated")
def test_fused_nonlinear_step_failure_keeps_the_presimulation():
    robot = ParallelRobot.load("planar_4rrr")
    model = ReducedModel(robot)
    H = Horizons(10)
    Wy, Wu = Weights(1.0, 1e-5).blocks(robot.n_y, robot.n_u)
    solver = RiccatiSolver(Wy, Wu, model.C, H, "nonlinear", native=True)
    X, u = np.concatenate([robot.home_pose, np.zeros(robot.n_y)]), np.zeros((10, robot.n_u))
    w = np.tile(robot.home_pose, (10, 1))
    w[3, 0] = np.inf  # a target the recursion cannot meet with a finite plan
    (A_seq, B_seq, c_seq, X_seq), result, _, _ = solver.presimulated(model.compiled_update, X, u, TS, None, w)
    assert result.status == "failed" and not result.ok and "not finite" in result.message
    assert np.isnan(result.v).all() and result.v.shape == (10 * robot.n_u,)
    reference = model.simulate_factorized(X, u, TS)
    np.testing.assert_allclose(X_seq, reference[3], rtol=0, atol=1e-12)
    np.testing.assert_allclose(A_seq, reference[0], rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="w must be"):
        solver.presimulated(model.compiled_update, X, u, TS, None, w[1:])
    absolute = RiccatiSolver(Wy, Wu, model.C, H, "absolute", native=True)
    assert not absolute.fuses_presimulation


@pytest.mark.skipif(not (HAS_COMPILED and hasattr(native_module(), "presimulated_stages")),
                    reason="the compiled core has no presimulated_stages")
def test_limited_nonlinear_stages_are_the_models_presimulation(robot):
    """The limited nonlinear step's pre-simulation (one compiled call with null(B_d(X))) against its
    references: the model's simulate_factorized and the LAPACK null_basis of B_d(X)."""
    model = ReducedModel(robot)
    rng = np.random.default_rng(7)
    X = np.concatenate([robot.home_pose + 0.002 * rng.standard_normal(robot.n_y),
                        0.05 * rng.standard_normal(robot.n_y)])
    for N, No, Nu in ((10, 0, 10), (15, 2, 5)):
        ctl = GPCController.build(model, TS, Horizons(N, No, Nu), Weights(1.0, 1e-4), form="nonlinear",
                                  solver="riccati", limits=Limits(torque=50.0))
        ctl.plan = rng.standard_normal((N, robot.n_u))
        ctl.disturbance = 1e-4 * rng.standard_normal(model.n_x)
        path = ctl._riccati
        assert path._stages_call is not None and path.constrained is not None
        A_seq, B_seq, c_seq, X_seq = model.simulate_factorized(X, np.concatenate((ctl.plan[1:], ctl.plan[-1:])), TS,
                                                                ctl.disturbance)
        stages = path.stages(ctl, X, robot.home_pose + np.zeros((N - No, robot.n_y)))
        assert stages[0].flags.c_contiguous and stages[1].flags.c_contiguous  # read in place by RiccatiActive
        np.testing.assert_allclose(stages[0], A_seq, rtol=0, atol=1e-9 * np.abs(A_seq).max())
        np.testing.assert_allclose(stages[1], B_seq, rtol=0, atol=1e-9 * np.abs(B_seq).max())
        np.testing.assert_allclose(ctl._one_step[2], c_seq[0] + ctl.disturbance, rtol=0,
                                   atol=1e-9 * np.abs(c_seq[0]).max())
        np.testing.assert_allclose(path._extra["y_sim"], X_seq[1:] @ model.C.T, rtol=0, atol=1e-9)
        basis = null_basis(B_seq[0], native=False)
        assert (ctl._null is None) == (basis is None)
        if basis is not None:  # the same subspace (the rows may differ by sign or a rotation)
            np.testing.assert_allclose(ctl._null.T @ ctl._null, basis.T @ basis, rtol=0, atol=1e-10)
    with pytest.raises(ValueError, match="u_seq"):
        native_module().presimulated_stages(model.compiled_update, X, np.zeros((4, robot.n_u + 1)), TS, None, 1e-8)
