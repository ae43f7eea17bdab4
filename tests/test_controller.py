"""Closed-loop GPC on the nonlinear constrained plant of the default robot."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from parallel_gpc.limits import Limits
from parallel_gpc import (
    ConstrainedPlant,
    ControllerState,
    GPCController,
    GPCSettings,
    Hold,
    Horizons,
    ParallelRobot,
    ReducedModel,
    SCurve,
    SimulationResult,
    Weights,
    simulate,
)
from parallel_gpc.errors import InfeasibleLimitsError, InvalidParameterError, ShapeError
from parallel_gpc.gpc.settings import stagewise_compiled

TS = 0.01
TILT = np.radians(10.0)
GRAVITY_IN_PLANE = [0.0, -9.81 * np.sin(TILT), -9.81 * np.cos(TILT)]


def _run(robot, form, reference, duration, Qu=0.0, N=20, plant_robot=None, **kw):
    ctrl = GPCController.build(ReducedModel(robot), TS, Horizons(N), Weights(1.0, Qu), form=form, **kw)
    X0 = np.concatenate([reference.pose(0.0), np.zeros(3)])
    plant = ConstrainedPlant(plant_robot or robot, X0, Ts=TS, torque_limit=kw.get("limits"))
    return simulate(ctrl, plant, reference, duration, progress=False)


@pytest.fixture(scope="module")
def s_curve_runs(robot4):
    ref = SCurve(duration=1.5)
    return {form: _run(robot4, form, ref, 1.8) for form in ("absolute", "incremental", "nonlinear")}


@pytest.mark.parametrize("form", ["absolute", "incremental", "nonlinear"])
def test_s_curve_is_tracked_with_bounded_error(s_curve_runs, form):
    m = s_curve_runs[form].metrics()
    assert m["max_position_error_m"] < 1e-3 and m["max_orientation_error_rad"] < 1e-2
    assert m["fallbacks"] == 0


@pytest.mark.parametrize("form", ["absolute", "incremental"])
def test_redundant_drives_with_qu_zero_do_not_fight(s_curve_runs, form):
    res = s_curve_runs[form]
    # component of the applied torques in null(B_r) at the plant state, relative to |u|
    rel = res.internal_force / np.maximum(np.linalg.norm(res.u, axis=1), 1e-12)
    assert np.max(rel[np.linalg.norm(res.u, axis=1) > 1e-6]) <= 1e-8


@pytest.mark.parametrize("scale", [0.8, 1.2])
def test_incremental_forms_remove_steady_state_error_under_mass_mismatch(robot4, scale):
    """Tilted plane (gravity load) and ±20 % mass mismatch: the incremental forms reach the hold
    pose; the absolute form with Qu > 0 keeps an offset (the paper's integrating character)."""
    robot = ParallelRobot(robot4.description, gravity=GRAVITY_IN_PLANE)
    plant_robot = robot.with_mass_scale(scale)
    hold = Hold((0.55, 0.5, 0.05))
    start = type(hold)(tuple(robot.home_pose))
    errs = {}
    for form, duration in (("incremental", 3.0), ("nonlinear", 2.0), ("absolute", 1.0)):
        ctrl = GPCController.build(ReducedModel(robot), TS, Horizons(20), Weights(1.0, 1e-2), form=form)
        plant = ConstrainedPlant(plant_robot, np.concatenate([start.pose(0), np.zeros(3)]), Ts=TS)
        res = simulate(ctrl, plant, hold, duration, progress=False)
        errs[form] = np.linalg.norm(res.error[-1, :2])
    assert errs["incremental"] < 1e-5 and errs["nonlinear"] < 1e-5
    assert errs["absolute"] > 1e-2


def test_torque_limits_are_never_exceeded_in_closed_loop(robot4):
    ref = SCurve(duration=0.8)
    limit = 8.0
    res = _run(robot4, "incremental", ref, 1.0, Qu=1e-3, solver="qr-first:proxqp-direct", limits=Limits(torque=limit))
    assert np.max(np.abs(res.u)) <= limit * (1 + 1e-7)
    free = _run(robot4, "incremental", ref, 1.0, Qu=1e-3)
    assert np.max(np.abs(free.u)) > 1.5 * limit  # the limit really binds
    assert res.metrics()["saturated_steps"] == 0  # the plant never had to clip


def test_result_round_trips_through_npz_and_csv(s_curve_runs, tmp_path):
    res: SimulationResult = s_curve_runs["absolute"]
    path = res.save(tmp_path / "run.npz")
    with np.load(path) as data:
        np.testing.assert_array_equal(data["u"], res.u)
        assert str(data["robot"]) == "planar_4rrr"
    csv_path = res.save(tmp_path / "run.csv")
    rows = csv_path.read_text().splitlines()
    assert len(rows) == len(res.t) + 1 and rows[0].startswith("t,ref_0")


def test_qr_solver_with_limits_is_rejected(robot4):
    # the limits as the package describes them (not the dataclass's repr) and the way out
    with pytest.raises(InvalidParameterError, match=r"cannot enforce the limits torque ±10;.*drop the limits"):
        GPCController.build(ReducedModel(robot4), TS, Horizons(5), solver="qr", limits=Limits(torque=10.0))


def _closed_loop(ctrl, robot, ref, steps):
    plant = ConstrainedPlant(robot, np.concatenate([ref.pose(0.0), np.zeros(3)]), Ts=TS)
    for k in range(steps):
        plant.step(ctrl.step(plant.X, ref.window(k * TS, TS, ctrl.horizons.N)).u)
    return plant


@pytest.mark.parametrize("form", ["absolute", "incremental", "incremental-delayed", "nonlinear"])
def test_state_snapshot_restores_bit_identical_steps(robot4, form):
    """restore(state) puts plan, u(k−1), disturbance estimate, one-step prediction and warm start
    back: the replayed step gives the same u, on a fresh controller too (to rounding: the robot
    model's assembly warm start is the model's, not the controller's, state)."""
    ref = SCurve()
    kw = dict(form=form, limits=Limits(torque=12.0), solver="daqp-direct")
    ctrl = GPCController.build(ReducedModel(robot4), TS, Horizons(10), Weights(1.0, 1e-3), **kw)
    plant = _closed_loop(ctrl, robot4, ref, 8)
    X, w = plant.X.copy(), ref.window(8 * TS, TS, 10)
    state = ctrl.state
    assert isinstance(state, ControllerState) and state.x_next is not None and state.warm_start is not None
    with pytest.raises(ValueError):  # read-only snapshot
        state.plan[0, 0] = 1.0
    u = ctrl.step(X, w).u
    ctrl.step(X + 1e-3, w)  # move on
    ctrl.restore(state)
    np.testing.assert_allclose(ctrl.step(X, w).u, u, rtol=0, atol=1e-12)
    other = GPCController.build(ReducedModel(robot4), TS, Horizons(10), Weights(1.0, 1e-3), **kw)
    other.restore(state)
    np.testing.assert_allclose(other.step(X, w).u, u, rtol=0, atol=1e-12)
    with pytest.raises(ShapeError, match="plan"):
        GPCController.build(ReducedModel(robot4), TS, Horizons(12), form=form).restore(state)


def test_settings_are_frozen_validated_and_equivalent_to_keywords(robot4):
    settings = GPCSettings(TS, Horizons(10), Weights(1.0, 1e-3), form="incremental", limits=Limits(torque=12.0))
    stagewise = "riccati" if stagewise_compiled(True) else "qr-first:daqp-direct"  # no compiled core: condensed
    assert settings.solver == stagewise and settings.solver_is_default and settings.disturbance_gain == 0.5
    with pytest.raises(dataclasses.FrozenInstanceError):
        settings.Ts = 0.02
    from_settings = GPCController(ReducedModel(robot4), settings)
    keywords = GPCController.build(ReducedModel(robot4), TS, Horizons(10), Weights(1.0, 1e-3), form="incremental",
                                   limits=Limits(torque=12.0))
    assert from_settings.settings is settings and keywords.solver == settings.solver
    ref = SCurve()
    a, b = _closed_loop(from_settings, robot4, ref, 6), _closed_loop(keywords, robot4, ref, 6)
    np.testing.assert_array_equal(a.X, b.X)
    with pytest.raises(InvalidParameterError, match="1.5"):
        GPCSettings(TS, Horizons(10), disturbance_gain=1.5)


def test_assigning_a_limit_revalidates_it(robot4):
    ctrl = GPCController.build(ReducedModel(robot4), TS, Horizons(5), limits=Limits(torque=10.0))
    ctrl.limits = Limits(torque=[5.0, 6.0, 7.0, 8.0])
    np.testing.assert_array_equal(ctrl.limits.torque, [5.0, 6.0, 7.0, 8.0])
    assert ctrl.settings.limits.torque.tolist() == [5.0, 6.0, 7.0, 8.0]
    with pytest.raises(InfeasibleLimitsError, match="-1.0"):
        ctrl.limits = Limits(torque=-1.0)
    with pytest.raises(ShapeError, match="(3,)"):
        ctrl.limits = Limits(torque=[1.0, 2.0, 3.0])
    with pytest.raises(InvalidParameterError, match="absolute"):
        ctrl.limits = Limits(torque=5.0, du=1.0)
    np.testing.assert_array_equal(ctrl.limits.torque, [5.0, 6.0, 7.0, 8.0])  # unchanged by the failures


@pytest.mark.parametrize("native", [False, None])
def test_condition_number_matches_numpy_and_refuses_non_finite_gains(native):
    """The conditioning check's σ_max/σ_min (the reference: LAPACK gesdd called directly; None:
    compiled when built) against numpy's 2-norm condition number; NaN, inf, singular and empty gains
    count as infinitely ill-conditioned."""
    import math

    from parallel_gpc.gpc.protocol import condition_number

    rng = np.random.default_rng(7)
    for shape in ((3, 4), (6, 8), (4, 4), (5, 3)):
        g = rng.standard_normal(shape) * 10.0 ** rng.uniform(-3, 3)
        assert condition_number(g, native=native) == pytest.approx(np.linalg.cond(g), rel=1e-10)
    assert condition_number(np.diag([2.0, 1e-3]), native=native) == pytest.approx(2e3, rel=1e-12)
    near = np.diag([1.0, 1e-6]) @ np.random.default_rng(1).standard_normal((2, 3))  # rank 2, barely
    assert condition_number(near, native=native) == pytest.approx(np.linalg.cond(near), rel=1e-6)
    for bad in (np.array([[1.0, np.nan], [0.0, 1.0]]), np.array([[1.0, np.inf], [0.0, 1.0]]),
                np.array([[1.0, 2.0], [2.0, 4.0]]) * 0.0, np.zeros((0, 3))):
        assert condition_number(bad, native=native) == math.inf
