"""The one limits type (parallel_gpc.limits.Limits): validated once where it is built, taken whole by
the controller, the planner, the tracking study, the plant and the result writer; the nonlinear
form's Δu limit measured from u(k−1); unconstrained back ends refuse limits; Ts owned once."""

from __future__ import annotations

import numpy as np
import pytest
import qpsolvers

from parallel_gpc import (ConstrainedPlant, GPCController, GPCSettings, Hold, Horizons, Limits, PlanSettings,
                          ReducedModel, ReducedPlant, SCurve, TrackingSettings, Weights, build_problem, make_solver,
                          simulate)
from parallel_gpc.errors import InfeasibleLimitsError, InvalidParameterError, ParallelGPCError, ShapeError
from parallel_gpc.results import saturation_flags
from parallel_gpc.solvers import QRFirst, QRSolver, DAQPBackend
from parallel_gpc.studies.tracking import run_tracking

TS = 0.01


# ---------------------------------------------------------------------------- the type
@pytest.mark.parametrize("value, error, needle", [
    (-5.0, InfeasibleLimitsError, "-5.0"),
    (0.0, InfeasibleLimitsError, "0.0"),
    ([1.0, float("nan")], InfeasibleLimitsError, "nan"),
    ([1.0, float("inf")], InfeasibleLimitsError, "inf"),
    ([[1.0, 2.0]], ShapeError, "(1, 2)"),
    ([], ShapeError, "(0,)"),
    ("abc", InvalidParameterError, "'abc'"),
    (True, InvalidParameterError, "True"),
    ([1.0, "a"], InvalidParameterError, "'a'"),
])
@pytest.mark.parametrize("kind", ["torque", "du"])
def test_a_bad_limit_is_refused_when_built_naming_it(kind, value, error, needle):
    with pytest.raises(error) as info:
        Limits(**{kind: value})
    assert isinstance(info.value, ParallelGPCError) and needle in str(info.value) and kind in str(info.value)


def test_limits_are_frozen_read_only_and_sized_once():
    lim = Limits(torque=60.0, du=[1.0, 2.0, 3.0])
    assert lim.torque.shape == () and lim.n_drives == 3 and lim.has_input_limits and not lim.is_empty
    sized = lim.for_drives(3)
    np.testing.assert_array_equal(sized.torque, [60.0, 60.0, 60.0])
    np.testing.assert_array_equal(sized.du, [1.0, 2.0, 3.0])
    assert sized.for_drives(3) is sized  # already sized: nothing redone
    with pytest.raises(ValueError):
        sized.torque[0] = 1.0  # read-only
    with pytest.raises(AttributeError):
        sized.torque = None  # frozen
    with pytest.raises(ShapeError, match=r"\(4,\)"):
        lim.for_drives(4)
    with pytest.raises(ShapeError, match="different lengths"):
        Limits(torque=[1.0, 2.0], du=[1.0, 2.0, 3.0])
    assert Limits() == Limits.none() and Limits().is_empty and not Limits().has_input_limits
    assert Limits(torque=2.0) == Limits(torque=2.0) and Limits(torque=2.0) != Limits(torque=[2.0])
    assert Limits(torque=2.0).to_dict() == {"torque": 2.0, "du": None}
    np.testing.assert_array_equal(Limits(torque=4.0).scaled(0.5).torque, 2.0)


def test_the_kind_table_sizes_each_kind_by_what_it_is_for():
    """The kinds' groups (written out here, not read from the table) and the sizing they imply:
    per-drive kinds by n_u, per-output kinds by n_y, named joint ranges never; the kinematic kinds
    are the ones the constraint rows compute through the robot's kinematics."""
    from parallel_gpc import limits

    assert limits.INPUT_KINDS == ("torque", "du")
    assert limits.STATE_KINDS == ("drive_position", "drive_rate", "output_box", "output_velocity", "joint_position")
    assert limits.KINEMATIC_KINDS == ("drive_position", "drive_rate", "joint_position")
    lim = Limits(drive_rate=[1.0, 2.0], output_velocity=0.5, output_box=[-1.0, 1.0],
                 joint_position={"b": (-1.0, 1.0), "a": (0.0, 2.0)})
    assert lim.n_drives == 2 and lim.has_kinematic_limits and not Limits(output_velocity=0.5).has_kinematic_limits
    sized = lim.for_drives(2, 3)
    assert sized.output_velocity.shape == (3,) and sized.output_box.shape == (3, 2) and sized.drive_rate.shape == (2,)
    assert dict(sized.joint_position) == {"a": (0.0, 2.0), "b": (-1.0, 1.0)}
    assert "joint_position a [0, 2]; b [-1, 1] (soft)" in sized.describe()
    assert sized == lim.for_drives(2, 3) and hash(sized) == hash(lim.for_drives(2, 3))
    with pytest.raises(ShapeError, match="per-output limits of different lengths"):
        Limits(output_velocity=[1.0, 2.0], output_box=[[0.0, 1.0]] * 3)

