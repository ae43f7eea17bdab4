"""Idle motions locked at load (:mod:`parallel_gpc.model.idle`): a coaxial revolute pair and a rod
between two ball joints, each in a 5-bar written here. Loading locks one joint per idle motion
(with a :class:`~parallel_gpc.errors.ParallelGPCWarning`), the locked model's reduced dynamics
equal ``pin.constraintDynamics`` of the locked model, ``idle_spins = "refuse"`` keeps the refusal,
and an under-actuation that moves the output or a drive is never locked."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pinocchio as pin
import pytest

from parallel_gpc import ParallelRobot, cli
from parallel_gpc.errors import ParallelGPCWarning, RobotFormatError, UnderactuatedError

import mechanisms as mech

#: a small body whose centre of mass is on the spin axis (kg, kg·m²)
SMALL = '<inertial><mass value="0.05"/><inertia ixx="2e-5" ixy="0" ixz="0" iyy="2e-5" iyz="0" izz="1e-5"/></inertial>'
LIMIT = '<limit lower="-6" upper="6" effort="10" velocity="10"/>'


def _revolute(name: str, parent: str, child: str, axis: str, origin: str = "") -> str:
    return (f'  <joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>{origin}'
            f'<axis xyz="{axis}"/>{LIMIT}</joint>\n')


def coaxial_fivebar(tmp_path, extra: str = ""):
    """The 5-bar of :mod:`mechanisms` whose leg 2 ends in two coaxial hinges ``s1``, ``s2`` (axis y,
    through the tip) and is welded to the end-effector: the body between the hinges spins idly."""
    urdf = mech.fivebar_urdf().replace("</robot>", (
        _revolute("s1", "tip2", "spin", "0 1 0") + f'  <link name="spin">{SMALL}</link>\n'
        + _revolute("s2", "spin", "tip2w", "0 1 0") + f'  <link name="tip2w">{SMALL}</link>\n</robot>'))
    q = mech.fivebar_q_guess()
    turn = math.remainder(q["a1"] + q["e1"] - q["a2"] - q["e2"], 2 * math.pi)
    toml = (mech.fivebar_sidecar(extra=extra, closures=False).replace("[drives]", f"s1 = {turn!r}\ns2 = 0.0\n[drives]")
            + '[[closures]]\nname = "close"\nkind = "weld"\nframes = ["ee", "tip2w"]\n')
    return mech.write(tmp_path, "coaxial", urdf, toml)


def ball_rod_fivebar(tmp_path, extra: str = ""):
    """The 5-bar whose distal link 2 hangs on a ball joint at elbow 2 (three hinges ``b_y``, ``b_x``,
    ``b_z``; the rod lies along the last one's axis) and whose tip meets the end-effector in a point
    closure (the second ball): the rod spins idly about its axis."""
    urdf = mech.fivebar_urdf()
    elbow = urdf.index('<joint name="e2"')
    urdf = urdf[:elbow] + urdf[elbow:].replace('<joint name="e2" type="revolute"><parent link="prox2"/><child link="dist2"/>',
                                               '<joint name="b_y" type="revolute"><parent link="prox2"/><child link="ball1"/>', 1)
    urdf = urdf.replace("</robot>", (
        f'  <link name="ball1">{SMALL}</link>\n' + _revolute("b_x", "ball1", "ball2", "1 0 0")
        + f'  <link name="ball2">{SMALL}</link>\n' + _revolute("b_z", "ball2", "dist2", "0 0 1") + "</robot>"))
    q = mech.fivebar_q_guess()
    toml = mech.fivebar_sidecar(extra=extra).replace(f"e2 = {q['e2']!r}", f"b_y = {q['e2']!r}\nb_x = 0.0\nb_z = 0.0")
    toml = toml.replace('branch_joints = ["e1", "e2"]', 'branch_joints = ["e1"]')
    return mech.write(tmp_path, "ballrod", urdf, toml)


def _load_locked(path):
    with pytest.warns(ParallelGPCWarning, match=r"1 idle motion\(s\) .* locked: ") as record:
        robot = ParallelRobot.load(path)
    return robot, str(record[0].message)


@pytest.mark.parametrize("build, locked", [(coaxial_fivebar, "s2"), (ball_rod_fivebar, "b_z")])
def test_idle_motion_is_locked_and_the_locked_model_matches_constraint_dynamics(tmp_path, build, locked):
    robot, notice = _load_locked(build(tmp_path))
    assert robot.description.locked_joints == (locked,)
    assert f"{locked!r} at " in notice and 'idle_spins = "refuse"' in notice
    assert not robot.model.existJointName(locked)  # welded at its assembled value
    assert (robot.n_y, robot.n_u) == (2, 2)
    mech.assert_reduced_matches_constraint_dynamics(robot)  # pin.constraintDynamics of the locked model


def test_the_locked_joint_is_the_one_along_the_idle_motion(tmp_path):
    """Rod between two balls: the hinge locked turns about the rod's own axis at home (the spin)."""
    robot, _ = _load_locked(ball_rod_fivebar(tmp_path))
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, robot.q_home)
    rod = data.oMf[robot.model.getFrameId("tip2")].translation - data.oMf[robot.model.getFrameId("dist2")].translation
    z_axis = data.oMf[robot.model.getFrameId("dist2")].rotation[:, 2]  # b_z turns about the rod frame's z
    assert abs(abs(rod @ z_axis) - np.linalg.norm(rod)) <= 1e-9 * np.linalg.norm(rod)


