"""State and output constraints (issue 22): the stage-wise rows, hard and soft, against an
independent QP and its KKT conditions; inactive constraints cost nothing; closed loops keep them."""

from pathlib import Path

import numpy as np
import pytest
import qpsolvers
from scipy.optimize import nnls

from parallel_gpc.errors import InfeasibleLimitsError, InvalidParameterError, ShapeError
from parallel_gpc.gpc import DiscreteLinearModel, GPCController, Horizons, Weights
from parallel_gpc.gpc.constraints import constrain, hard_excess, hard_violation, stage_constraints
from parallel_gpc.gpc.criterion import build_problem
from parallel_gpc.gpc.prediction import Prediction, absolute_prediction, incremental_prediction
from parallel_gpc.limits import Limits
from parallel_gpc.solvers import make_solver

TS = 0.01


def double_integrator():
    """Two decoupled double integrators, outputs the positions (m), inputs accelerations."""
    A = np.eye(4)
    A[0, 2] = A[1, 3] = TS
    B = np.zeros((4, 2))
    B[0, 0] = B[1, 1] = TS ** 2 / 2
    B[2, 0] = B[3, 1] = TS
    C = np.hstack([np.eye(2), np.zeros((2, 2))])
    return A, B, C


def one_step(form, X, u_prev, H):
    A, B, C = double_integrator()
    if form == "absolute":
        return absolute_prediction(A, B, None, C, X, H)
    return incremental_prediction(A, B, None, C, X, u_prev, H)


def kkt_residual(P, q, Gc, hc, x, tol=1e-7):
    """Stationarity residual of min ½xᵀPx + qᵀx s.t. Gc x ≤ hc at x, with multipliers ≥ 0 on the
    active rows found by non-negative least squares (an independent optimality certificate)."""
    grad = P @ x + q
    active = hc - Gc @ x <= tol * (1 + np.abs(hc))
    if not active.any():
        return float(np.linalg.norm(grad)) / max(1.0, float(np.linalg.norm(q)))
    lam, res = nnls(Gc[active].T, -grad)
    return res / max(1.0, float(np.linalg.norm(q)))


@pytest.mark.parametrize("form", ["absolute", "incremental"])
@pytest.mark.parametrize("solver", ["daqp-direct", "proxqp-direct"])
def test_hard_box_and_velocity_match_an_independent_qp(form, solver):
    H = Horizons(12)
    X = np.array([0.3, -0.1, 2.0, -0.5])
    u_prev = np.array([1.0, -2.0])
    pred = one_step(form, X, u_prev, H)
    w = np.tile([1.0, -0.6], (H.n_rows, 1))
    weights = Weights(1.0, 0.05)
    limits = Limits(output_box=[[-1.0, 0.45], [-0.3, 1.0]], output_velocity=[1.5, 2.5], soft=()).for_drives(2, 2)
    problem = build_problem(pred, w, weights, 2, 2)
    rows = stage_constraints(pred, limits, TS, X[:2])
    full = constrain(problem, rows, limits)
    res = make_solver(solver).solve(full)
    assert res.ok and full.n_slack == 0
    # the oracle: the raw QP written here from ŷ = f + G v, no scaling, no equilibration
    Qu = 0.05 ** 2 * np.eye(problem.n)
    P = 2 * (pred.G.T @ pred.G + Qu)
    q = 2 * pred.G.T @ (pred.f - w.reshape(-1))
    Y, dY = pred.G.reshape(H.n_rows, 2, -1), None
    f = pred.f.reshape(H.n_rows, 2)
    dG = np.concatenate([Y[:1], np.diff(Y, axis=0)]).reshape(-1, problem.n)
    df = np.concatenate([f[:1] - X[:2], np.diff(f, axis=0)]).reshape(-1)
    hi_y, lo_y = np.tile([0.45, 1.0], H.n_rows), np.tile([-1.0, -0.3], H.n_rows)
    vmax = np.tile([1.5, 2.5], H.n_rows) * TS
    Gc = np.vstack([pred.G, -pred.G, dG, -dG])
    hc = np.concatenate([hi_y - pred.f, pred.f - lo_y, vmax - df, vmax + df])
    scale = 1.0 / np.diag(P).max()
    x = qpsolvers.solve_qp(P * scale, q * scale, Gc, hc, solver="daqp")  # raw rows, through qpsolvers
    assert x is not None
    assert kkt_residual(P, q, Gc, hc, x) < 1e-6  # the oracle is optimal
    assert np.max(Gc @ res.v - hc) < 1e-8  # hard: kept
    assert kkt_residual(P, q, Gc, hc, res.v) < 1e-5
    np.testing.assert_allclose(res.v, x, atol=1e-6 * max(1.0, np.abs(x).max()))
    assert np.sum(Gc @ res.v - hc > -1e-7) >= 1  # a limit binds (a test that can fail)
    assert np.max(Gc @ np.linalg.solve(P, -q) - hc) > 1e-3  # the unconstrained optimum breaks them


