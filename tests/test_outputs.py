"""Task-space outputs on a planar 5-bar whose end-effector (x, z) is y: assembly, velocity map
and acceleration offset against finite differences of forward kinematics, dynamics against
Pinocchio's constraintDynamics, and the plant in those coordinates."""

from __future__ import annotations

import numpy as np
import pytest

from parallel_gpc import ParallelRobot, ReducedModel
from parallel_gpc.errors import RobotFormatError
from parallel_gpc.model.plant import ConstrainedPlant, ReducedPlant

import mechanisms as mech


@pytest.fixture(scope="module")
def fivebar(tmp_path_factory) -> ParallelRobot:
    folder = tmp_path_factory.mktemp("fivebar")
    return ParallelRobot.load(mech.write(folder, "fivebar", mech.fivebar_urdf(), mech.fivebar_sidecar()))


def test_fivebar_loads_with_end_effector_output(fivebar):
    assert (fivebar.n_y, fivebar.n_u, fivebar.model.nv, fivebar.n_z) == (2, 2, 4, 4)
    assert fivebar.description.output_labels == ("x", "z") and fivebar.redundancy == 0
    np.testing.assert_allclose(fivebar.home_pose, mech.FIVEBAR_HOME, atol=1e-12)
    ee = fivebar.platform_placement(fivebar.q_home).translation
    np.testing.assert_allclose(ee[[0, 2]], mech.FIVEBAR_HOME, atol=1e-12)


def test_assembly_closes_loop_and_hits_output(fivebar):
    rng = np.random.default_rng(4)
    q = None
    for _ in range(20):
        y = fivebar.home_pose + rng.uniform(-0.08, 0.08, 2)
        q = fivebar.assemble(y, q)
        assert np.max(np.abs(fivebar.closure_residual(q))) <= 1e-10
        np.testing.assert_allclose(fivebar.platform_pose(q), y, atol=1e-11)
        np.testing.assert_array_equal(fivebar.branch_signature(q), fivebar.branch_signature(fivebar.q_home))


def test_velocity_map_and_offset_match_finite_differences_of_forward_kinematics(fivebar):
    rng = np.random.default_rng(5)
    model = ReducedModel(fivebar)
    eps = 1e-6
    for X in mech.random_output_states(fivebar, rng, 5):
        terms = model.terms(X)
        q, v = terms.q, terms.v
        # ẏ = H T ẏ: the output moves at ẏ along q ⊕ t v, the closures stay closed
        dy = (fivebar.platform_pose(q + eps * v) - fivebar.platform_pose(q - eps * v)) / (2 * eps)
        np.testing.assert_allclose(dy, X[2:], atol=1e-8)
        dphi = (fivebar.closure_residual(q + eps * v) - fivebar.closure_residual(q - eps * v)) / (2 * eps)
        assert np.max(np.abs(dphi)) < 1e-8
        # H against finite differences of forward kinematics, column by column
        H = fivebar.output_jacobian(q)
        for i in range(fivebar.model.nv):
            e = np.zeros(fivebar.model.nv)
            e[i] = eps
            fd = (fivebar.platform_pose(q + e) - fivebar.platform_pose(q - e)) / (2 * eps)
            np.testing.assert_allclose(H[:, i], fd, atol=1e-8)
        # q̈ = T ÿ + ℓ: the output accelerates at ÿ, the closures at 0 (second differences)
        ydd = np.array([0.7, -1.3])
        a = terms.T @ ydd + terms.ell
        np.testing.assert_allclose(mech.output_acceleration(fivebar, q, v, a, 1e-4), ydd, atol=1e-5)
        phi = [fivebar.closure_residual(q + t * v + 0.5 * t * t * a) for t in (-1e-4, 0.0, 1e-4)]
        assert np.max(np.abs(phi[0] - 2 * phi[1] + phi[2])) / 1e-8 < 1e-5


