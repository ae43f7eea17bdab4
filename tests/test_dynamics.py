"""Reduced ODE against Pinocchio's constraintDynamics, redundancy, factorization, ZOH, energy."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from scipy.integrate import solve_ivp

from parallel_gpc import ReducedModel, discretize_zoh, rk4_step
from parallel_gpc.model.dynamics import kinetic_energy
from parallel_gpc.model.plant import ConstrainedPlant, ReducedPlant

from conftest import POSE_A, POSE_B, random_states


def _pin_constraint_dynamics(robot, q, v, u):
    """Independent oracle: Pinocchio's own constrained forward dynamics (and closure forces)."""
    model = robot.model
    data = model.createData()
    cms = pin.StdVec_RigidConstraintModel()
    for c in robot.description.closures:
        fa, fb = (model.frames[model.getFrameId(n)] for n in c.frames)
        cms.append(pin.RigidConstraintModel(pin.ContactType.CONTACT_3D, model, fa.parentJoint, fa.placement,
                                            fb.parentJoint, fb.placement, pin.ReferenceFrame.LOCAL))
    cds = pin.StdVec_RigidConstraintData()
    for cm in cms:
        cds.append(cm.createData())
    pin.initConstraintDynamics(model, data, cms, cds)
    tau = np.zeros(model.nv)
    tau[robot.drive_idx] = u
    ddq = pin.constraintDynamics(model, data, q, v, tau, cms, cds, pin.ProximalSettings(1e-14, 1e-10, 200))
    forces = np.concatenate([np.asarray(cd.contact_force.linear) for cd in cds])
    return ddq, forces


def assert_matches_constraint_dynamics(robot, terms, u) -> None:
    """ÿ of the reduced model and q̈ = T ÿ + ℓ equal Pinocchio's to 1e-8 relative."""
    ydd = terms.acceleration(u)
    ddq, _ = _pin_constraint_dynamics(robot, terms.q, terms.v, u)
    assert np.linalg.norm(ddq[robot.y_idx] - ydd) <= 1e-8 * np.linalg.norm(ydd)
    assert np.linalg.norm(ddq - (terms.T @ ydd + terms.ell)) <= 1e-8 * np.linalg.norm(ddq)


def test_reduced_accelerations_equal_pinocchio_constraint_dynamics(robot):
    model = ReducedModel(robot)
    rng = np.random.default_rng(1)
    for X in random_states(rng, 10):
        u = rng.uniform(-20, 20, robot.n_u)
        assert_matches_constraint_dynamics(robot, model.terms(X), u)


def test_null_space_of_redundant_drives_changes_only_internal_forces(robot4):
    model = ReducedModel(robot4)
    X = np.concatenate([0.5 * (POSE_A + POSE_B), [0.3, -0.2, 0.4]])
    terms = model.terms(X)
    n = np.linalg.svd(terms.B_r)[2][-1]  # null(B_r), B_r is 3 x 4
    assert np.linalg.norm(terms.B_r @ n) < 1e-12
    u = np.array([3.0, -1.0, 2.0, 0.5])
    a1, f1 = _pin_constraint_dynamics(robot4, terms.q, terms.v, u)
    a2, f2 = _pin_constraint_dynamics(robot4, terms.q, terms.v, u + 10.0 * n)
    assert np.linalg.norm(a2[robot4.y_idx] - a1[robot4.y_idx]) <= 1e-9 * max(1.0, np.linalg.norm(a1))
    np.testing.assert_allclose(terms.acceleration(u + 10 * n), terms.acceleration(u), atol=1e-9)
    assert np.linalg.norm(f2 - f1) > 1.0  # drive fighting: internal force only


def test_factorization_reproduces_state_derivative(robot):
    model = ReducedModel(robot)
    rng = np.random.default_rng(2)
    for X in random_states(rng, 5):
        u = rng.uniform(-10, 10, robot.n_u)
        A, B, c = model.factorize(X)
        np.testing.assert_allclose(A @ X + B @ u + c, model.state_derivative(X, u), atol=1e-10)


def test_factorization_carries_gravity_as_affine_term(robot4):
    tilted = type(robot4)(robot4.description, gravity=[0.0, -9.81 * np.sin(0.2), -9.81 * np.cos(0.2)])
    model = ReducedModel(tilted)
    X = np.concatenate([POSE_A, [0.2, 0.1, -0.3]])
    A, B, c = model.factorize(X)
    assert np.linalg.norm(c) > 0.1
    np.testing.assert_allclose(A @ X + B @ np.ones(4) + c, model.state_derivative(X, np.ones(4)), atol=1e-10)


