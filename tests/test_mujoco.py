"""MuJoCo as an independent plant: the exported MJCF's dynamics against the reduced model, and
closed loops on MuJoCo against the same loops on our own constrained plant."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from parallel_gpc import ConstrainedPlant, GPCController, Horizons, Limits, ParallelRobot, ReducedModel, Weights
from parallel_gpc.errors import InvalidParameterError
from parallel_gpc.estimation import Sensors, SensedPlant, StateEstimator
from parallel_gpc.gpc.references import path_for
from parallel_gpc.studies.loop import run_loop

mujoco = pytest.importorskip("mujoco")
from parallel_gpc.estimation.mujoco_plant import INSTALL_HINT, MujocoPlant  # noqa: E402
from parallel_gpc.model.mjcf_export import export_mjcf  # noqa: E402

TS = 0.002


@pytest.mark.parametrize("name", ["planar_4rrr", "delta_3rus", "hexapod_6ups"])
def test_exported_accelerations_match_the_reduced_model(name):
    """MuJoCo's constrained q̈ (soft loops, solimp 0.9999) vs ÿ = M_r⁻¹ (B_r u − h_r): relative ≤ 1e-3."""
    robot = ParallelRobot.load(name)
    model = ReducedModel(robot)
    rng = np.random.default_rng(3)
    scale = 20.0 if name.startswith("hexapod") else 1.0  # N on the legs vs N·m on the cranks
    plant = MujocoPlant(robot, TS, np.concatenate([robot.home_pose, np.zeros(robot.n_y)]))
    for _ in range(5):
        y = robot.home_pose + rng.uniform(-1, 1, robot.n_y) * np.where(robot.output_angular, 0.05, 0.02)
        X = np.concatenate([y, rng.uniform(-0.3, 0.3, robot.n_y)])
        u = rng.uniform(-3, 3, robot.n_u) * scale
        q = robot.assemble(y)
        v = robot.velocity_map(q)[0] @ X[robot.n_y:]
        ydd_mujoco = robot.output_jacobian(q) @ plant.accelerations(q, v, u)
        ydd = model.acceleration(X, u)
        assert np.linalg.norm(ydd_mujoco - ydd) <= 1e-3 * np.linalg.norm(ydd)


def test_a_users_mjcf_file_is_stepped_the_same(tmp_path, robot4):
    path = tmp_path / "machine.xml"
    path.write_text(export_mjcf(robot4, TS / 20))
    X0 = np.concatenate([robot4.home_pose, np.zeros(3)])
    a, b = MujocoPlant(robot4, TS, X0), MujocoPlant(robot4, TS, X0, mjcf=path)
    for p in (a, b):
        p.apply(np.array([1.0, -2.0, 0.5, 1.5]))
    np.testing.assert_allclose(a.true_state(), b.true_state(), rtol=0, atol=1e-12)


def _rms(robot, form, plant_kind, torque_limit, sensors=Sensors("full"), duration=0.6):
    ref = path_for("s-curve", robot.home_pose, robot.output_angular, 2.0)
    X0 = np.concatenate([ref.pose(0.0), np.zeros(robot.n_y)])
    encoders = sensors.kind == "encoders"
    ctrl = GPCController.build(ReducedModel(robot), TS, Horizons(20), Weights(1.0, 1e-4), form=form,
                               limits=Limits(torque=torque_limit), disturbance_gain=0.0 if encoders else None)
    if plant_kind == "own":
        plant = SensedPlant(ConstrainedPlant(robot, X0, Ts=TS, torque_limit=torque_limit), sensors)
    else:
        plant = MujocoPlant(robot, TS, X0, sensors, torque_limit=torque_limit)
    est = StateEstimator(ReducedModel(robot), TS, sensors, X0) if encoders else None
    return run_loop(ctrl, plant, ref, duration, estimator=est).metrics()["rms_position_error_m"]


@pytest.mark.parametrize("torque_limit", [None, 3.0])
@pytest.mark.parametrize("form", ["absolute", "incremental", "incremental-delayed", "nonlinear"])
def test_closed_loop_on_mujoco_matches_our_plant(robot4, form, torque_limit):
    """Qu = 1e-4, with and without a (binding) torque limit: RMS errors within 5 %."""
    own, mj = (_rms(robot4, form, kind, torque_limit) for kind in ("own", "mujoco"))
    assert abs(mj - own) <= 0.05 * own


def test_encoder_loop_on_mujoco(robot4):
    own, mj = (_rms(robot4, "incremental", kind, None, Sensors("encoders")) for kind in ("own", "mujoco"))
    assert abs(mj - own) <= 0.05 * own


def test_missing_mujoco_says_how_to_get_it(monkeypatch, robot4):
    monkeypatch.setitem(sys.modules, "mujoco", None)
    with pytest.raises(InvalidParameterError, match=r"pip install 'parallel-gpc\[mujoco\]'"):
        MujocoPlant(robot4, TS, np.zeros(6))
    assert "\n" not in INSTALL_HINT