def test_reduced_accelerations_equal_constraint_dynamics(fivebar):
    mech.assert_reduced_matches_constraint_dynamics(fivebar)


def test_factorization_and_linearization_in_task_space(fivebar):
    model = ReducedModel(fivebar)
    rng = np.random.default_rng(6)
    for X in mech.random_output_states(fivebar, rng, 4):
        u = rng.uniform(-5, 5, 2)
        A, B, c = model.factorize(X)
        np.testing.assert_allclose(A @ X + B @ u + c, model.state_derivative(X, u), atol=1e-10)


def test_constrained_plant_in_task_space_agrees_with_reduced_plant(fivebar):
    X0 = np.concatenate([fivebar.home_pose, [0.1, -0.05]])
    force = np.array([0.5, -0.3])  # N on (x, z)
    full = ConstrainedPlant(fivebar, X0, Ts=0.002, platform_force=force)
    reduced = ReducedPlant(fivebar, X0, Ts=0.002, substeps=4, platform_force=force)
    np.testing.assert_allclose(full.X, X0, atol=1e-12)
    u = np.array([1.0, -0.5])
    for _ in range(50):
        a, b = full.step(u), reduced.step(u)
    np.testing.assert_allclose(a, b, atol=1e-8)
    assert np.max(np.abs(fivebar.closure_residual(full.q))) < 1e-10


def test_output_that_does_not_parametrize_the_mechanism_is_refused(tmp_path):
    # (x, y): y of a mechanism moving in the x-z plane never changes
    path = mech.write(tmp_path, "fb", mech.fivebar_urdf(), mech.fivebar_sidecar(axes=("x", "y")))
    with pytest.raises(RobotFormatError, match=r"does not parametrize.*2 DOF.*can move along \[.*a1") as info:
        ParallelRobot.load(path)
    assert "'x', 'y'" in str(info.value)
    # three outputs for two DOF
    path = mech.write(tmp_path, "fb3", mech.fivebar_urdf(), mech.fivebar_sidecar(axes=("x", "y", "z")))
    with pytest.raises(RobotFormatError, match="2 DOF"):
        ParallelRobot.load(path)


def test_inverse_then_forward_kinematics_round_trip_in_task_space(fivebar):
    for y in (fivebar.home_pose, fivebar.home_pose + [0.05, -0.03]):
        drives = fivebar.inverse_kinematics(y)
        np.testing.assert_allclose(fivebar.forward_kinematics(drives), y, atol=1e-10)
    cond = fivebar.singularity(fivebar.q_home)
    assert 1 <= cond["cond_phi_z"] < 1e3 and 1 <= cond["cond_B_r"] < 1e3


def test_gpc_tracks_an_end_effector_circle_on_the_full_constrained_plant(fivebar):
    from parallel_gpc import GPCController, Horizons, Weights, simulate
    from parallel_gpc.gpc import SampledTrajectory

    t = np.linspace(0.0, 1.0, 501)
    s = 0.5 - 0.5 * np.cos(np.pi * t)  # 0 → 1 at rest at both ends
    circle = fivebar.home_pose + 0.03 * np.column_stack([np.sin(2 * np.pi * s), 1 - np.cos(2 * np.pi * s)])
    controller = GPCController.build(ReducedModel(fivebar), 0.002, Horizons(20, 0, 20), Weights(1.0, 0.0))
    plant = ConstrainedPlant(fivebar.with_mass_scale(1.2), np.concatenate([fivebar.home_pose, [0.0, 0.0]]), Ts=0.002)
    result = simulate(controller, plant, SampledTrajectory(t, circle), 1.0, progress=False)
    error = np.linalg.norm(result.pose - result.reference, axis=1)
    assert error.max() < 2e-5  # m, with 20 % more mass in the plant (measured 5.1e-6)
    assert np.max(np.abs(fivebar.closure_residual(plant.q))) < 1e-10
