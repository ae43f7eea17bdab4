"""Encoder-only closed loops: sensors, the Kalman filter and the machine loop runner.

Oracle: the same controller on the same simulated plant fed the true state (full sensors, the
controller's own disturbance estimate); the encoder-only loop (quantized drive readings →
forward kinematics → Kalman filter of [y, ẏ, d]) must track nearly as well. 1 s of the S-curve
(its accelerating half) at Ts = 2 ms, N = 20, Qu = 1e-4.
"""

from __future__ import annotations

import numpy as np
import pytest

from parallel_gpc import ConstrainedPlant, GPCController, Horizons, ParallelRobot, ReducedModel, Weights
from parallel_gpc.errors import InvalidParameterError, SensorError, ShapeError
from parallel_gpc.estimation import Measurement, Sensors, SensedPlant, StateEstimator
from parallel_gpc.gpc.references import path_for
from parallel_gpc.model.native import native_module, native_status
from parallel_gpc.studies.loop import run_loop

TS = 0.002
FORMS = ("absolute", "incremental", "incremental-delayed", "nonlinear")


def loop(robot, form, sensors, duration=1.0, computation_delay=False, plant=None):
    kind = "s-curve" if robot.name.startswith("planar") else "helix"
    ref = path_for(kind, robot.home_pose, robot.output_angular, 2.0)
    X0 = np.concatenate([ref.pose(0.0), np.zeros(robot.n_y)])
    encoders = sensors.kind == "encoders"
    ctrl = GPCController.build(ReducedModel(robot), TS, Horizons(20), Weights(1.0, 1e-4), form=form,
                         disturbance_gain=0.0 if encoders else None)
    plant = plant or SensedPlant(ConstrainedPlant(robot, X0, Ts=TS), sensors)
    est = StateEstimator(ReducedModel(robot), TS, sensors, X0) if encoders else None
    return run_loop(ctrl, plant, ref, duration, estimator=est, computation_delay=computation_delay)


_FULL = {}


def full_state_rms(robot, form, duration=1.0):
    key = (robot.name, form, duration)
    if key not in _FULL:
        _FULL[key] = loop(robot, form, Sensors("full"), duration).metrics()["rms_position_error_m"]
    return _FULL[key]


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("counts, factor", [(2**20, 1.5), (2**16, 3.0)])
def test_encoder_loop_tracks_like_the_full_state_loop(robot4, form, counts, factor):
    res = loop(robot4, form, Sensors("encoders", counts_per_rev=counts))
    m = res.metrics()
    assert m["rms_position_error_m"] <= factor * full_state_rms(robot4, form)
    assert m["fallbacks"] == 0
    # the estimate itself: within a few counts' worth of platform motion (0.3 m legs)
    assert m["rms_estimate_position_error_m"] < 200 * 2 * np.pi / counts * 0.3


@pytest.mark.parametrize("name", ["delta_3rus", "hexapod_6ups"])
@pytest.mark.parametrize("form", ["absolute", "nonlinear"])
def test_encoder_loop_on_spatial_robots(name, form):
    robot = ParallelRobot.load(name)
    res = loop(robot, form, Sensors("encoders"), duration=0.6)
    assert res.metrics()["rms_position_error_m"] <= 1.5 * full_state_rms(robot, form, 0.6)


#: counts per metre on hexapod_6ups's prismatic legs comparable to 2^16 counts per revolution on
#: planar_4rrr's 0.3 m links: 2π · 0.3 m / 2^16 ≈ 28.8 µm at the platform, 1 / 3.5e4 m ≈ 28.6 µm
COUNTS_PER_M_LIKE_2_16 = 3.5e4


@pytest.mark.parametrize("form", ["absolute", "nonlinear"])
def test_coarse_linear_scales_on_the_hexapod(form):
    """The 2^16-count case for prismatic drives: 28.6 µm counts keep the encoder-only loop
    within 3x the full-state RMS error (the spec string gives the same sensors)."""
    robot = ParallelRobot.load("hexapod_6ups")
    sensors = Sensors.parse(f"encoders:m={COUNTS_PER_M_LIKE_2_16:g}")
    assert sensors == Sensors("encoders", counts_per_m=COUNTS_PER_M_LIKE_2_16)
    np.testing.assert_allclose(sensors.resolution(robot), 1 / COUNTS_PER_M_LIKE_2_16)
    m = loop(robot, form, sensors, duration=0.6).metrics()
    assert m["rms_position_error_m"] <= 3.0 * full_state_rms(robot, form, 0.6)
    assert m["fallbacks"] == 0


def test_computation_delay_is_compensated(robot4):
    """u(k) applied one sample late, computed from x̂(k+1|k): tracks as well as without the delay."""
    delayed = loop(robot4, "incremental", Sensors("encoders"), computation_delay=True)
    assert delayed.meta["computation_delay"]
    assert delayed.metrics()["rms_position_error_m"] <= 1.2 * full_state_rms(robot4, "incremental")