def test_rows_of_fixed_outputs_have_no_column_and_measure_their_violation():
    """The rows of a trajectory's own outputs (no decision variable: how gpc/nmpc.py checks a
    rolled-out plan) give the violation computed directly from the outputs, and the same as the
    prediction's rows at that plan."""
    H = Horizons(8)
    X = np.array([0.3, -0.1, 2.0, -0.5])
    pred = one_step("incremental", X, np.array([1.0, -2.0]), H)
    v = np.random.default_rng(3).standard_normal(pred.G.shape[1]) * 20.0
    y = pred.outputs(v)
    limits = Limits(output_box=[[-1.0, 0.45], [-0.3, 1.0]], output_velocity=[1.5, 2.5], soft=()).for_drives(2, 2)
    fixed = Prediction(y, np.zeros((len(y), 0)), np.zeros(0), np.zeros((0, 0)), H, "simulative")
    rows = stage_constraints(fixed, limits, TS, X[:2])
    assert rows.G.shape == (len(rows.h), 0)
    Y = y.reshape(-1, 2)
    box = np.maximum(Y - [0.45, 1.0], [-1.0, -0.3] - Y)
    speed = np.abs(np.diff(np.vstack([X[:2], Y]), axis=0)) - np.array([1.5, 2.5]) * TS  # rows in m per sample
    expected = max(box.max(), speed.max(), 0.0)
    assert expected > 0.01  # the plan breaks the limits
    assert hard_excess(rows, np.zeros(len(rows.h))) == pytest.approx(expected, rel=1e-9)
    problem = build_problem(pred, np.tile([1.0, -0.6], (H.n_rows, 1)), Weights(1.0, 0.05), 2, 2)
    assert hard_violation(problem, stage_constraints(pred, limits, TS, X[:2]), v) == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize("form", ["absolute", "incremental"])
def test_soft_equals_hard_when_feasible_and_pays_the_exact_penalty_when_not(form):
    H = Horizons(10)
    X = np.array([0.3, -0.1, 2.0, -0.5])
    pred = one_step(form, X, np.zeros(2), H)
    w = np.tile([1.0, -0.6], (H.n_rows, 1))
    problem = build_problem(pred, w, Weights(1.0, 0.05), 2, 2)
    hard = Limits(output_box=[[-1.0, 0.45], [-1.0, 1.0]], soft=()).for_drives(2, 2)
    soft = Limits(output_box=[[-1.0, 0.45], [-1.0, 1.0]]).for_drives(2, 2)
    solver = make_solver("daqp-direct")
    v_hard = solver.solve(constrain(problem, stage_constraints(pred, hard, TS, X[:2]), hard)).v
    full = constrain(problem, stage_constraints(pred, soft, TS, X[:2]), soft)
    x = solver.solve(full).v
    assert full.n_slack > 0 and np.max(x[full.n_decision:]) < 1e-9  # exact penalty: no slack used
    np.testing.assert_allclose(x[:full.n_decision], v_hard, atol=1e-6 * np.abs(v_hard).max())
    # an infeasible box (the first predicted position cannot move far enough in one sample):
    # the soft problem is solved, the hard one is not; the slack is the violation
    # (the torque limit: no input stops it in time)
    tight = Limits(torque=100.0, output_box=[[-1.0, 0.25], [-1.0, 1.0]], penalty=1e3).for_drives(2, 2)
    problem = build_problem(pred, w, Weights(1.0, 0.05), 2, 2, tight.only("torque"), np.zeros(2))
    rows = stage_constraints(pred, tight, TS, X[:2])
    full = constrain(problem, rows, tight)
    res = solver.solve(full)
    assert res.ok
    v, s = res.v[:full.n_decision], res.v[full.n_decision:] * full.slack_unit  # in m
    y = pred.outputs(v).reshape(-1, 2)
    excess = np.maximum(y[:, 0] - 0.25, 0.0)
    assert excess[0] > 1e-3
    np.testing.assert_allclose(np.sort(s[s > 1e-9]), np.sort(excess[excess > 1e-9]), rtol=1e-6, atol=1e-9)
    hard_tight = Limits(torque=100.0, output_box=[[-1.0, 0.25], [-1.0, 1.0]], soft=()).for_drives(2, 2)
    assert not solver.solve(constrain(problem, stage_constraints(pred, hard_tight, TS, X[:2]), hard_tight)).ok


def run(form, limits, solver, steps=120):
    A, B, C = double_integrator()
    ctl = GPCController.build(DiscreteLinearModel(A, B, C, Ts=TS), Ts=TS, horizons=Horizons(15), form=form,
                              weights=Weights(1.0, 0.01), limits=limits, solver=solver)
    X, w = np.zeros(4), np.tile([1.0, 0.2], (15, 1))
    plans, ys, infos = [], [], []
    for _ in range(steps):
        info = ctl.step(X, w)
        plans.append(ctl.plan.copy())
        X = A @ X + B @ info.u
        ys.append(X.copy())
        infos.append(info)
    return np.array(plans), np.array(ys), infos


@pytest.mark.parametrize("form", ["absolute", "incremental", "incremental-delayed", "nonlinear"])
def test_inactive_constraints_give_the_unconstrained_plan(form):
    wide = dict(output_box=[[-5.0, 5.0], [-5.0, 5.0]], output_velocity=100.0)
    free, _, _ = run(form, Limits(), "daqp-direct", 60)
    for soft in ((), ("output_box", "output_velocity")):
        plans, _, infos = run(form, Limits(**wide, soft=soft), "daqp-direct", 60)
        np.testing.assert_allclose(plans, free, atol=1e-9, rtol=0)
        assert all(i.constraints.active == () and i.constraints.max_slack < 1e-12 for i in infos)
    qr, _, _ = run(form, Limits(), "qr", 60)
    np.testing.assert_allclose(free, qr, atol=1e-7 * np.abs(qr).max(), rtol=0)


@pytest.mark.parametrize("form", ["absolute", "incremental", "nonlinear"])
@pytest.mark.parametrize("solver", ["daqp-direct", "qr-first:daqp-direct"])
def test_closed_loop_keeps_the_box_and_the_velocity(form, solver):
    _, ys_free, _ = run(form, Limits(), "qr")
    assert ys_free[:, 0].max() > 1.0 and np.abs(np.diff(ys_free[:, 0]) / TS).max() > 3.0  # would break both
    for soft in ((), ("output_box", "output_velocity")):
        _, ys, infos = run(form, Limits(output_box=[[-1, 0.5], [-1, 1]], output_velocity=3.0, soft=soft), solver)
        assert not any(i.fallback for i in infos)
        assert ys[:, 0].max() <= 0.5 + 1e-6
        vel = np.abs(np.diff(np.vstack([np.zeros(4), ys])[:, :2], axis=0)) / TS
        assert vel.max() <= 3.0 + 1e-5
        assert any("output_box" in i.constraints.active for i in infos)
        assert abs(ys[-1, 1] - 0.2) < 5e-3  # the free output still tracks (absolute form: Qu's offset)


