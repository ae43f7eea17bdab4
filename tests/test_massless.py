"""The full constrained plant of a robot with a massless moving body (distal link 2 of the
planar 5-bar without ``<inertial>``): the open-tree mass matrix is singular, the closed chain is
not, and ``pin.constraintDynamics`` returns NaN; the plant solves the KKT system instead."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

import mechanisms as mech
from parallel_gpc import GPCController, Horizons, ReducedModel, Weights
from parallel_gpc.errors import InvalidParameterError
from parallel_gpc.gpc.references import Hold
from parallel_gpc.model.plant import ConstrainedPlant
from parallel_gpc.model.robot import ParallelRobot
from parallel_gpc.model.singular_kkt import mass_matrix
from parallel_gpc.studies import simulate

TS = 0.005  # s
TINY = 1e-6  # kg: the mass put back on the massless link for the comparison run


def _dist2(inertial: str) -> str:
    text = mech.fivebar_urdf()
    start = text.index('<link name="dist2">') + len('<link name="dist2">')
    return text[:start] + inertial + text[text.index("</link>", start):]


def _robot(tmp_path, mass: float | None) -> ParallelRobot:
    inertial = "" if mass is None else (f'<inertial><origin xyz="0 0 {mech.L_DIST / 2}"/><mass value="{mass}"/>'
                                        f'<inertia {mech._rod_inertia(mass, mech.L_DIST)}/></inertial>')
    stem = "massless" if mass is None else "tiny"
    return ParallelRobot.load(mech.write(tmp_path, stem, _dist2(inertial), mech.fivebar_sidecar()))


def _ydd_plant(plant, q, v, a):
    """Output acceleration H q̈ + Ḣ v of the plant's joint accelerations (Ḣ v by central differences)."""
    r, eps = plant.robot, 1e-6
    hdot_v = (r.output_velocity(r.integrate(q, eps * v), v) - r.output_velocity(r.integrate(q, -eps * v), v)) / (2 * eps)
    return r.output_velocity(q, a) + hdot_v


def test_massless_link_makes_mass_matrix_singular_and_pinocchio_fail(tmp_path):
    robot = _robot(tmp_path, None)
    plant = ConstrainedPlant(robot, np.r_[mech.FIVEBAR_HOME, 0.0, 0.0], Ts=TS)
    assert plant.kkt is not None and plant.compiled is None
    M = mass_matrix(robot.model, robot.model.createData(), plant.q)
    assert np.linalg.eigvalsh(M)[0] < 1e-12 * np.linalg.eigvalsh(M)[-1]
    with pytest.raises(InvalidParameterError, match="singular"):
        ConstrainedPlant(robot, np.r_[mech.FIVEBAR_HOME, 0.0, 0.0], Ts=TS, native=True)
    regular = ConstrainedPlant(_robot(tmp_path, 0.8), np.r_[mech.FIVEBAR_HOME, 0.0, 0.0], Ts=TS)
    assert regular.kkt is None


@pytest.mark.parametrize("ydot", [(0.0, 0.0), (0.3, -0.2)])
def test_accelerations_match_reduced_model_and_kkt(tmp_path, ydot):
    robot = _robot(tmp_path, None)
    X = np.r_[mech.FIVEBAR_HOME, ydot]
    plant = ConstrainedPlant(robot, X, Ts=TS)
    q, v, u = plant.q, plant.v, np.array([0.7, -1.3])
    a = plant.accelerations(q, v, u)
    assert np.all(np.isfinite(a))
    # oracle 1: the reduced model ÿ = f + g u (assembled state: the Baumgarte terms vanish)
    ydd = ReducedModel(robot).acceleration(plant.X, u)
    np.testing.assert_allclose(_ydd_plant(plant, q, v, a), ydd, rtol=1e-6, atol=1e-6)
    # oracle 2: KKT residual from Pinocchio's M, h, J and a finite-difference J̇ v
    model, data = robot.model, robot.model.createData()
    M = mass_matrix(model, data, q)
    h = pin.nonLinearEffects(model, data, q, v)

    def jac(qq):
        pin.computeJointJacobians(model, data, qq)
        pin.forwardKinematics(model, data, qq)
        return pin.getConstraintsJacobian(model, data, plant.cms, plant.kkt.cds)

    J = jac(q)
    lam = plant.constraint_forces()
    tau = robot.drive_selection @ u
    scale = np.abs(tau).max() + np.abs(h).max()
    assert np.abs(M @ a + h - tau - J.T @ lam).max() < 1e-9 * scale
    # oracle 3: the closed point's two frames have the same classical acceleration (world axes)
    pin.forwardKinematics(model, data, q, v, a)
    acc = [pin.getFrameClassicalAcceleration(model, data, model.getFrameId(f), pin.LOCAL_WORLD_ALIGNED).linear
           for f in ("ee", "tip2")]
    np.testing.assert_allclose(acc[0], acc[1], atol=1e-9 * (1 + np.abs(a).max()))


def test_closed_loop_tracks_like_tiny_mass(tmp_path):
    reference = Hold((mech.FIVEBAR_HOME[0] + 0.01, mech.FIVEBAR_HOME[1] - 0.01))
    X0 = np.r_[mech.FIVEBAR_HOME, 0.0, 0.0]
    poses = []
    for mass in (None, TINY):
        robot = _robot(tmp_path, mass)
        ctrl = GPCController.build(ReducedModel(robot), TS, Horizons(10), Weights(1.0, 1e-5))
        plant = ConstrainedPlant(robot, X0, Ts=TS)
        res = simulate(ctrl, plant, reference, 0.1, progress=False)
        assert not res.stopped
        poses.append(res.pose)
    # the tiny mass is ~3e-7 of the moving mass: trajectories agree far below the 1 cm step
    np.testing.assert_allclose(poses[0], poses[1], atol=1e-6)
    assert np.abs(poses[0][-1] - reference.target).max() < 5e-3


def test_mujoco_tracks_the_massless_robot_like_our_plant(tmp_path):
    """MuJoCo with the export's bounds on the massless link (1e-5 of the largest body's mass and moment) follows the
    same hold step as our KKT plant (found on a field five-bar: 1e-9 kg made MuJoCo wander 155 mm RMS off a 5.55 mm
    run). The plants differ (MuJoCo's soft loop constraints, the bound's mass): RMS errors within 5 %."""
    pytest.importorskip("mujoco")
    from parallel_gpc.estimation import MujocoPlant, SensedPlant, Sensors
    from parallel_gpc.studies.loop import run_loop

    robot = _robot(tmp_path, None)
    reference = Hold((mech.FIVEBAR_HOME[0] + 0.01, mech.FIVEBAR_HOME[1] - 0.01))
    X0 = np.r_[mech.FIVEBAR_HOME, 0.0, 0.0]
    rms = []
    for plant in (SensedPlant(ConstrainedPlant(robot, X0, Ts=TS), Sensors("full")), MujocoPlant(robot, TS, X0, Sensors("full"))):
        ctrl = GPCController.build(ReducedModel(robot), TS, Horizons(10), Weights(1.0, 1e-5))
        result = run_loop(ctrl, plant, reference, 0.1)
        assert not result.stopped
        rms.append(result.metrics()["rms_position_error_m"])
    assert rms[1] == pytest.approx(rms[0], rel=0.05)