def test_every_place_takes_a_limits_not_a_bare_number(robot4):
    with pytest.raises(InvalidParameterError, match="Limits"):
        GPCSettings(TS, Horizons(5), limits=60.0)
    with pytest.raises(InvalidParameterError, match="Limits"):
        PlanSettings(limits=60.0)
    with pytest.raises(InvalidParameterError, match="Limits"):
        TrackingSettings(limits=60.0)
    with pytest.raises(InvalidParameterError, match="Limits"):
        saturation_flags(np.zeros((2, 4)), 60.0)
    with pytest.raises(ShapeError, match=r"\(4,\)"):  # per-drive limits checked against the drives once
        GPCController.build(ReducedModel(robot4), TS, Horizons(5), limits=Limits(torque=[1.0, 2.0, 3.0]))


# ---------------------------------------------------------------------------- the plant
@pytest.mark.parametrize("Plant", [ConstrainedPlant, ReducedPlant])
def test_a_negative_plant_limit_is_refused(robot4, Plant):
    X0 = np.concatenate([robot4.home_pose, np.zeros(3)])
    with pytest.raises(InfeasibleLimitsError, match="-5.0"):
        Plant(robot4, X0, Ts=TS, torque_limit=-5.0)
    with pytest.raises(InvalidParameterError, match="du"):  # a plant saturates torques only
        Plant(robot4, X0, Ts=TS, torque_limit=Limits(torque=5.0, du=1.0))
    plant = Plant(robot4, X0, Ts=TS, torque_limit=Limits(torque=5.0))
    np.testing.assert_array_equal(plant.torque_limit, [5.0] * 4)
    plant.step([1.0, 0.0, 0.0, 0.0])  # inside the limit: not clipped
    assert plant.saturated == 0
    plant.step([50.0, 0.0, 0.0, 0.0])
    assert plant.saturated == 1


def test_a_negative_plant_limit_in_the_tracking_settings_is_refused():
    with pytest.raises(InfeasibleLimitsError, match="-5.0"):
        run_tracking(TrackingSettings(plant_torque_limit=-5.0, duration=0.01))
    with pytest.raises(InvalidParameterError, match="nowhere"):
        TrackingSettings(plant_torque_limit="nowhere")


# ---------------------------------------------------------------------------- tracking settings
@pytest.mark.parametrize("build, needle", [
    (lambda: TrackingSettings(Ts=-1), "-1"),
    (lambda: TrackingSettings.from_flat(N=0), "N = 0"),
    (lambda: TrackingSettings.from_flat(Qu="abc"), "'abc'"),
    (lambda: TrackingSettings.from_flat(torque_limit=-2.0), "-2.0"),
    (lambda: TrackingSettings(horizons=20), "Horizons"),
    (lambda: TrackingSettings(weights=(1.0, 0.0)), "Weights"),
    (lambda: TrackingSettings(duration=0.0), "duration"),
    (lambda: TrackingSettings(mass_scale=-1.0), "mass_scale"),
    (lambda: TrackingSettings(noise_std=-1e-3), "noise_std"),
    (lambda: TrackingSettings(disturbance_gain=2.0), "disturbance_gain"),
    (lambda: TrackingSettings(reference="zigzag"), "zigzag"),
    (lambda: TrackingSettings(seed=-1), "seed"),
    (lambda: TrackingSettings(platform_force=(0.0, float("nan"), 0.0)), "platform_force"),
    (lambda: TrackingSettings(solver=3), "solver"),
])
def test_tracking_settings_are_validated_when_built(build, needle):
    with pytest.raises(InvalidParameterError) as info:
        build()
    assert needle in str(info.value)


def test_flat_keywords_round_trip():
    s = TrackingSettings.from_flat(N=8, No=1, Qy=2.0, Qu=1e-3, torque_limit=30.0, du_limit=1.0, Ts=0.005)
    assert s.horizons == Horizons(8, 1) and s.weights == Weights(2.0, 1e-3)
    assert s.limits == Limits(torque=30.0, du=1.0) and s.Ts == 0.005
    assert TrackingSettings.from_flat(**s.flat()).flat() == s.flat()
    with pytest.raises(TypeError):
        TrackingSettings.from_flat(bogus=1)