def test_bad_limits_get_one_clear_error_each():
    with pytest.raises(InfeasibleLimitsError, match=r"output_box\[1\] = \[2, 1\].*lower bound must be below"):
        Limits(output_box=[[0, 1], [2, 1]])
    with pytest.raises(InfeasibleLimitsError, match="drive_position"):
        Limits(drive_position=[1.3, 0.45])
    with pytest.raises(InvalidParameterError, match="torque.*cannot be soft"):
        Limits(torque=1.0, soft=("torque",))
    with pytest.raises(InvalidParameterError, match="penalty"):
        Limits(output_box=[0, 1], penalty=0.0)
    with pytest.raises(ShapeError, match="3 pairs"):
        Limits(output_box=[[0, 1]] * 3).for_drives(2, 2)
    with pytest.raises(InfeasibleLimitsError, match=r"y\[0\] = 0.7.*outside \[0, 0.5\]"):
        Limits(output_box=[[0, 0.5], [0, 1]]).check_pose([0.7, 0.2])
    A, B, C = double_integrator()
    with pytest.raises(InvalidParameterError, match="drive_position limits need a robot.s model"):
        GPCController.build(DiscreteLinearModel(A, B, C, Ts=TS), Ts=TS, horizons=Horizons(5),
                            limits=Limits(drive_position=[0, 1]))
    with pytest.raises(InvalidParameterError, match="box limits only"):
        GPCController.build(DiscreteLinearModel(A, B, C, Ts=TS), Ts=TS, horizons=Horizons(5),
                            limits=Limits(output_box=[0, 1]), solver="bvls")


# ---------------------------------------------------------------------------- the hexapod's stroke
def hexapod_stroke_run(period, duration, limits, N=8):
    """hexapod_6ups tracking z: 0.70 m → 1.35 m → 0.70 m in ``period`` s (the legs would need 1.39 m);
    returns the error norm (m), the longest leg (m) per sample and the step reports."""
    from parallel_gpc.gpc.references import SampledTrajectory
    from parallel_gpc.model import ConstrainedPlant, ParallelRobot, ReducedModel

    robot = ParallelRobot.load("hexapod_6ups")
    t = np.linspace(0.0, period, 101)
    poses = np.tile(robot.home_pose, (len(t), 1))
    poses[:, 2] = 0.70 + 0.325 * (1 - np.cos(2 * np.pi * t / period))
    ref = SampledTrajectory(t, poses)
    Ts = 0.002
    ctl = GPCController.build(ReducedModel(robot), Ts=Ts, horizons=Horizons(N), form="nonlinear", limits=limits)
    plant = ConstrainedPlant(robot, np.concatenate([robot.home_pose, np.zeros(6)]), Ts=Ts)
    X, err, legs, infos = plant.X, [], [], []
    for k in range(int(round(duration / Ts))):
        info = ctl.step(X, ref.sample((k + 1 + np.arange(N)) * Ts))
        X = plant.step(info.u)
        err.append(np.linalg.norm(X[:6] - ref.pose((k + 1) * Ts)))
        legs.append(plant.q[robot.drive_q_indices].max())
        infos.append(info)
    return np.array(err), np.array(legs), infos


def stroke_limits(robot_range, soft):
    lo, hi = robot_range
    return Limits(torque=1000.0, drive_position=np.c_[lo, hi], soft=("drive_position",) if soft else ())


def test_hexapod_stroke_holds_and_costs_nothing_before_it_binds():
    from parallel_gpc.model import ParallelRobot

    rng = ParallelRobot.load("hexapod_6ups").drive_range
    assert np.allclose(rng[1], 1.30)
    err, legs, infos = hexapod_stroke_run(2.0, 1.0, stroke_limits(rng, False), N=10)  # up to the top
    assert not any(i.fallback for i in infos)
    assert legs.max() <= 1.30 + 1e-6  # the plant's legs, not the prediction's
    assert legs.max() > 1.30 - 1e-4  # it binds
    first = next(k for k, i in enumerate(infos) if i.constraints.active)
    assert first > 10
    free_err, _, _ = hexapod_stroke_run(2.0, (first + 1) * 0.002, Limits(torque=1000.0), N=10)
    np.testing.assert_allclose(err[:first], free_err[:first], atol=1e-9, rtol=0)


@pytest.mark.slow
@pytest.mark.parametrize("soft", [False, True])
def test_hexapod_stroke_over_the_two_second_move(soft):
    from parallel_gpc.model import ParallelRobot

    err, legs, infos = hexapod_stroke_run(2.0, 2.0, stroke_limits(ParallelRobot.load("hexapod_6ups").drive_range,
                                                                  soft), N=10)
    assert not any(i.fallback for i in infos) and legs.max() <= 1.30 + 1e-6
    if soft:  # the exact penalty: no slack where the hard problem is feasible
        assert max(i.constraints.max_slack for i in infos) < 1e-6
    assert err[-100:].max() < 1e-5  # back on the reference once the stroke lets go (3.6e-6 m measured)


