"""The compiled model update (parallel_gpc._native.ModelUpdate) against the pure-Python reference.

Every embedded robot and the special robots of the suite (universal joints, spherical joint with a
rotation output, task-space output, MJCF, weld closure, free-flyer root): ``discrete`` and
``simulate_factorized`` along a trajectory agree to 1e-12 relative, the failure paths raise the same
package errors, and closed loops of each form give the same inputs. Without the compiled core the
tests skip with the reason, except under CI (``pip install .`` builds it there: it must exist).
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from parallel_gpc import ConstrainedPlant, GPCController, Horizons, ParallelRobot, ReducedModel, SCurve, Weights
from parallel_gpc.errors import InvalidParameterError, NonFiniteError, SingularPoseError, UnreachablePoseError
from parallel_gpc.model.native_update import model_update_status

import mechanisms as mech
import mechanisms_ups as ups

STATUS = model_update_status(None)
if STATUS != "compiled model update":
    if os.environ.get("CI"):
        raise RuntimeError(f"CI must test the compiled core, but: {STATUS}")
    print(f"test_native skipped: {STATUS}")
    pytestmark = pytest.mark.skip(reason=STATUS)

TS = 0.002
EMBEDDED = ["planar_4rrr", "planar_3rrr", "delta_3rus", "hexapod_6ups", "hexapod_8ups"]
SPECIAL = ["ups_universal", "rps_spherical", "fivebar_task", "fivebar_mjcf", "fivebar_weld", "fivebar_free_flyer"]


def _special(name: str, folder) -> ParallelRobot:
    if name == "ups_universal":
        return ParallelRobot.load(mech.write(folder, name, ups.ups_urdf(True), ups.ups_sidecar(True), ".urdf", ".yaml"))
    if name == "rps_spherical":
        return ParallelRobot.load(mech.write(folder, name, mech.rps_urdf(True), mech.rps_sidecar(True), ".urdf", ".yaml"))
    if name == "fivebar_task":
        return ParallelRobot.load(mech.write(folder, name, mech.fivebar_urdf(), mech.fivebar_sidecar()))
    if name == "fivebar_mjcf":
        return ParallelRobot.load(mech.write(folder, name, mech.fivebar_mjcf(), mech.fivebar_mjcf_sidecar(), ".xml"))
    if name == "fivebar_weld":
        return ParallelRobot.load(mech.write(folder, name, mech.fivebar_urdf(split=True),
                                             mech.fivebar_sidecar(split=True)))
    side = mech.fivebar_sidecar(extra='root = "free_flyer"\n') + (
        '[[closures]]\nname = "ground"\nkind = "weld"\nframes = ["base", "universe"]\n')
    return ParallelRobot.load(mech.write(folder, name, mech.fivebar_urdf(), side))


@pytest.fixture(scope="module", params=EMBEDDED + SPECIAL)
def robot(request, tmp_path_factory) -> ParallelRobot:
    if request.param in EMBEDDED:
        return ParallelRobot.load(request.param)
    return _special(request.param, tmp_path_factory.mktemp(request.param))


def _trajectory(robot: ParallelRobot, n: int = 20) -> list[np.ndarray]:
    """n states X = [y, ẏ] along a curved path near home with nonzero velocities (m, rad, /s)."""
    rng = np.random.default_rng(3)
    direction, bend = rng.uniform(-1, 1, robot.n_y), rng.uniform(-1, 1, robot.n_y)
    s = np.linspace(0.0, 1.0, n)
    return [np.concatenate([robot.home_pose + 0.02 * (t * direction + t * t * bend),
                            0.5 * (direction + 2 * t * bend)]) for t in s]


def _assert_close(ref, got, what: str, rtol: float = 1e-12) -> None:
    for i, (a, b) in enumerate(zip(ref, got)):
        a, b = np.asarray(a), np.asarray(b)
        assert a.shape == b.shape, (what, i, a.shape, b.shape)
        err = np.linalg.norm(a - b)
        assert err <= rtol * np.linalg.norm(a) or err == 0.0, f"{what}[{i}]: ‖Δ‖ = {err:.3g}, ‖ref‖ = {np.linalg.norm(a):.3g}"


def test_every_robot_uses_the_compiled_update(robot):
    model = ReducedModel(robot)
    assert model.native and model.native_reason == "compiled model update"
    assert not ReducedModel(robot, native=False).native


def test_discrete_matches_python_along_a_trajectory(robot):
    py, cc = ReducedModel(robot, native=False), ReducedModel(robot, native=True)
    for k, X in enumerate(_trajectory(robot)):
        _assert_close(py.discrete(X, TS), cc.discrete(X, TS), f"discrete at state {k}")
        _assert_close(py.factorize(X), cc.factorize(X), f"factorize at state {k}")
    # a cold start far from the last pose (Newton from the last q, no predictor)
    X = _trajectory(robot)[0]
    _assert_close(ReducedModel(robot, native=False).discrete(X, TS), ReducedModel(robot).discrete(X, TS), "cold")


def test_simulate_factorized_matches_python(robot):
    py, cc = ReducedModel(robot, native=False), ReducedModel(robot, native=True)
    rng = np.random.default_rng(5)
    X0 = _trajectory(robot)[3]
    u = rng.uniform(-1, 1, (20, robot.n_u))
    offset = 1e-4 * rng.standard_normal(2 * robot.n_y)
    for shift in range(3):  # receding horizon: the second and third calls use the pre-simulation warm starts
        args = (X0 + 1e-4 * shift, np.roll(u, -shift, axis=0), TS)
        for off in (None, offset):
            ref, got = py.simulate_factorized(*args, off), cc.simulate_factorized(*args, off)
            for name, a, b in zip(("A", "B", "c", "X"), ref, got):
                _assert_close(a, b, f"simulate {name} (shift {shift})")


@pytest.mark.parametrize("name", ["planar_4rrr", "hexapod_6ups", "ups_universal", "rps_spherical"])
def test_velocity_block_is_half_the_derivative_of_the_reference_acceleration(name, tmp_path):
    """−M_r⁻¹ C_r(ẏ) of the compiled update (∂h/∂v · T from Pinocchio's Coriolis matrix when every joint
    has one degree of freedom, else from RNEA derivatives, or by polarization for universal joints)
    against an oracle that never differentiates: at fixed y the drive-free
    acceleration of the Python reference (RNEA values, no RNEA derivatives) is a(ẏ) = g-part + Q(ẏ, ẏ)
    with Q symmetric bilinear, and the factorization's block is Q(ẏ, ·): A₂₂(ẏ) w = (a(ẏ + w) − a(ẏ − w)) / 4,
    exactly (no step error)."""
    robot = ParallelRobot.load(name) if name in EMBEDDED else _special(name, tmp_path)
    py, cc = ReducedModel(robot, native=False), ReducedModel(robot, native=True)
    ny, u0 = robot.n_y, np.zeros(robot.n_u)
    rng = np.random.default_rng(11)
    for X in _trajectory(robot, 4):
        block = cc.factorize(X)[0][ny:, ny:]
        W = rng.uniform(-1, 1, (ny, ny))
        for j in range(ny):
            up, down = X.copy(), X.copy()
            up[ny:] += W[:, j]
            down[ny:] -= W[:, j]
            expected = (py.acceleration(up, u0) - py.acceleration(down, u0)) / 4
            err = np.linalg.norm(block @ W[:, j] - expected)
            assert err <= 1e-10 * np.linalg.norm(expected), (name, j, err, np.linalg.norm(expected))


def test_failure_paths_raise_the_python_errors():
    robot = ParallelRobot.load("planar_3rrr")
    py, cc = ReducedModel(robot, native=False), ReducedModel(robot, native=True)
    far = np.array([2.5, 0.5, 0.0, 0.0, 0.0, 0.0])
    errors = []
    for model in (py, cc):
        with pytest.raises(UnreachablePoseError) as info:
            model.discrete(far, TS)
        errors.append(str(info.value))
    assert errors[0] == errors[1] and "2.5" in errors[0]
    bad_speed = np.concatenate([robot.home_pose, [np.nan, 0.0, 0.0]])
    for model in (py, cc):
        with pytest.raises(NonFiniteError, match="NaN"):
            model.discrete(bad_speed, TS)
        with pytest.raises(NonFiniteError, match="NaN"):
            model.simulate_factorized(bad_speed, np.zeros((3, robot.n_u)), TS)
    # after a failure both continue from where they were
    X = np.concatenate([robot.home_pose + 0.01, [0.1, -0.2, 0.3]])
    _assert_close(py.discrete(X, TS), cc.discrete(X, TS), "after failure")


def test_a_far_jump_takes_the_validated_path_and_still_matches(monkeypatch):
    from parallel_gpc.model import native_update

    calls = []
    original = native_update._ValidatedPath.assemble
    monkeypatch.setattr(native_update._ValidatedPath, "assemble",
                        lambda self, y, q_last: calls.append(y.copy()) or original(self, y, q_last))
    robot = ParallelRobot.load("planar_4rrr")
    py, cc = ReducedModel(robot, native=False), ReducedModel(robot, native=True)
    for jump in (0.0, 0.15, -0.1):  # 0.15 m away: Newton from the warm start is refused, continuation from home
        X = np.concatenate([robot.home_pose + jump * np.array([1.0, 0.5, 0.0]), [0.2, -0.1, 0.3]])
        _assert_close(py.discrete(X, TS), cc.discrete(X, TS), f"jump {jump}")
    assert len(calls) >= 1


def test_a_singular_velocity_map_on_the_fallback_path_raises_singular_pose_error(monkeypatch):
    """The compiled rank check (SVD on the fallback path) refuses a configuration with a stretched
    leg (elbow angle exactly 0: Φ_z loses rank) and reports it through the package's error."""
    from parallel_gpc.model import native_update

    robot = ParallelRobot.load("planar_3rrr")
    stretched = robot.q_home.copy()
    stretched[robot.model.joints[robot.model.getJointId("elbow_1")].idx_q] = 0.0
    assert robot.singularity(stretched)["cond_phi_z"] > 1e8
    monkeypatch.setattr(native_update._ValidatedPath, "assemble", lambda self, y, q_last: stretched)
    model = ReducedModel(robot, native=True)
    with pytest.raises(SingularPoseError, match="legs singular"):
        model.discrete(np.array([2.5, 0.5, 0.0, 0.0, 0.0, 0.0]), TS)  # unreachable: the fallback path