def test_zoh_matches_rk4_of_the_linear_ode(model4):
    X = np.concatenate([POSE_B, [0.4, -0.3, 0.6]])
    u = np.array([5.0, -3.0, 1.0, 2.0])
    A, B, c = model4.factorize(X)
    Ts = 0.002
    Ad, Bd, cd = discretize_zoh(A, B, c, Ts)
    rk = rk4_step(lambda x, uu: A @ x + B @ uu + c, X, u, Ts, substeps=50)
    np.testing.assert_allclose(Ad @ X + Bd @ u + cd, rk, atol=1e-9, rtol=0)
    ivp = solve_ivp(lambda t, x: A @ x + B @ u + c, (0, Ts), X, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(Ad @ X + Bd @ u + cd, ivp.y[:, -1], atol=1e-9)


def test_jacobian_linearization_is_first_order_accurate(model4):
    X = np.concatenate([0.5 * (POSE_A + POSE_B), [0.5, -0.4, 0.8]])
    u = np.array([4.0, -2.0, 3.0, 1.0])
    A, B, c = model4.linearize(X, u)
    rng = np.random.default_rng(3)
    d = rng.normal(size=6)
    du = rng.normal(size=4)
    errs = []
    for h in (1e-2, 5e-3):
        exact = model4.state_derivative(X + h * d, u + h * du)
        errs.append(np.linalg.norm(exact - (A @ (X + h * d) + B @ (u + h * du) + c)))
    # the remainder is second order: halving the step divides it by ~4
    assert 3.5 < errs[0] / errs[1] < 4.5
    np.testing.assert_allclose(A @ X + B @ u + c, model4.state_derivative(X, u), atol=1e-8)


def test_kinetic_energy_is_conserved_without_input(robot):
    model = ReducedModel(robot)
    X = np.concatenate([0.5 * (POSE_A + POSE_B), [0.3, -0.2, 0.5]])
    E0 = kinetic_energy(model, X)
    for _ in range(500):  # 1 s at 2 ms
        X = rk4_step(model.state_derivative, X, np.zeros(robot.n_u), 0.002)
    assert abs(kinetic_energy(model, X) - E0) <= 1e-6 * E0


def test_constrained_plant_agrees_with_reduced_plant(robot4):
    X0 = np.concatenate([POSE_A, [0.2, 0.1, -0.2]])
    full, reduced = ConstrainedPlant(robot4, X0, Ts=0.002), ReducedPlant(robot4, X0, Ts=0.002, substeps=4)
    u = np.array([2.0, -1.0, 1.5, 0.5])
    for _ in range(50):
        a, b = full.step(u), reduced.step(u)
    np.testing.assert_allclose(a, b, atol=1e-8)
    assert np.max(np.abs(robot4.closure_residual(full.q))) < 1e-10


def test_plant_saturates_at_its_torque_limit_and_counts_it(robot4):
    X0 = np.concatenate([POSE_A, np.zeros(3)])
    limited, free = ConstrainedPlant(robot4, X0, Ts=0.002, torque_limit=5.0), ConstrainedPlant(robot4, X0, Ts=0.002)
    limited.step([50.0, 0, 0, 0])
    free.step([5.0, 0, 0, 0])
    np.testing.assert_allclose(limited.X, free.X, atol=1e-14)
    assert limited.saturated == 1


def test_expm_derivative_action_equals_scipys_frechet_derivative():
    """The derivatives of e^M ξ (Horner sums of the Taylor polynomial and its squarings) against
    scipy.linalg.expm_frechet (Al-Mohy & Higham), unscaled (‖M‖ ≤ 0.5) and with 1–5 squarings."""
    from scipy.linalg import expm as scipy_expm, expm_frechet

    from parallel_gpc.model.discretization import expm_derivative_action

    rng = np.random.default_rng(7)
    m, n, n_dir = 6, 11, 4
    for size in (0.01, 0.3, 2.0, 9.0):
        M = np.zeros((n, n))
        M[:m] = rng.normal(size=(m, n)) * size / np.sqrt(m * n)
        D = np.zeros((n_dir, n, n))
        D[:, :m] = rng.normal(size=(n_dir, m, n))
        xi = rng.normal(size=n)
        E, dE = expm_derivative_action(M[:m], D[:, :m], xi)
        ref = np.column_stack([expm_frechet(M, D[k], compute_expm=False)[:m] @ xi for k in range(n_dir)])
        assert np.abs(E - scipy_expm(M)[:m]).max() <= 1e-13 * np.abs(E).max()
        assert np.abs(dE - ref).max() <= 1e-13 * np.abs(ref).max()