# ---------------------------------------------------------------------------- robot files and the command line
def test_the_hexapod_declares_its_stroke_and_bad_limit_tables_are_refused(tmp_path):
    import shutil

    from parallel_gpc.errors import RobotFormatError
    from parallel_gpc.model import ParallelRobot
    from parallel_gpc.model.description import load_description
    from parallel_gpc.studies import run_limits

    robot = ParallelRobot.load("hexapod_6ups")
    lim = robot.state_limits
    np.testing.assert_array_equal(lim.drive_position, np.c_[robot.drive_range])
    assert lim.soft == frozenset() and "drive_position [0.45, 1.3] (hard)" in lim.describe()
    assert run_limits(robot, "none").is_empty
    both = run_limits(robot, "robot", Limits(torque=1000.0), output_velocity=2.0)
    assert both.torque.shape == () and both.drive_position.shape == (6, 2) and both.output_velocity.shape == ()
    with pytest.raises(ShapeError, match="expected 2 × 6 = 12"):
        run_limits(robot, "robot", output_box=[0, 1])
    src = Path(robot.description.sidecar_path)
    shutil.copy(robot.description.urdf_path, tmp_path / "hexapod_6ups.urdf")
    text = src.read_text()
    for table, message in (('drive_position = { drive_1 = [0.5, 1.2], leg_9 = [0.5, 1.2] }', "leg_9.*not drive"),
                           ('drive_position = "stroke"', "valid: \"urdf\""),
                           ('speed = 1.0', "unknown key")):
        (tmp_path / "hexapod_6ups.toml").write_text(text.replace('drive_position = "urdf"', table))
        with pytest.raises(RobotFormatError, match=message):
            load_description(tmp_path / "hexapod_6ups.urdf")
    (tmp_path / "hexapod_6ups.toml").write_text(text.replace('drive_position = "urdf"', "drive_position = [1.3, 0.45]"))
    with pytest.raises(RobotFormatError, match=r"\[limits\].*lower bound must be below"):
        ParallelRobot.load(tmp_path / "hexapod_6ups.urdf").state_limits
    (tmp_path / "hexapod_6ups.toml").write_text(
        text.replace('drive_position = "urdf"', "drive_position = { drive_2 = [0.5, 1.2] }"))
    one = ParallelRobot.load(tmp_path / "hexapod_6ups.urdf").state_limits.drive_position
    assert one[1].tolist() == [0.5, 1.2] and np.isinf(one[[0, 2, 3, 4, 5]]).all()


def test_track_keeps_the_workspace_box_and_prints_the_limits(tmp_path, capsys):
    from parallel_gpc.cli import main

    box = ["--output-box", "0.3", "0.6", "0.1", "0.9", "-1", "1"]  # x ≤ 0.6 cuts the S-curve (x up to 0.65)
    assert main(["track", "--robot", "planar_4rrr", "--forms", "nonlinear", "--N", "10", "--no-progress",
                 "--out", str(tmp_path), *box]) == 0
    out = capsys.readouterr().out
    assert "limits (robot file and flags; efforts in N·m, positions in m and rad): torque ±60, output_box [0.3, 0.6]; [0.1, 0.9]; [-1, 1] (soft)" in out
    res = np.load(tmp_path / "track_nonlinear.npz", allow_pickle=True)
    assert res["pose"][:, 0].max() <= 0.6 + 1e-3 and res["reference"][:, 0].max() > 0.64
    assert not res["fallback"].any()