def test_wrong_sizes_and_the_native_switch_are_checked(robot4):
    cc = ReducedModel(robot4, native=True)
    with pytest.raises(ValueError, match="n_x"):
        cc.discrete(np.zeros(4), TS)
    with pytest.raises(ValueError, match="u_seq"):
        cc.simulate_factorized(np.concatenate([robot4.home_pose, np.zeros(3)]), np.zeros((3, 2)), TS)
    with pytest.raises(InvalidParameterError, match="native"):
        ReducedModel(robot4, native="yes")


def test_environment_switch_gives_the_python_path(robot4, monkeypatch):
    monkeypatch.setenv("PARALLEL_GPC_NATIVE", "0")
    model = ReducedModel(robot4)
    assert not model.native and "PARALLEL_GPC_NATIVE=0" in model.native_reason
    with pytest.raises(InvalidParameterError, match="not available"):
        ReducedModel(robot4, native=True)


@pytest.mark.parametrize("name", ["planar_4rrr", "delta_3rus", "hexapod_6ups"])
@pytest.mark.parametrize("form", ["absolute", "incremental", "nonlinear"])
def test_closed_loop_inputs_are_the_same(name, form):
    robot = ParallelRobot.load(name)
    ref = SCurve(duration=0.2) if name == "planar_4rrr" else None
    pose0 = robot.home_pose if ref is None else ref.pose(0.0)
    target = pose0 + 0.01
    runs = []
    for native in (False, True):
        ctl = GPCController.build(ReducedModel(robot, native=native), TS, Horizons(20), Weights(1.0, 1e-5), form=form)
        plant = ConstrainedPlant(robot, np.concatenate([pose0, np.zeros(robot.n_y)]), Ts=TS)
        us = []
        for k in range(40):
            window = ref.window(k * TS, TS, 20) if ref is not None else np.tile(target, (20, 1))
            u = ctl.step(plant.X, window).u
            us.append(u)
            plant.step(u)
        runs.append(np.array(us))
    scale = np.abs(runs[0]).max()
    np.testing.assert_allclose(runs[1], runs[0], rtol=0, atol=1e-10 * max(scale, 1.0))