def test_deadline_overruns_are_the_steps_longer_than_ts(robot4):
    res = loop(robot4, "absolute", Sensors("encoders"), duration=0.05)
    assert res.overruns == int(np.sum(res.step_time > TS)) == res.metrics()["deadline_overruns"]


def test_quantized_readings_are_multiples_of_the_resolution(robot4):
    sensors = Sensors("encoders", counts_per_rev=4096, rates=True)
    X0 = np.concatenate([robot4.home_pose + 0.01, np.zeros(3)])
    plant = SensedPlant(ConstrainedPlant(robot4, X0, Ts=TS), sensors)
    m = plant.measure()
    counts = m.drives / (2 * np.pi / 4096)
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    assert np.max(np.abs(m.drives - robot4.assemble(X0[:3])[robot4.drive_q_indices])) <= np.pi / 4096 + 1e-12
    assert m.rates.shape == (4,)


def test_one_sample_sensor_delay(robot4):
    X0 = np.concatenate([robot4.home_pose, np.zeros(3)])
    plant = SensedPlant(ConstrainedPlant(robot4, X0, Ts=TS), Sensors("encoders", delay=1))
    first = plant.measure()
    plant.apply(np.full(4, 5.0))
    np.testing.assert_array_equal(plant.measure().drives, first.drives)  # the reading of one sample ago


class _WrongShapePlant:
    """A foreign plant whose measure() returns three drive readings for four drives."""

    def __init__(self, robot):
        self.robot, self.Ts, self.applied = robot, TS, 0
        self.sensors = Sensors("encoders")

    def measure(self):
        return Measurement(drives=np.zeros(3))

    def apply(self, u):
        self.applied += 1


def test_a_plant_returning_the_wrong_shape_is_refused_at_the_first_step(robot4):
    plant = _WrongShapePlant(robot4)
    with pytest.raises(ShapeError, match=r"drives of shape \(3,\); expected \(4,\)"):
        loop(robot4, "absolute", Sensors("encoders"), duration=0.01, plant=plant)
    assert plant.applied == 0


def test_a_nan_reading_names_the_drive(robot4):
    X0 = np.concatenate([robot4.home_pose, np.zeros(3)])
    est = StateEstimator(ReducedModel(robot4), TS, Sensors("encoders"), X0)
    drives = robot4.inverse_kinematics(robot4.home_pose)
    drives[3] = np.nan
    with pytest.raises(SensorError, match=r"drive 3 \('drive_4'\) reads nan"):
        est.update(Measurement(drives=drives))


def test_two_disturbance_estimators_are_refused(robot4):
    ref = path_for("s-curve", robot4.home_pose, robot4.output_angular, 2.0)
    X0 = np.concatenate([ref.pose(0.0), np.zeros(3)])
    sensors = Sensors("encoders")
    ctrl = GPCController.build(ReducedModel(robot4), TS, Horizons(20), Weights(1.0, 1e-4), form="incremental")
    with pytest.raises(InvalidParameterError, match="disturbance_gain=0"):
        run_loop(ctrl, SensedPlant(ConstrainedPlant(robot4, X0, Ts=TS), sensors), ref, 0.01,
                 estimator=StateEstimator(ReducedModel(robot4), TS, sensors, X0))


@pytest.mark.parametrize("spec, kind, counts, per_m", [
    ("full", "full", None, None), ("encoders", "encoders", None, None), ("encoders:65536", "encoders", 65536.0, None),
    ("encoders:2^16", "encoders", 65536.0, None), ("encoders:rev=4096", "encoders", 4096.0, None),
    ("encoders:m=1e5", "encoders", None, 1e5), ("encoders: 2^20 , m=3.5e4", "encoders", 2.0**20, 3.5e4)])
def test_sensor_specs(spec, kind, counts, per_m):
    s = Sensors.parse(spec)
    assert (s.kind, s.counts_per_rev, s.counts_per_m) == (kind, counts, per_m)


@pytest.mark.parametrize("spec", ["pose", "encoders:abc", "encoders:-5", "full:12", "encoders:m=0", "encoders:=5",
                                  "encoders:m=1,m=2", "encoders:2^16,4096", "encoders:mm=3", "encoders:2^9999"])
def test_bad_sensor_specs(spec):
    with pytest.raises(InvalidParameterError):
        Sensors.parse(spec)