def test_flat_keywords_carry_every_limit_field():
    """Every Limits field (input and state kinds, joint ranges, soft kinds, penalty) survives
    flat() → from_flat(), and each flat keyword reaches its own field."""
    from parallel_gpc.limits import KINDS

    full = Limits(torque=[30.0, 40.0, 50.0], drive_position=[[-1.0, 1.0], [-2.0, 2.0], [-3.0, np.inf]],
                  drive_rate=2.0, output_box=[[-0.1, 0.2], [-0.3, 0.4], [-np.inf, 1.0]], output_velocity=[0.5, 0.6, 3.0],
                  joint_position={"elbow_2": [-10.0, 2.47]}, soft=("output_box", "joint_position"), penalty=250.0)
    assert set(full.values()) == set(KINDS) - {"du"}  # every kind set (du: incremental forms)
    s = TrackingSettings(limits=full, Ts=0.004)
    back = TrackingSettings.from_flat(**s.flat())
    assert back.limits == full and back.limits.soft == full.soft and back.limits.penalty == 250.0
    assert back.flat() == s.flat()
    du = TrackingSettings(limits=Limits(du=1.0, soft=()))
    assert TrackingSettings.from_flat(**du.flat()).limits == du.limits
    one = TrackingSettings.from_flat(output_velocity=0.5, limit_penalty=10.0, soft_limits=[])
    assert one.limits == Limits(output_velocity=0.5, penalty=10.0, soft=())
    assert TrackingSettings().flat()["soft_limits"] == sorted(Limits().soft)  # the default: every state kind soft


def test_a_du_limit_with_the_absolute_form_is_refused_before_any_run():
    with pytest.raises(InvalidParameterError, match="incremental forms"):
        run_tracking(TrackingSettings.from_flat(du_limit=1.0, duration=0.01), forms=("nonlinear", "absolute"))


# ---------------------------------------------------------------------------- Ts owned once
def test_the_plant_sample_time_must_equal_the_controllers(robot4):
    ctl = GPCController.build(ReducedModel(robot4), TS, Horizons(5))
    plant = ConstrainedPlant(robot4, np.concatenate([robot4.home_pose, np.zeros(3)]), Ts=2 * TS)
    with pytest.raises(InvalidParameterError, match="sample time"):
        simulate(ctl, plant, Hold(tuple(robot4.home_pose)), 0.05, progress=False)
    with pytest.raises(TypeError):
        plant.step(np.zeros(4), TS)  # the sample time is the plant's own


# ---------------------------------------------------------------------------- unconstrained back ends
def test_qr_and_cholesky_refuse_limits(robot4):
    ctl = GPCController.build(ReducedModel(robot4), TS, Horizons(5), Weights(1.0, 1e-3))
    X = np.concatenate([robot4.home_pose, np.zeros(3)])
    pred = ctl.predict(X)
    w = np.tile(robot4.home_pose + [0.02, 0.0, 0.0], (5, 1))
    limited = build_problem(pred, w, ctl.weights, 3, 4, Limits(torque=1e-3))
    free = build_problem(pred, w, ctl.weights, 3, 4)
    for name in ("qr", "cholesky"):
        with pytest.raises(InvalidParameterError, match=name):
            make_solver(name).solve(limited)
        assert make_solver(name).solve(free).ok
    first = QRFirst(DAQPBackend()).solve(limited)  # QR-first still tries QR, then the QP
    assert first.ok and first.status == "optimal" and np.max(np.abs(first.v)) <= 1e-3 * (1 + 1e-9)
    np.testing.assert_allclose(QRSolver().solve_unconstrained(limited).v, QRSolver().solve(free).v, rtol=0, atol=0)


# ---------------------------------------------------------------------------- nonlinear form, Δu from u(k−1)
def _nonlinear_loop(robot4, delta, steps, Qu=1e-3):
    ref = SCurve(duration=0.6)
    ctl = GPCController.build(ReducedModel(robot4), TS, Horizons(10), Weights(1.0, Qu), form="nonlinear",
                              limits=None if delta is None else Limits(du=delta), disturbance_gain=0.0)
    plant = ConstrainedPlant(robot4, ref.initial_state(), Ts=TS)
    infos = []
    for k in range(steps):
        info = ctl.step(plant.X, ref.window(k * TS, TS, 10))
        infos.append(info)
        plant.step(info.u)
    return ctl, plant, ref, infos