def test_cli_info_says_which_model_update_is_used(capsys, monkeypatch):
    from parallel_gpc.cli import main

    main(["info", "planar_3rrr"])
    out = capsys.readouterr().out
    assert "compiled core in use" in out and "model update" in out and "compiled model update" in out
    monkeypatch.setenv("PARALLEL_GPC_NATIVE", "0")
    main(["info", "planar_3rrr"])
    assert "pure-Python model update" in capsys.readouterr().out


def test_mass_scale_gravity_and_array_layouts_reach_the_compiled_update():
    robot = ParallelRobot.load("delta_3rus", mass_scale=1.3, gravity=[1.0, -2.0, -9.0])
    py, cc = ReducedModel(robot, native=False), ReducedModel(robot, native=True)
    X = np.concatenate([robot.home_pose + 0.01, [0.1, -0.2, 0.3]])
    _assert_close(py.discrete(X, TS), cc.discrete(X, TS), "scaled")
    assert np.abs(cc.discrete(X, TS)[2]).max() > 1e-4  # the gravity term is there
    u = np.asfortranarray(np.random.default_rng(2).uniform(-1, 1, (6, robot.n_u)))
    ref = ReducedModel(robot, native=False).simulate_factorized(X, np.ascontiguousarray(u), TS)
    got = ReducedModel(robot, native=True).simulate_factorized(list(X), u, TS)
    for name, a, b in zip("ABcX", ref, got):
        _assert_close(a, b, f"simulate {name} (Fortran-ordered inputs)")