@pytest.mark.parametrize("Ts", [0.002, 0.01])
@pytest.mark.parametrize("bandwidth", [2.5, 10.0])
def test_the_disturbance_estimate_has_the_stated_bandwidth(robot4, Ts, bandwidth):
    """Oracle: the steady-state Kalman filter of the estimator's own F, Q, H and R at rest
    (scipy's discrete Riccati solver): its slowest pole is e^{−ω_d Ts}, at any Ts."""
    from scipy.linalg import solve_discrete_are

    X0 = np.concatenate([robot4.home_pose, np.zeros(3)])
    est = StateEstimator(ReducedModel(robot4), Ts, Sensors("encoders"), X0, disturbance_bandwidth=bandwidth)
    Ad = est.model.discrete(X0, Ts)[0]
    F = np.eye(9)  # z = [y, ẏ, d]: [[A_d, [0; I]], [0, I]]
    F[:6, :6] = Ad
    F[3:6, 6:] = np.eye(3)
    sol = robot4.forward_solution(robot4.inverse_kinematics(robot4.home_pose))
    Jw = sol.jacobian / Sensors("encoders").reading_std(robot4)[:, None]
    R = np.linalg.inv(Jw.T @ Jw)
    H = np.hstack([np.eye(3), np.zeros((3, 6))])
    P = solve_discrete_are(F.T, H.T, est.Q, R)
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    slowest = np.max(np.abs(np.linalg.eigvals((np.eye(9) - K @ H) @ F)))
    assert -np.log(slowest) / Ts == pytest.approx(bandwidth, rel=0.05)
    assert est.disturbance_std == pytest.approx(bandwidth * Ts**2 * 2.0)


def test_encoder_loop_rejects_the_demos_load_at_ts_10_ms():
    """``parallel-gpc demo``'s plant (mass × 1.2, a steady platform load, Ts = 10 ms, N = 30,
    Qu = 1e-3): the encoder-only loop ends within a few counts' worth of platform motion of the
    reference (2^20 counts on 0.3 m links: 1.8 µm a count), not ~1 mm off as with the earlier
    fixed disturbance random walk (a 10 s time constant at this Ts)."""
    from parallel_gpc.cli.defaults import DEMO
    from parallel_gpc.studies import TrackingSettings, run_tracking
    from parallel_gpc.studies.comparison import steady_state_error

    settings = TrackingSettings.from_flat(robot="planar_4rrr", Ts=DEMO["Ts"], N=DEMO["N"], Qu=DEMO["Qu"],
                                          mass_scale=DEMO["mass_scale"], platform_force=DEMO["platform_force"],
                                          duration=DEMO["duration"], sensors="encoders")
    res = run_tracking(settings, ["incremental"], progress=False)["incremental"]
    count_at_platform = 2 * np.pi / 2**20 * 0.3
    assert steady_state_error(res) < 5 * count_at_platform


@pytest.mark.parametrize("native", [False, True])
@pytest.mark.parametrize("rates", [False, True])
def test_one_update_is_the_textbook_kalman_correction(robot4, rates, native):
    """Oracle: the correction written out with the full matrices, H = [I 0 0] (and [0 I 0] for ẏ
    from the drive rates), R the measured pose's (and rate's) covariance (Jᵀ Σ⁻¹ J)⁻¹, K = P Hᵀ
    (H P Hᵀ + R)⁻¹ by an explicit inverse, P⁺ = (I − K H) P (I − K H)ᵀ + K R Kᵀ; after some samples
    of motion so that P is full, not the initial diagonal. The NumPy correction (a Python model)
    and the compiled one (native/src/kalman.cpp, with the compiled model update)."""
    if native and not hasattr(native_module(), "kalman_correct"):
        pytest.skip(f"no compiled Kalman correction: {native_status()}")
    sensors = Sensors("encoders", rates=rates, noise_counts=0.5)
    X0 = np.concatenate([robot4.home_pose, np.zeros(3)])
    est = StateEstimator(ReducedModel(robot4, native=native), TS, sensors, X0)
    res = sensors.resolution(robot4)
    y = robot4.home_pose
    for k in range(5):
        y = y + np.array([2e-4, -1e-4, 3e-4])
        drives = np.round(robot4.inverse_kinematics(y) / res) * res
        measurement = Measurement(drives=drives, rates=np.full(4, 0.01 * k) if rates else None)
        est.predict(np.array([0.1, -0.2, 0.05, 0.3]))
        z, P = est.z.copy(), est.P.copy()
        est.update(measurement)
    sol = robot4.forward_solution(drives, est.q, res)
    Jw = sol.jacobian / sensors.reading_std(robot4)[:, None]
    R, measured = np.linalg.inv(Jw.T @ Jw), sol.pose
    H = np.hstack([np.eye(3), np.zeros((3, 6))])
    if rates:
        std = np.full(4, sensors.rate_noise)
        Jr = sol.jacobian / std[:, None]
        R = np.block([[R, np.zeros((3, 3))], [np.zeros((3, 3)), np.linalg.inv(Jr.T @ Jr)]])
        ydot = np.linalg.lstsq(Jr, measurement.rates / std, rcond=None)[0]
        measured = np.concatenate([measured, ydot])
        H = np.vstack([H, np.hstack([np.zeros((3, 3)), np.eye(3), np.zeros((3, 3))])])
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    IKH = np.eye(9) - K @ H
    np.testing.assert_allclose(est.z, z + K @ (measured - H @ z), rtol=0, atol=1e-12)
    P_new = IKH @ P @ IKH.T + K @ R @ K.T
    np.testing.assert_allclose(est.P, P_new, rtol=1e-9, atol=1e-9 * np.abs(P_new).max())
    assert np.all(np.linalg.eigvalsh(0.5 * (est.P + est.P.T)) > 0)
