"""Universal joints declared in a sidecar (``joint_type: UJOINT``): a 6-UPS Gough-Stewart platform
loads, assembles and matches Pinocchio's constraintDynamics, and equals the same mechanism written
with two revolute joints in series through one point; the Jacobian time variation of frames moved
by universal joints agrees with finite differences of the Jacobian."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from parallel_gpc import ParallelRobot, ReducedModel
from parallel_gpc.model.universal import UniversalJoints

import mechanisms as mech
import mechanisms_ups as ups


@pytest.fixture(scope="module")
def ups_pair(tmp_path_factory):
    """(universal joints from the sidecar, two revolutes per U joint) 6-UPS robots."""
    folder = tmp_path_factory.mktemp("ups")
    return tuple(ParallelRobot.load(mech.write(folder, f"ups_{uj}", ups.ups_urdf(uj), ups.ups_sidecar(uj), ".urdf", ".yaml"))
                 for uj in (True, False))


def test_ujoint_override_gives_universal_joints_about_x_then_y(ups_pair):
    uni, rr = ups_pair
    for k in range(1, 7):
        joint = uni.model.joints[uni.model.getJointId(f"u{k}")]
        assert joint.shortname() == "JointModelUniversal" and (joint.nq, joint.nv) == (2, 2)
    # U: 2 + P: 1 per leg, the ball joint 4 (3): the same coordinates as two revolutes per U
    assert (uni.model.nq, uni.model.nv, rr.model.nq, rr.model.nv) == (22, 21, 22, 21)
    assert (uni.n_y, uni.n_u, uni.redundancy) == (6, 6, 0)
    np.testing.assert_allclose(uni.home_pose, [0, 0, ups.UPS_H, 0, 0, 0], atol=1e-9)
    np.testing.assert_allclose(uni.home_pose, rr.home_pose, atol=1e-12)
    assert np.max(np.abs(uni.closure_residual(uni.q_home))) <= 1e-10
    # the U joint's coordinates are the two revolutes' angles: same configuration of every body
    data_u, data_r = uni.model.createData(), rr.model.createData()
    pin.framesForwardKinematics(uni.model, data_u, uni.q_home)
    pin.framesForwardKinematics(rr.model, data_r, rr.q_home)
    for name in ["platform"] + [f"rod{k}" for k in range(1, 7)]:
        Mu, Mr = data_u.oMf[uni.model.getFrameId(name)], data_r.oMf[rr.model.getFrameId(name)]
        np.testing.assert_allclose(Mu.homogeneous, Mr.homogeneous, atol=1e-12)


@pytest.mark.parametrize("which", [0, 1])
def test_reduced_accelerations_equal_constraint_dynamics(ups_pair, which):
    # assembly residual <= 1e-10, q̈ and ÿ within 1e-8 relative of pin.constraintDynamics
    mech.assert_reduced_matches_constraint_dynamics(ups_pair[which], n=6, seed=21)


def test_universal_and_two_revolutes_give_the_same_reduced_dynamics(ups_pair):
    mech.assert_same_reduced_dynamics(*ups_pair, n=6, seed=22)


def test_jacobian_rate_and_bias_derivative_with_universal_joints_match_finite_differences(ups_pair):
    uni = ups_pair[0]
    model, data = uni.model, uni.model.createData()
    universal = UniversalJoints(model)
    assert [i for _, i in universal.columns] == [model.joints[model.getJointId(f"u{k}")].idx_v for k in range(1, 7)]
    lwa = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    frames = [model.getFrameId(n) for n in ("platform", "tip2", "attach6")]

    def jacobians(q):
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        return [pin.getFrameJacobian(model, data, f, lwa).copy() for f in frames]

    rng = np.random.default_rng(23)
    eps = 1e-6
    for X in mech.random_output_states(uni, rng, 3, speed=1.0):
        q, v = ReducedModel(uni).terms(X).q, rng.uniform(-1, 1, model.nv)
        plus, minus = jacobians(pin.integrate(model, q, eps * v)), jacobians(pin.integrate(model, q, -eps * v))
        pin.computeJointJacobiansTimeVariation(model, data, q, v)
        pin.updateFramePlacements(model, data)
        for f, Jp, Jm in zip(frames, plus, minus):
            fd = (Jp - Jm) / (2 * eps)
            np.testing.assert_allclose(universal.frame_jacobian_rate(model, data, f, v), fd, atol=1e-7)
        # ∂h/∂v along a few directions W, against central differences of the RNEA bias forces
        W, zero = rng.uniform(-1, 1, (model.nv, 3)), np.zeros(model.nv)
        fd = np.column_stack([(pin.rnea(model, data, q, v + eps * w, zero) - pin.rnea(model, data, q, v - eps * w, zero))
                              / (2 * eps) for w in W.T])
        np.testing.assert_allclose(universal.bias_derivative(model, q, v, W), fd, rtol=1e-7, atol=1e-7)


def test_constrained_plant_with_universal_joints_follows_the_reduced_plant(ups_pair):
    from parallel_gpc.model.plant import ConstrainedPlant, ReducedPlant

    uni = ups_pair[0]
    X0 = np.concatenate([uni.home_pose, [0.02, -0.03, 0.05, 0.1, -0.05, 0.08]])
    full, reduced = ConstrainedPlant(uni, X0, Ts=0.002), ReducedPlant(uni, X0, Ts=0.002, substeps=4)
    u = np.array([40.0, 42.0, 38.0, 41.0, 39.0, 40.0])  # N, about the weight of the platform
    for _ in range(20):
        a, b = full.step(u), reduced.step(u)
    np.testing.assert_allclose(a, b, atol=1e-8)
    assert np.max(np.abs(uni.closure_residual(full.q))) < 1e-10
