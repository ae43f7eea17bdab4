"""The stage Jacobians' cheaper difference steps (model/dynamics.py ``_factor_derivatives``, native
stage_jacobian.cpp): the velocity map's derivative against central differences of the velocity map,
and the compiled Jacobian (first-order velocity maps, the tangent rates from one kinematics pass)
against the Python reference and against central differences of the whole stage map, on revolute
(planar_4rrr, delta_3rus), prismatic-leg (hexapod_6ups), prismatic-drive (3-PRR) and universal-joint
(6-UPS) robots."""

from __future__ import annotations

import numpy as np
import pytest

import mechanisms as mech
import mechanisms_ups as ups
from parallel_gpc import ParallelRobot, ReducedModel
from parallel_gpc.model.native import native_module

TS = 0.002
NAMES = ["planar_4rrr", "delta_3rus", "hexapod_6ups", "prr3", "ups_universal"]


@pytest.fixture(scope="module")
def robots(tmp_path_factory, prr3):
    folder = tmp_path_factory.mktemp("ups_rates")
    universal = ParallelRobot.load(mech.write(folder, "ups_rates", ups.ups_urdf(True), ups.ups_sidecar(True),
                                              ".urdf", ".yaml"))
    out = {name: ParallelRobot.load(name) for name in NAMES[:3]}
    out.update(prr3=prr3, ups_universal=universal)
    return out


def _moving(robot, native=None):
    """(model, trajectory (6, n_x), inputs (5, n_u)): five stages of a fast move from near the home
    pose (0.02 m or rad off, 0.3 m/s or rad/s), inputs spread over ±5 (N·m or N)."""
    model = ReducedModel(robot, native=native)
    rng = np.random.default_rng(7)
    pose = robot.home_pose + rng.uniform(-0.02, 0.02, model.n_y)
    X = np.concatenate([pose, rng.uniform(-0.3, 0.3, model.n_y)])
    u = np.tile(np.linspace(-5.0, 5.0, model.n_u), (5, 1))
    return model, model.simulate_factorized(X, u, TS)[3], u


@pytest.mark.parametrize("name", NAMES)
def test_velocity_map_rate_equals_central_differences_of_the_velocity_map(robots, name):
    """(Ṫ, K̇⁺) along T e_j (the difference steps' directions) against (map(q + hδ) − map(q − hδ)) / 2h:
    truncation O(h²) ≈ 1e-12, rounding ≈ 1e-10 relative."""
    robot = robots[name]
    model, traj, _ = _moving(robot, native=False)
    q = model.assemble(traj[2, :model.n_y])
    T, P = robot.velocity_map(q)
    h = 1e-5
    for j in range(model.n_y):
        d = T[:, j]
        dT, dP = robot.velocity_map_rate(q, T, P, robot.constraint_jacobian_derivative(q, d))
        Tp, Pp = robot.velocity_map(robot.integrate(q, d * h))
        Tm, Pm = robot.velocity_map(robot.integrate(q, -d * h))
        assert np.abs(dT - (Tp - Tm) / (2 * h)).max() <= 1e-7 * max(np.abs(dT).max(), 1.0)
        assert np.abs(dP - (Pp - Pm) / (2 * h)).max() <= 1e-7 * max(np.abs(dP).max(), 1.0)
        assert np.abs(dT).max() > 1e-3  # the map moves along the closures' tangent


@pytest.mark.parametrize("native", [None, False])
@pytest.mark.parametrize("name", ["prr3", "ups_universal"])
def test_stage_jacobians_equal_central_differences_of_the_stage_map(robots, name, native):
    """Compiled and Python Jacobians against central differences of the stage map Φ = A_d X + B_d u + c_d
    (2·n_x discrete() per stage, an independent oracle) on the prismatic-drive and universal-joint robots
    (tests/test_nmpc.py covers planar_4rrr, delta_3rus and hexapod_6ups)."""
    mech.assert_stage_jacobians_match_differences(*_moving(robots[name], native=native), TS, 5)


@pytest.mark.parametrize("name", NAMES)
def test_compiled_stage_jacobians_equal_the_python_reference(robots, name):
    """The compiled Jacobian (one native call: first-order velocity maps, the tangent rates from one
    kinematics pass) against the Python loop: two rounding paths of the same formulas."""
    if not hasattr(native_module(), "stage_jacobians"):
        pytest.skip("the compiled core has no stage_jacobians (PARALLEL_GPC_NATIVE=0 or an older build)")
    model, traj, u = _moving(robots[name])
    J = model.stage_jacobians(traj, u, TS)
    J_py = ReducedModel(model.robot, native=False).stage_jacobians(traj, u, TS)
    assert J.shape == J_py.shape == (5, model.n_x, model.n_x)
    assert np.abs(J - J_py).max() <= 1e-8 * np.abs(J_py).max()
