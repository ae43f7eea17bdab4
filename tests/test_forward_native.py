"""The compiled forward kinematics (``_native.ModelUpdate.solve_forward_into``) against the Python reference.

Oracle: :func:`~parallel_gpc.model.forward.solve_forward` with ``compiled=None`` (the Python
Gauss-Newton loop) on the same readings, resolution and warm start: the same pose, configuration,
drive Jacobian and residual, on every embedded robot and the special robots of
the suite (task-space output, free-flyer root, spherical joint), at random poses with readings
±10 counts off, cold from home and warm; the same SensorError for readings no pose explains; and
a start the compiled warm Newton cannot assemble handed back to the Python loop; warm-started
sample after sample along a path (the compiled loop's kept last solution and first-order trial
starts); bad readings, resolutions and starts refused with the Python path's errors. Without the
compiled core the tests skip with the reason, except under CI.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from parallel_gpc import ParallelRobot, path_for
from parallel_gpc.errors import ParallelGPCError, SensorError
from parallel_gpc.model.description import embedded_robots
from parallel_gpc.model.forward import drive_resolution, solve_forward
from parallel_gpc.model.native_update import compiled_forward, forward_status, use_native

import mechanisms as mech
import mechanisms_ups as ups
from test_forward_kinematics import random_configurations

STATUS = forward_status()
if STATUS != "compiled":
    if os.environ.get("CI"):
        raise RuntimeError(f"CI must test the compiled forward kinematics, but: {STATUS}")
    pytestmark = pytest.mark.skip(reason=STATUS)

SPECIAL = ["fivebar_task", "fivebar_free_flyer", "rps_spherical", "ups_universal"]
#: random poses per robot
POSES = 40


def _special(name: str, folder) -> ParallelRobot:
    if name == "fivebar_task":
        return ParallelRobot.load(mech.write(folder, name, mech.fivebar_urdf(), mech.fivebar_sidecar()))
    if name == "rps_spherical":
        return ParallelRobot.load(mech.write(folder, name, mech.rps_urdf(True), mech.rps_sidecar(True), ".urdf", ".yaml"))
    if name == "ups_universal":
        return ParallelRobot.load(mech.write(folder, name, ups.ups_urdf(True), ups.ups_sidecar(True), ".urdf", ".yaml"))
    side = mech.fivebar_sidecar(extra='root = "free_flyer"\n') + (
        '[[closures]]\nname = "ground"\nkind = "weld"\nframes = ["base", "universe"]\n')
    return ParallelRobot.load(mech.write(folder, name, mech.fivebar_urdf(), side))


@pytest.fixture(scope="module", params=list(embedded_robots()) + SPECIAL)
def robot(request, tmp_path_factory) -> ParallelRobot:
    if request.param in SPECIAL:
        return _special(request.param, tmp_path_factory.mktemp(request.param))
    return ParallelRobot.load(request.param)


def both(robot, compiled, readings, res, q_guess, **kw):
    """(Python solution, compiled solution) of the same problem."""
    py = solve_forward(robot, readings, res, q_guess, robot.platform_pose(q_guess), compiled=None, **kw)
    cc = solve_forward(robot, readings, res, q_guess, compiled=compiled, **kw)
    return py, cc


def assert_same(py, cc, atol=1e-9):
    """Equal to ``atol`` (m, rad): both loops stop where the next step would move no drive by more
    than forward.STOP_COUNTS = 10^-4 counts, at the same iterate unless rounding puts a step on that
    line (then up to 6e-10 rad apart at 2^20 counts per revolution)."""
    np.testing.assert_allclose(cc.pose, py.pose, rtol=0, atol=atol)
    np.testing.assert_allclose(cc.q, py.q, rtol=0, atol=atol)
    np.testing.assert_allclose(cc.jacobian, py.jacobian, rtol=1e-8, atol=atol)
    np.testing.assert_allclose(cc.residual, py.residual, rtol=0, atol=atol)


def test_compiled_equals_python_at_random_poses(robot):
    """±10 counts on every drive; cold from home (several trust-region steps) and warm from a
    configuration 1 mm / 1 mrad away; the validated-path callback of trial poses included."""
    compiled = compiled_forward(robot)
    rng = np.random.default_rng(11)
    res = drive_resolution(robot)
    iterations = []
    for k, (y, q) in enumerate(random_configurations(robot, rng, POSES)):
        readings = q[robot.drive_q_indices] + rng.integers(-10, 11, robot.n_u) * res
        guess = robot.q_home if k % 2 == 0 else robot.assemble(y + 1e-3, q)
        py, cc = both(robot, compiled, readings, res, guess)
        assert_same(py, cc)
        # not compared: the stopping tests (10^-4 counts, an improvement of 10^-14 relative) may fall
        # on either side in the two loops, one taking a step that changes nothing above 1e-9
        iterations.append(py.iterations)
    assert max(iterations) >= 3  # the cold starts took several bounded steps


def test_the_robot_uses_the_compiled_loop_unless_switched_off(robot4, monkeypatch):
    y = robot4.home_pose + np.array([0.02, -0.01, 0.03])
    drives = robot4.inverse_kinematics(y)
    calls = []
    real = solve_forward.__globals__["_gauss_newton"]
    monkeypatch.setitem(solve_forward.__globals__, "_gauss_newton", lambda *a: calls.append(1) or real(*a))
    np.testing.assert_allclose(robot4.forward_kinematics(drives), y, atol=1e-9)
    assert calls == [] and use_native(None)
    monkeypatch.setenv("PARALLEL_GPC_NATIVE", "0")
    np.testing.assert_allclose(robot4.forward_kinematics(drives), y, atol=1e-9)
    assert calls == [1]


def test_a_start_off_the_closures_is_handed_to_python(robot4):
    """A q_guess whose passive joints are 0.5 rad off: the compiled warm Newton refuses it
    (None), and solve_forward solves it with the Python loop (the validated assembly)."""
    compiled = compiled_forward(robot4)
    y = robot4.home_pose + np.array([0.01, 0.02, -0.02])
    q = robot4.assemble(y)
    res = drive_resolution(robot4)
    bad = q.copy()
    bad[robot4.z_idx] += 0.5
    readings = q[robot4.drive_q_indices]
    assert compiled.solve(readings, res, bad, 50, 50.0) == (1, None)  # status 1: the Python path
    py, cc = both(robot4, compiled, readings, res, bad)
    assert_same(py, cc, atol=0)
    np.testing.assert_allclose(cc.pose, y, atol=1e-9)


@pytest.mark.parametrize("name, drive, offset", [("planar_4rrr", 2, 0.05), ("hexapod_8ups", 5, 0.002)])
def test_a_broken_encoder_raises_the_same_error(name, drive, offset):
    robot = ParallelRobot.load(name)
    compiled = compiled_forward(robot)
    res = drive_resolution(robot)
    drives = robot.inverse_kinematics(robot.home_pose + np.where(robot.output_angular, 0.02, 0.01))
    drives[drive] += offset
    messages = []
    for c in (None, compiled):
        with pytest.raises(SensorError, match=r"inconsistent.*drive \d \('drive_\d'\) is off by") as info:
            solve_forward(robot, drives, res, robot.q_home, robot.home_pose, compiled=c)
        messages.append(str(info.value).split("drives [")[1].split("]")[0])
    assert messages[0] == messages[1] and f"'drive_{drive + 1}'" in messages[0]


@pytest.mark.parametrize("name", ["planar_4rrr", "delta_3rus", "hexapod_6ups"])
def test_warm_started_along_a_path_equals_python(name):
    """The estimator's use: each call starts at the previous solution's configuration (the compiled
    loop then reuses its kept pose, T and K⁺), on quantized readings along the robot's path; every
    tenth call starts at a configuration the compiled loop has not seen (a cache miss)."""
    robot = ParallelRobot.load(name)
    compiled = compiled_forward(robot)
    res = drive_resolution(robot)
    kind = "s-curve" if name.startswith("planar") else "helix"
    ref = path_for(kind, robot.home_pose, robot.output_angular, 0.4)
    q_true, q_py, q_cc = robot.q_home, robot.q_home, robot.q_home
    for k in range(200):
        q_true = robot.assemble(ref.pose(k * 0.002), q_true)
        readings = np.round(q_true[robot.drive_q_indices] / res) * res
        if k % 10 == 9:
            q_py = q_cc = robot.assemble(robot.platform_pose(q_cc) + 1e-4, q_cc)
        py = solve_forward(robot, readings, res, q_py, compiled=None)
        cc = solve_forward(robot, readings, res, q_cc, compiled=compiled)
        assert_same(py, cc)
        q_py, q_cc = py.q, cc.q


def _message(robot, monkeypatch, native, *args):
    monkeypatch.setenv("PARALLEL_GPC_NATIVE", "1" if native else "0")
    with pytest.raises(ParallelGPCError) as info:
        robot.forward_solution(*args)
    return type(info.value), str(info.value)


def test_bad_input_gives_the_python_paths_error(robot4, monkeypatch):
    """What the compiled checks refuse is redone on the Python path: the same error and message."""
    readings = robot4.inverse_kinematics(robot4.home_pose)
    nan, far, bad_q = readings.copy(), readings.copy(), robot4.q_home.copy()
    nan[1] = np.nan
    far[0] = robot4.drive_range[1][0] + 1.0
    bad_q[3] = np.inf
    cases = [(nan,), (far,), (readings, bad_q), (readings, None, -1e-6), (readings, None, [1e-6, np.nan, 1e-6, 1e-6]),
             (readings[:3],), (readings[:, None],)]
    calls = []
    real = solve_forward.__globals__["_gauss_newton"]
    monkeypatch.setitem(solve_forward.__globals__, "_gauss_newton", lambda *a: calls.append(1) or real(*a))
    for args in cases:
        compiled = _message(robot4, monkeypatch, True, *args)
        assert compiled == _message(robot4, monkeypatch, False, *args)
    assert calls == []  # the errors came from the checks, not from a loop on bad input
