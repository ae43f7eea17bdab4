"""Multi-DOF joints (nq ≠ nv): a spatial 3-RPS whose platform hangs on a Pinocchio spherical joint
(Gepetto-style ``joint_type: SPHERICAL``) against the same mechanism with three revolute joints
through one point; universal joints; under-actuation; a free-flyer root welded to the world."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from parallel_gpc import ParallelRobot, ReducedModel
from parallel_gpc.errors import RobotFormatError, UnderactuatedError

import mechanisms as mech


@pytest.fixture(scope="module")
def rps_pair(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rps")
    sph = ParallelRobot.load(mech.write(folder, "rps_s", mech.rps_urdf(True), mech.rps_sidecar(True), ".urdf", ".yaml"))
    rrr = ParallelRobot.load(mech.write(folder, "rps_r", mech.rps_urdf(False), mech.rps_sidecar(False), ".urdf", ".yaml"))
    return sph, rrr


def test_spherical_override_gives_a_ball_joint(rps_pair):
    sph, rrr = rps_pair
    joint = sph.model.joints[sph.model.getJointId("s1")]
    assert joint.shortname() == "JointModelSpherical" and (joint.nq, joint.nv) == (4, 3)
    assert (sph.model.nq, sph.model.nv, rrr.model.nq, rrr.model.nv) == (10, 9, 9, 9)
    assert sph.n_y == rrr.n_y == 3 and sph.description.output_labels == ("z", "rx", "ry")
    np.testing.assert_allclose(sph.home_pose, [mech.H, 0.0, 0.0], atol=1e-12)


def test_spherical_and_three_revolutes_give_the_same_reduced_dynamics(rps_pair):
    mech.assert_same_reduced_dynamics(*rps_pair, n=6, seed=7)


@pytest.mark.parametrize("which", [0, 1])
def test_reduced_accelerations_equal_constraint_dynamics(rps_pair, which):
    mech.assert_reduced_matches_constraint_dynamics(rps_pair[which])


def test_velocity_map_matches_finite_differences_on_the_manifold(rps_pair):
    sph = rps_pair[0]
    model = ReducedModel(sph)
    rng = np.random.default_rng(8)
    eps = 1e-6
    for X in mech.random_output_states(sph, rng, 4):
        terms = model.terms(X)
        q, v = terms.q, terms.v
        iq = sph.model.joints[sph.model.getJointId("s1")].idx_q
        assert abs(np.linalg.norm(q[iq:iq + 4]) - 1.0) < 1e-12  # the ball joint's quaternion stays unit
        plus, minus = sph.integrate(q, eps * v), sph.integrate(q, -eps * v)
        np.testing.assert_allclose((sph.platform_pose(plus) - sph.platform_pose(minus)) / (2 * eps), X[3:], atol=1e-8)
        assert np.max(np.abs(sph.closure_residual(plus) - sph.closure_residual(minus))) / (2 * eps) < 1e-8
        ydd = rng.uniform(-1, 1, 3)
        a = terms.T @ ydd + terms.ell
        np.testing.assert_allclose(mech.output_acceleration(sph, q, v, a, 1e-4), ydd, atol=1e-5)


def test_factorization_reproduces_state_derivative_with_spherical_joint(rps_pair):
    model = ReducedModel(rps_pair[0])
    rng = np.random.default_rng(9)
    for X in mech.random_output_states(rps_pair[0], rng, 4):
        u = rng.uniform(-5, 5, 3)
        A, B, c = model.factorize(X)
        np.testing.assert_allclose(A @ X + B @ u + c, model.state_derivative(X, u), atol=1e-9)


def test_constrained_plant_with_spherical_joint_stays_on_the_closures(rps_pair):
    from parallel_gpc.model.plant import ConstrainedPlant, ReducedPlant

    sph = rps_pair[0]
    X0 = np.concatenate([sph.home_pose, [0.02, 0.05, -0.03]])
    full, reduced = ConstrainedPlant(sph, X0, Ts=0.002), ReducedPlant(sph, X0, Ts=0.002, substeps=4)
    u = np.array([20.0, 21.0, 19.0])
    for _ in range(25):
        a, b = full.step(u), reduced.step(u)
    np.testing.assert_allclose(a, b, atol=1e-8)
    assert np.max(np.abs(sph.closure_residual(full.q))) < 1e-10


def test_universal_joint_spinning_a_leg_is_named_as_the_free_direction(tmp_path):
    # UJOINT about y then z: at home the second axis runs along the leg, so each leg can spin
    # about its own axis without moving anything: the output cannot parametrize that motion
    side = mech.rps_sidecar(True, axes=("x", "y", "z", "rx", "ry", "rz"),
                            joint_types={"r1": "UJOINT", "r2": "UJOINT", "r3": "UJOINT"})
    path = mech.write(tmp_path, "ups", mech.rps_urdf(True), side, ".urdf", ".yaml")
    with pytest.raises(RobotFormatError, match=r"12 − 6\).*can move along \[r\d\[1\]: [+-]1\.000\]"):
        ParallelRobot.load(path)


def test_under_actuated_fivebar_is_refused_with_the_numbers(tmp_path):
    path = mech.write(tmp_path, "fb", mech.fivebar_urdf(), mech.fivebar_sidecar(drives=("a1",)))
    with pytest.raises(UnderactuatedError, match=r"1 drives \['a1'\] span rank\(B_r\) = 1 of its 2 DOF") as info:
        ParallelRobot.load(path)
    assert isinstance(info.value, RobotFormatError)


def test_redundant_drives_are_reported(tmp_path):
    path = mech.write(tmp_path, "fb", mech.fivebar_urdf(), mech.fivebar_sidecar(drives=("a1", "a2", "e1")))
    robot = ParallelRobot.load(path)
    assert robot.redundancy == 1 and "redundancy=1" in repr(robot)


@pytest.mark.parametrize("bad, match", [
    ({"s1": "BALL"}, r"joint 's1' has unknown joint_type 'BALL'; valid types are \['SPHERICAL'"),
    ({"nosuch": "SPHERICAL"}, r"joint_name 'nosuch' is not a joint of the model"),
    ({"p1": "UJOINT"}, r"joint 'p1' is a JointModelPZ in the file, not a revolute joint"),
])
def test_bad_joint_types_are_refused(tmp_path, bad, match):
    side = mech.rps_sidecar(False, joint_types=bad)
    path = mech.write(tmp_path, "rps", mech.rps_urdf(False), side, ".urdf", ".yaml")
    with pytest.raises(RobotFormatError, match=match):
        ParallelRobot.load(path)


def test_fixed_override_locks_a_joint(tmp_path):
    # the 5-bar with its second elbow fixed at its home angle: a 4-bar with one DOF left
    q = mech.fivebar_q_guess()
    side = mech.fivebar_sidecar(drives=("a1",), axes=("x",)).replace(
        'name = "fivebar"\n', 'name = "fivebar"\njoint_name = ["e2"]\njoint_type = ["FIXED"]\n')
    side = side.replace('branch_joints = ["e1", "e2"]', 'branch_joints = ["e1"]')
    robot = ParallelRobot.load(mech.write(tmp_path, "fb", mech.fivebar_urdf(), side))
    assert robot.model.nv == 3 and not robot.model.existJointName("e2") and robot.n_y == 1
    assert abs(robot.home_pose[0] - mech.FIVEBAR_HOME[0]) < 1e-9  # e2 locked at its home angle
    mech.assert_reduced_matches_constraint_dynamics(robot)
    # the locked elbow keeps its home angle: the distal link 2 keeps its angle to the proximal one
    pin_data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, pin_data, robot.assemble(robot.home_pose + [0.01]))
    R2 = pin_data.oMf[robot.model.getFrameId("prox2")].rotation.T @ pin_data.oMf[robot.model.getFrameId("dist2")].rotation
    assert abs(np.arctan2(R2[0, 2], R2[0, 0]) - q["e2"]) < 1e-12


def test_free_flyer_root_welded_to_the_world_matches_the_fixed_base(tmp_path):
    fixed = ParallelRobot.load(mech.write(tmp_path, "fb", mech.fivebar_urdf(), mech.fivebar_sidecar()))
    side = mech.fivebar_sidecar(extra='root = "free_flyer"\n') + (
        '[[closures]]\nname = "ground"\nkind = "weld"\nframes = ["base", "universe"]\n')
    floating = ParallelRobot.load(mech.write(tmp_path, "fbf", mech.fivebar_urdf(), side))
    assert (floating.model.nq, floating.model.nv) == (11, 10)
    assert floating.description.closures[-1].kind == "weld"
    X = np.concatenate([fixed.home_pose + [0.01, -0.02], [0.1, 0.2]])
    u = np.array([1.0, -2.0])
    ta, tb = ReducedModel(fixed).terms(X), ReducedModel(floating).terms(X)
    np.testing.assert_allclose(tb.acceleration(u), ta.acceleration(u), rtol=1e-9)
    np.testing.assert_allclose(tb.M_r, ta.M_r, rtol=1e-10)
    mech.assert_reduced_matches_constraint_dynamics(floating)


def test_inverse_then_forward_kinematics_round_trip_with_spherical_joint(rps_pair):
    sph = rps_pair[0]
    y = sph.home_pose + [0.02, 0.05, -0.04]
    np.testing.assert_allclose(sph.forward_kinematics(sph.inverse_kinematics(y)), y, atol=1e-10)