@pytest.mark.parametrize("build", [coaxial_fivebar, ball_rod_fivebar])
def test_idle_spins_refuse_keeps_the_under_actuation_error(tmp_path, build):
    with warnings.catch_warnings():
        warnings.simplefilter("error", ParallelGPCWarning)
        with pytest.raises(UnderactuatedError, match=r"not determined by the output|can move along") as refused:
            ParallelRobot.load(build(tmp_path, extra='idle_spins = "refuse"\n'))
    message = str(refused.value)
    assert 'set idle_spins = "lock" in the sidecar' in message  # the sidecar option that locks it, not by hand
    assert "FIXED" not in message and "fix a joint" not in message


def test_a_bad_idle_spins_value_is_one_clear_error(tmp_path):
    with pytest.raises(RobotFormatError, match=r"idle_spins = 'maybe' is not one of \['lock', 'refuse'\]"):
        ParallelRobot.load(coaxial_fivebar(tmp_path, extra='idle_spins = "maybe"\n'))


def test_a_yaml_sidecar_takes_idle_spins_too(tmp_path):
    """The Gepetto-style YAML sidecar reads the same key."""
    path = coaxial_fivebar(tmp_path)
    import tomllib
    import yaml

    data = tomllib.loads(path.with_suffix(".toml").read_text())
    path.with_suffix(".toml").unlink()
    gepetto = {"closed_loop": [["ee", "tip2w"]], "type": ["6d"], "name_mot": ["a1", "a2"], "output": data["output"],
               "home": data["home"], "idle_spins": "refuse"}
    path.with_suffix(".yaml").write_text(yaml.safe_dump(gepetto))
    with pytest.raises(UnderactuatedError):
        ParallelRobot.load(path)
    gepetto["idle_spins"] = "lock"
    path.with_suffix(".yaml").write_text(yaml.safe_dump(gepetto))
    robot, _ = _load_locked(path)
    assert robot.description.locked_joints == ("s2",)


def test_a_motion_that_moves_a_drive_is_not_idle_and_stays_refused(tmp_path):
    """One output (x) for the 2-DOF 5-bar: the free motion moves the drives, so nothing is locked."""
    path = mech.write(tmp_path, "fb1", mech.fivebar_urdf(), mech.fivebar_sidecar(axes=("x",)))
    with warnings.catch_warnings():
        warnings.simplefilter("error", ParallelGPCWarning)
        with pytest.raises(RobotFormatError, match="does not parametrize"):
            ParallelRobot.load(path)


def test_info_lists_the_locked_joints(tmp_path, capsys):
    """``info`` says what was locked: a row of its table and the notice as one line on stderr."""
    path = coaxial_fivebar(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("always", ParallelGPCWarning)
        assert cli.main(["info", str(path)]) == 0
    out, err = capsys.readouterr()
    line = next(x for x in out.splitlines() if x.strip().startswith("locked joints"))
    assert "s2 = " in line
    notes = [x for x in err.splitlines() if "idle motion(s)" in x]
    assert len(notes) == 1 and notes[0].startswith("parallel-gpc: note: robot 'fivebar': 1 idle motion(s)"), err


def test_a_command_that_loads_the_robot_twice_says_the_notice_once(tmp_path, capsys):
    """``track`` loads the robot for the controller and for the plant: the idle-lock notice prints once."""
    path = coaxial_fivebar(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("always", ParallelGPCWarning)
        code = cli.main(["track", "--robot", str(path), "--forms", "absolute", "--reference", "hold",
                         "--duration", "0.02", "--out", str(tmp_path / "out")])
    out, err = capsys.readouterr()
    assert code == 0, err
    notes = [x for x in err.splitlines() if "idle motion(s)" in x]
    assert len(notes) == 1, err