@pytest.mark.parametrize("flags, message", [
    (["--output-box", "0.6", "0.7", "0.1", "0.9", "-1", "1"], "excludes the pose: x = 0.5"),
    (["--output-box", "0.6", "0.3", "0.1", "0.9", "-1", "1"], "lower bound must be below"),
    (["--output-box", "0.3", "0.6"], "expected 2 × 3 = 6"),
    (["--velocity-limit", "1", "2"], r"one value per output \(3,\)"),
])
def test_track_refuses_bad_limits_in_one_line(tmp_path, capsys, flags, message):
    from parallel_gpc.cli import main

    assert main(["track", "--robot", "planar_4rrr", "--forms", "nonlinear", "--no-progress",
                 "--out", str(tmp_path), *flags]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("parallel-gpc: error:") and "\n" not in err
    assert __import__("re").search(message, err), err


def test_the_planner_slows_down_to_respect_the_velocity_limit():
    from parallel_gpc.cli.plan import default_poses
    from parallel_gpc.gpc.plan_settings import PlanSettings
    from parallel_gpc.gpc.planning import plan_point_to_point
    from parallel_gpc.model import ParallelRobot

    robot = ParallelRobot.load("planar_4rrr")
    A, B = default_poses(robot)
    speeds = {}
    for name, lim in (("free", Limits()), ("hard", Limits(output_velocity=[0.3, 0.3, 10.0], soft=()))):
        res = plan_point_to_point(robot, A, B, PlanSettings(Nmax=60, limits=lim, settle_steps=10), mode="b")
        assert not any(s == "fallback" for s in res.status)
        speeds[name] = np.abs(np.diff(res.poses, axis=0) / res.settings.Ts).max(axis=0)  # mean over each sample
    assert speeds["free"][:2].max() > 0.6
    # the plan is the model frozen at each state (eq. (20)): the plant follows it to its one-step error
    assert speeds["hard"][:2].max() <= 0.3 + 1e-4


def test_drive_rows_are_the_inverse_kinematics_to_first_order(model4):
    """drive_position and drive_rate rows against the robot's own inverse kinematics (Newton
    assembly) at the predicted poses, by finite differences."""
    from parallel_gpc.gpc.constraints import DriveKinematics

    robot = model4.robot
    H = Horizons(6)
    X = np.concatenate([robot.home_pose, [0.05, -0.02, 0.1]])
    Ad, Bd, cd = model4.discrete(X, TS)
    pred = absolute_prediction(Ad, Bd, cd, model4.C, X, H)
    lim = Limits(drive_position=[-10.0, 10.0], drive_rate=50.0).for_drives(robot.n_u, robot.n_y)
    rows = stage_constraints(pred, lim, TS, X[:3], drives=DriveKinematics(robot))
    p, m = robot.n_y, robot.n_u
    poses = pred.f.reshape(-1, p)
    q0 = np.array([robot.inverse_kinematics(y) for y in poses])
    pos = rows.kind == "drive_position"
    hi_rows = np.flatnonzero(pos)[: len(q0.reshape(-1))]  # the upper side comes first
    np.testing.assert_allclose(10.0 - rows.h[hi_rows], q0.reshape(-1), atol=1e-9)  # value at v = 0
    v = np.random.default_rng(1).normal(size=pred.G.shape[1]) * 0.5
    q1 = np.array([robot.inverse_kinematics(y) for y in pred.outputs(v).reshape(-1, p)])
    lin = rows.G[hi_rows] @ v
    dq = (q1 - q0).reshape(-1)
    assert np.abs(dq).max() > 1e-5
    np.testing.assert_allclose(lin, dq, atol=1e-3 * np.abs(dq).max())  # first order: error O(|Δy|²)
    rate = np.flatnonzero(rows.kind == "drive_rate")[: len(q0.reshape(-1))]  # |J (ŷ_i − ŷ_{i−1})| ≤ r Ts
    q_prev = np.vstack([robot.inverse_kinematics(X[:3]), q1[:-1]])
    np.testing.assert_allclose(rows.G[rate] @ v + (50.0 * TS - rows.h[rate]), (q1 - q_prev).reshape(-1),
                               atol=2e-3 * np.abs(q1 - q_prev).max())


def test_a_predicted_pose_beyond_the_workspace_is_linearized_at_the_last_one_that_assembles(model4):
    """A long prediction may leave the workspace (found on a hand-written biglide: the planner's first
    prediction of 120 samples reached past the rods' reach and `plan` stopped with exit 2): the drive rows of
    such a pose are the first-order extension from the pose before it that assembles, or from y(k)."""
    from parallel_gpc.errors import AssemblyError
    from parallel_gpc.gpc.constraints import DriveKinematics, linearization_points

    robot = model4.robot
    p = robot.n_y
    y0 = robot.home_pose
    far = y0 + np.array([5.0, 0.0, 0.0])[:p]  # metres beyond any reach
    kin = DriveKinematics(robot)
    with pytest.raises(AssemblyError):
        kin(far)
    poses = np.array([far, y0 + 0.01, far, far, y0 - 0.01])
    points, qj = linearization_points(kin, poses, y0)
    np.testing.assert_array_equal(points, [y0, y0 + 0.01, y0 + 0.01, y0 + 0.01, y0 - 0.01])
    for (q, J), y in zip(qj, points):
        q_ref, J_ref = DriveKinematics(robot)(y)
        np.testing.assert_allclose(q, q_ref, atol=1e-10)
        np.testing.assert_allclose(J, J_ref, atol=1e-8)
    # the rows of a prediction through such poses: built (the old code raised), each the extension from its point
    H = Horizons(len(poses))
    n = 2
    pred = Prediction(poses.reshape(-1), np.zeros((len(poses) * p, n)), np.zeros(0), np.zeros((0, 0)), H,
                      "simulative")
    lim = Limits(drive_position=[-10.0, 10.0]).for_drives(robot.n_u, p)
    rows = stage_constraints(pred, lim, TS, y0, drives=DriveKinematics(robot))
    hi = np.flatnonzero(rows.kind == "drive_position")[: len(poses) * robot.n_u].reshape(len(poses), -1)
    for i, (y, (q, J)) in enumerate(zip(poses, qj)):
        np.testing.assert_allclose(10.0 - rows.h[hi[i]], q + J @ (y - points[i]), atol=1e-9)


# ---------------------------------------------------------------------------- passive joint ranges
def test_joint_rows_are_the_closure_solution_to_first_order(model4):
    """joint_position rows against the robot's own assembly (Newton on the closures) at the
    predicted poses, by finite differences: value at v = 0 and first-order change."""
    from parallel_gpc.gpc.constraints import DriveKinematics

    robot = model4.robot
    H = Horizons(6)
    X = np.concatenate([robot.home_pose, [0.05, -0.02, 0.1]])
    Ad, Bd, cd = model4.discrete(X, TS)
    pred = absolute_prediction(Ad, Bd, cd, model4.C, X, H)
    names = ("elbow_1", "elbow_3")
    lim = Limits(joint_position={n: [-10.0, 10.0] for n in names})
    rows = stage_constraints(pred, lim, TS, X[:3], drives=DriveKinematics(robot, names))
    iq = [robot.passive_joints[n][0] for n in names]

    def joints(poses):  # the oracle: full assembly of each pose, the named coordinates
        return np.array([robot.assemble(y, robot.q_home)[iq] for y in poses.reshape(-1, robot.n_y)])

    q0 = joints(pred.f)
    hi_rows = np.flatnonzero(rows.kind == "joint_position")[: q0.size]  # the upper side comes first
    np.testing.assert_allclose(10.0 - rows.h[hi_rows], q0.reshape(-1), atol=1e-9)
    v = np.random.default_rng(2).normal(size=pred.G.shape[1]) * 0.5
    dq = (joints(pred.outputs(v)) - q0).reshape(-1)
    assert np.abs(dq).max() > 1e-5
    np.testing.assert_allclose(rows.G[hi_rows] @ v, dq, atol=1e-3 * np.abs(dq).max())


def test_a_hard_joint_range_holds_in_closed_loop():
    """planar_4rrr on the S-curve: elbow_2 would reach 2.55 rad; with its range capped at 2.47 rad
    (hard) the plant's elbow stays below it (linearization error ≤ 1e-5 rad) and the platform bends
    away from the path only while the range binds."""
    from parallel_gpc.gpc.constraints import DriveKinematics
    from parallel_gpc.gpc.robot_references import reference_for
    from parallel_gpc.model import ConstrainedPlant, ParallelRobot, ReducedModel

    robot = ParallelRobot.load("planar_4rrr")
    ref = reference_for("s-curve", robot, 1.0)
    kin = DriveKinematics(robot, ("elbow_2",))
    along = np.array([kin(ref.pose(t))[0][-1] for t in np.linspace(0.0, 1.2, 61)])
    assert along.max() > 2.54 and along[0] < 2.4 and along[-1] < 2.4  # the path breaks the range, its ends do not
    Ts, N, hi = 0.004, 8, 2.47
    ctl = GPCController.build(ReducedModel(robot), Ts=Ts, horizons=Horizons(N), form="nonlinear",
                              limits=Limits(torque=1000.0, joint_position={"elbow_2": [-10.0, hi]}, soft=()))
    plant = ConstrainedPlant(robot, np.concatenate([ref.pose(0.0), np.zeros(3)]), Ts=Ts)
    X, elbow, err, active = plant.X, [], [], []
    iq = robot.passive_joints["elbow_2"][0]
    for k in range(300):
        info = ctl.step(X, ref.sample((k + 1 + np.arange(N)) * Ts))
        assert not info.fallback
        X = plant.step(info.u)
        elbow.append(plant.q[iq])
        err.append(np.linalg.norm(X[:2] - ref.pose((k + 1) * Ts)[:2]))
        active.append("joint_position" in info.constraints.active)
    elbow, err, active = np.array(elbow), np.array(err), np.array(active)
    assert active.any() and elbow.max() <= hi + 1e-5
    assert err.max() > 1e-2  # it had to leave the path
    assert err[-50:].max() < 1e-4  # and returns to it once the range is free


def test_joint_ranges_come_from_the_robot_file_and_bad_names_are_refused(tmp_path):
    from parallel_gpc.errors import RobotFormatError
    from parallel_gpc.model import ParallelRobot, ReducedModel

    robot = ParallelRobot.load("hexapod_6ups")
    with pytest.raises(InvalidParameterError, match=r"'u_c_1'.*valid joint names: \['platform_x'.*'u_a_1', 'u_b_1'"):
        GPCController.build(ReducedModel(robot), Ts=0.002, horizons=Horizons(4),
                            limits=Limits(joint_position={"u_c_1": [-1, 1]}))
    with pytest.raises(InvalidParameterError, match="'drive_1', which is a drive.*drive_position"):
        GPCController.build(ReducedModel(robot), Ts=0.002, horizons=Horizons(4),
                            limits=Limits(joint_position={"drive_1": [-1, 1]}))
    with pytest.raises(InfeasibleLimitsError, match=r"joint_position\['u_a_1'\]"):
        Limits(joint_position={"u_a_1": [1, -1]})
    # a copy of the hexapod's files with the URDF ranges and one explicit range
    src = robot.description.sidecar_path
    text = src.read_text()
    for name in ("joint_ranges = \"urdf\"\njoint_position = { u_a_1 = [-0.4, 0.4] }", "joint_position = { u_z_1 = [0, 1] }"):
        folder = tmp_path / str(len(name))
        folder.mkdir()
        for f in src.parent.glob(src.stem + ".*"):
            (folder / f.name).write_text(f.read_text())
        (folder / src.name).write_text(text.replace("[limits]", "[limits]\n" + name, 1))
        if "u_z_1" in name:
            with pytest.raises(RobotFormatError, match=r"\['u_z_1'\].*valid: \["):
                ParallelRobot.load(folder / src.name).state_limits
            continue
        limits = ParallelRobot.load(folder / src.name).state_limits
        ranges = limits.joint_position
        iq = robot.passive_joints["u_b_1"][0]
        assert ranges["u_a_1"] == (-0.4, 0.4)  # the explicit range replaces the file's
        assert ranges["u_b_1"] == (robot.model.lowerPositionLimit[iq], robot.model.upperPositionLimit[iq])
        assert "drive_1" not in ranges and not limits.is_soft("joint_position")  # the file's soft = []


# ---------------------------------------------------------------------------- terminal weight and equality
def closed_loop_plans(form, weights, steps=40, **settings):
    A, B, C = double_integrator()
    ctl = GPCController.build(DiscreteLinearModel(A, B, C, Ts=TS), Ts=TS, horizons=Horizons(12), form=form,
                              weights=weights, **settings)
    X, w, plans = np.array([0.3, -0.1, 2.0, -0.5]), np.tile([1.0, -0.6], (12, 1)), []
    for _ in range(steps):
        info = ctl.step(X, w)
        assert not info.fallback
        plans.append(ctl.plan.copy())
        X = A @ X + B @ info.u
    return np.array(plans)


@pytest.mark.parametrize("form", ["absolute", "incremental", "nonlinear"])
def test_a_terminal_weight_of_one_is_the_paper_criterion(form):
    base = closed_loop_plans(form, Weights([1.0, 2.0], 0.05))
    np.testing.assert_allclose(closed_loop_plans(form, Weights([1.0, 2.0], 0.05, Qf=1.0)), base, atol=1e-12, rtol=0)
    np.testing.assert_allclose(closed_loop_plans(form, Weights([1.0, 2.0], 0.05, Qf=[1.0, 1.0])), base, atol=1e-12,
                               rtol=0)
    assert np.abs(closed_loop_plans(form, Weights([1.0, 2.0], 0.05, Qf=5.0)) - base).max() > 1e-3  # it acts


@pytest.mark.parametrize("Qy", [[1.0, 2.0], [[2.0, 0.5], [0.5, 1.0]]])
def test_the_terminal_weight_scales_the_last_predicted_error(Qy):
    """The stacked problem against one written here: the last block's rows times diag(Qf) Qy."""
    H = Horizons(8, 2)
    X = np.array([0.3, -0.1, 2.0, -0.5])
    pred = one_step("absolute", X, None, H)
    w = np.tile([1.0, -0.6], (H.n_rows, 1))
    Qf = np.array([3.0, 0.5])
    prob = build_problem(pred, w, Weights(Qy, 0.05, Qf), 2, 2)
    Wy = np.diag(Qy) if np.ndim(Qy) == 1 else np.array(Qy)
    blocks = [Wy] * (H.n_rows - 1) + [np.diag(Qf) @ Wy]
    W = np.zeros((2 * H.n_rows, 2 * H.n_rows))
    for i, Wi in enumerate(blocks):
        W[2 * i:2 * i + 2, 2 * i:2 * i + 2] = Wi
    A = np.vstack([W @ pred.G, 0.05 * np.eye(pred.G.shape[1])])
    b = np.concatenate([W @ (w.reshape(-1) - pred.f), np.zeros(pred.G.shape[1])])
    v = np.linalg.lstsq(A, b, rcond=None)[0]
    np.testing.assert_allclose(make_solver("qr").solve(prob).v, v, atol=1e-10 * np.abs(v).max())
    with pytest.raises(InvalidParameterError, match="Qf"):
        Weights(1.0, 0.0, -1.0)
    with pytest.raises(ShapeError, match="Qf"):
        build_problem(pred, w, Weights(1.0, 0.0, [1.0, 2.0, 3.0]), 2, 2)


@pytest.mark.parametrize("form", ["absolute", "incremental"])
@pytest.mark.parametrize("terminal", ["pose", "stop"])
def test_the_terminal_equality_holds_in_the_plan_and_is_kkt_optimal(form, terminal):
    A, B, C = double_integrator()
    H = Horizons(12)
    X = np.array([0.3, -0.1, 2.0, -0.5])
    ctl = GPCController.build(DiscreteLinearModel(A, B, C, Ts=TS), Ts=TS, horizons=H, form=form,
                              weights=Weights(1.0, 0.05), terminal=terminal)
    w = np.tile([1.0, -0.6], (H.n_rows, 1))
    info = ctl.step(X, w)
    assert not info.fallback and info.result.ok
    pred = one_step(form, X, np.zeros(2), H)  # the controller's own prediction at its first step
    v = info.result.v
    y = pred.outputs(v).reshape(-1, 2)
    np.testing.assert_allclose(y[-1], w[-1], atol=1e-8)
    free = np.linalg.lstsq(np.vstack([pred.G, 0.05 * np.eye(24)]),
                           np.concatenate([w.reshape(-1) - pred.f, np.zeros(24)]), rcond=None)[0]
    assert np.abs(pred.outputs(free).reshape(-1, 2)[-1] - w[-1]).max() > 1e-2  # the equality binds
    # the oracle: the equality-constrained QP's KKT system, solved here
    P = 2 * (pred.G.T @ pred.G + 0.05 ** 2 * np.eye(24))
    q = 2 * pred.G.T @ (pred.f - w.reshape(-1))
    E, e = pred.G[-2:], w[-1] - pred.f[-2:]
    if terminal == "stop":
        np.testing.assert_allclose(y[-1] - y[-2], 0.0, atol=1e-8)
        E, e = np.vstack([E, pred.G[-2:] - pred.G[-4:-2]]), np.concatenate([e, pred.f[-4:-2] - pred.f[-2:]])
    K = np.block([[P, E.T], [E, np.zeros((len(e), len(e)))]])
    x = np.linalg.solve(K, np.concatenate([-q, e]))[:24]
    np.testing.assert_allclose(v, x, atol=1e-6 * np.abs(x).max())
    lam = np.linalg.lstsq(E.T, -(P @ v + q), rcond=None)[0]  # stationarity: P v + q + Eᵀλ = 0
    assert np.linalg.norm(P @ v + q + E.T @ lam) < 1e-6 * np.linalg.norm(q)


def test_terminal_settings_are_refused_once_where_they_enter():
    A, B, C = double_integrator()
    model = DiscreteLinearModel(A, B, C, Ts=TS)
    for kwargs, needle in ((dict(terminal="end"), r"terminal = 'end' is not one of \['pose', 'stop'\]"),
                           (dict(terminal="stop", horizons=Horizons(5, 4)), "N − No ≥ 2"),
                           (dict(terminal="pose", solver="qr"), "cannot enforce the terminal equality"),
                           (dict(terminal="pose", solver="riccati"), "cannot enforce the terminal equality"),
                           (dict(weights=Weights(1.0, 0.1, 2.0), solver="riccati"), "terminal weight Qf")):
        kwargs.setdefault("horizons", Horizons(5))
        with pytest.raises(InvalidParameterError, match=needle):
            GPCController.build(model, Ts=TS, **kwargs)


# ---------------------------------------------------------------------------- back ends with general rows
BACKENDS = ["daqp-direct", "proxqp-direct", "osqp-direct", "qpsolvers:daqp", "qpsolvers:proxqp", "qpsolvers:osqp",
            "qpsolvers:highs", "qpsolvers:clarabel"]


def constrained_problems():
    """The constrained problems of this file: hard box and velocity, the same soft, an infeasible
    box made soft (slack used), a hard box with the torque limit, a terminal equality with a soft box."""
    from parallel_gpc.gpc.constraints import terminal_rows

    out = {}
    X, u_prev = np.array([0.3, -0.1, 2.0, -0.5]), np.array([1.0, -2.0])
    box = [[-1.0, 0.45], [-0.3, 1.0]]
    for form in ("absolute", "incremental"):
        H = Horizons(12)
        pred = one_step(form, X, u_prev, H)
        w = np.tile([1.0, -0.6], (H.n_rows, 1))
        for name, lim, terminal in (
                ("hard", Limits(output_box=box, output_velocity=[1.5, 2.5], soft=()), None),
                ("soft", Limits(output_box=box, output_velocity=[1.5, 2.5]), None),
                ("soft infeasible", Limits(torque=100.0, output_box=[[-1.0, 0.25], [-1.0, 1.0]]), None),
                ("hard with torque", Limits(torque=100.0, output_box=[[-1.0, 0.45], [-1.0, 1.0]], soft=()), None),
                ("terminal", Limits(output_box=[[-1.0, 1.2], [-1.0, 1.0]]), "stop")):
            lim = lim.for_drives(2, 2)
            problem = build_problem(pred, w, Weights(1.0, 0.05), 2, 2, lim.only("torque"), u_prev)
            out[f"{form} {name}"] = constrain(problem, stage_constraints(pred, lim, TS, X[:2]), lim,
                                              terminal_rows(pred, w, terminal))
    return out


@pytest.mark.parametrize("solver", BACKENDS)
def test_every_qp_back_end_solves_the_constrained_problems_to_the_kkt_tolerance(solver):
    """Each back end's answer passes the KKT check (its status "optimal" says so) and agrees with
    DAQP's; ProxQP and OSQP polish their point on its active set when it does not pass as it is."""
    from parallel_gpc.solvers import available_solvers, kkt_residuals, KKT_TOL

    if solver not in available_solvers():
        pytest.skip(f"{solver} is not installed here")
    for name, problem in constrained_problems().items():
        res = make_solver(solver).solve(problem)
        ref = make_solver("daqp-direct").solve(problem)
        assert ref.ok, name
        assert res.ok, f"{name}: {res.status}: {res.message}"
        assert kkt_residuals(problem, res.v, None, KKT_TOL).passes(KKT_TOL), name  # multipliers estimated here
        np.testing.assert_allclose(res.v, ref.v, atol=1e-6 * max(1.0, np.abs(ref.v).max()), err_msg=name)


@pytest.mark.parametrize("form", ["absolute", "incremental"])
def test_proxqp_keeps_hard_rows_in_closed_loop_without_fallbacks(form):
    """ProxQP warm-started from its previous result once reported these feasible problems
    infeasible (a fallback every few runs); a failed warm solve is now repeated cold."""
    _, ys, infos = run(form, Limits(output_box=[[-1, 0.5], [-1, 1]], output_velocity=3.0, soft=()), "proxqp-direct")
    assert not any(i.fallback for i in infos), [i.result.message for i in infos if i.fallback][:1]
    assert ys[:, 0].max() <= 0.5 + 1e-6


# ---------------------------------------------------------------------------- drive rates in closed loop
def test_a_hard_drive_rate_limit_holds_in_closed_loop():
    """planar_4rrr on the 1 s S-curve (nonlinear form): the drives would turn at up to 3.84 rad/s;
    with |q̇_a| ≤ 70 % of the free run's peak (hard) the plant's drive rates, both the mean over
    each sample (what the rows bound) and the rate at the sample instants, stay within it to the
    linearization's error (≤ 0.1 %, ≤ 0.5 %)."""
    from parallel_gpc.gpc.robot_references import reference_for
    from parallel_gpc.model import ConstrainedPlant, ParallelRobot, ReducedModel

    robot = ParallelRobot.load("planar_4rrr")
    ref = reference_for("s-curve", robot, 1.0)
    Ts, N = 0.004, 8

    def rates(limits):
        ctl = GPCController.build(ReducedModel(robot), Ts=Ts, horizons=Horizons(N), form="nonlinear",
                                  weights=Weights(1.0, 1e-4), limits=limits)
        plant = ConstrainedPlant(robot, np.concatenate([ref.pose(0.0), np.zeros(3)]), Ts=Ts)
        X, q, now, active = plant.X, [plant.q[robot.drive_q_indices].copy()], [], 0
        for k in range(300):
            info = ctl.step(X, ref.sample((k + 1 + np.arange(N)) * Ts))
            assert not info.fallback
            X = plant.step(info.u)
            q.append(plant.q[robot.drive_q_indices].copy())
            now.append(robot.velocity_map_nocopy(plant.q)[0][robot.drive_idx] @ X[3:])  # q̇_a = T_a ẏ
            active += info.constraints is not None and "drive_rate" in info.constraints.active
        return np.abs(np.diff(q, axis=0)).max() / Ts, np.abs(np.array(now)).max(), active

    mean_free, now_free, _ = rates(Limits(torque=1000.0))
    limit = 0.7 * mean_free
    mean, now, active = rates(Limits(torque=1000.0, drive_rate=limit, soft=()))
    assert now_free > 1.3 * limit and active > 50  # the limit binds over much of the run
    assert mean <= limit * (1 + 1e-3) and now <= limit * (1 + 5e-3)


def test_terminal_settings_reach_the_controllers_through_tracking_and_flat():
    """Qf and the terminal equality enter a tracking run (CLI, sweeps) through TrackingSettings:
    flat() round-trips them, a bad terminal is one error, and the run's controller uses both
    (oracle: the controller built directly from GPCSettings with the same fields)."""
    from parallel_gpc.errors import InvalidParameterError
    from parallel_gpc.studies import TrackingSettings

    s = TrackingSettings.from_flat(robot="planar_4rrr", N=8, Qu=1e-3, Qf=3.0, terminal="pose")
    assert TrackingSettings.from_flat(**s.flat()).flat() == s.flat()
    c = s.controller_settings("absolute")
    assert c.terminal == "pose" and float(np.asarray(c.weights.Qf).ravel()[0]) == 3.0
    with pytest.raises(InvalidParameterError, match="terminal"):
        TrackingSettings(terminal="halt")