def test_nonlinear_du_limit_binds_without_fallbacks(robot4):
    """The increment limit is on u(k+i) − u(k+i−1) itself (u(k−1) the input applied last), as in the
    incremental forms: no solution breaks it, so no step falls back, and it binds."""
    delta = 0.05
    _, _, _, free = _nonlinear_loop(robot4, None, 40)
    u_free = np.array([i.u for i in free])
    assert np.max(np.abs(np.diff(u_free, axis=0, prepend=0.0))) > 5 * delta  # the limit will bind
    _, _, _, infos = _nonlinear_loop(robot4, delta, 40)
    u = np.array([i.u for i in infos])
    du = np.abs(np.diff(u, axis=0, prepend=0.0))  # u(−1) = 0
    assert not any(i.fallback for i in infos), [i.result.message for i in infos if i.fallback]
    assert np.all(du <= delta * (1 + 1e-9))
    assert np.sum(du >= delta * (1 - 1e-5)) > 10  # binding on many samples


def test_nonlinear_du_limit_plan_equals_an_independent_qp(robot4):
    """One step mid-run (the pre-simulated inputs move by themselves there): the controller's plan
    equals the QP written in absolute inputs u, with |u(i) − u(i−1)| ≤ δ and u(−1) = u(k−1),
    solved by ProxQP through qpsolvers."""
    delta, m, N, Qu = 0.05, 4, 10, 1e-3
    ctl, plant, ref, _ = _nonlinear_loop(robot4, delta, 6, Qu)
    X, w = plant.X, ref.window(6 * TS, TS, N)
    state = ctl.state
    pred = ctl.predict(X)
    ctl.restore(state)
    info = ctl.step(X, w)
    assert info.result.ok and not info.fallback
    u_sim = pred.u_base.reshape(N, m)
    drift = np.diff(np.vstack([state.u_prev, u_sim]), axis=0)
    assert np.max(np.abs(drift)) > 1e-3  # the pre-simulated inputs do move: the old box would differ
    # u = u_sim + M v, v = D (u − u_sim): D the block differences
    n = N * m
    D = np.eye(n) - np.eye(n, k=-m)
    d_tight = delta * (1 - 1e-6)  # the controller's QP limit (LIMIT_MARGIN)
    Gu = pred.G @ D  # ŷ = f + G D (u − u_sim)
    rows = np.vstack([Gu, Qu * D])
    rhs = np.concatenate([w.reshape(-1) - pred.f + Gu @ u_sim.reshape(-1), Qu * D @ u_sim.reshape(-1)])
    P, q = rows.T @ rows, -rows.T @ rhs
    lo = np.concatenate([state.u_prev - d_tight, np.full(n - m, -d_tight)])
    hi = np.concatenate([state.u_prev + d_tight, np.full(n - m, d_tight)])
    Dabs = np.eye(n) - np.eye(n, k=-m)  # u(i) − u(i−1), with u(−1) moved to the bounds
    G_ineq, h_ineq = np.vstack([Dabs, -Dabs]), np.concatenate([hi, -lo])
    u_qp = qpsolvers.solve_qp(P, q, G_ineq, h_ineq, solver="proxqp", eps_abs=1e-12, eps_rel=0, max_iter=10000)
    assert u_qp is not None
    active = np.sum(np.abs(Dabs @ u_qp - np.where(Dabs @ u_qp > 0, hi, lo)) < 1e-9)
    assert active > 0  # the limit binds at this step
    np.testing.assert_allclose(ctl.plan.reshape(-1), u_qp, rtol=0, atol=1e-7)


def test_describe_keeps_the_order_of_different_ranges():
    """`track --output-box -0.2 0.2 -0.2 0.2 -1 1` on a 3-PRR printed "output_box [-1, 1]; [-0.2, 0.2]"
    (the distinct ranges sorted, as if x were within ±1 m); different values are listed in output
    or drive order, one shared value once."""
    lim = Limits(output_box=[[-0.2, 0.2], [-0.2, 0.2], [-1.0, 1.0]], torque=[50.0, 20.0, 50.0],
                 drive_position=[[-0.15, 0.15]] * 3)
    text = lim.describe()
    assert "output_box [-0.2, 0.2]; [-0.2, 0.2]; [-1, 1] (soft)" in text
    assert "torque ±50/20/50" in text and "drive_position [-0.15, 0.15] (soft)" in text
    assert "torque ±3," in Limits(torque=[3.0, 3.0], du=0.5).describe()
