"""Robot loading, assembly, kinematics and the sidecar formats."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from parallel_gpc import ParallelRobot, load_description
from parallel_gpc.errors import RobotFormatError, UnreachablePoseError, ParallelGPCError
from parallel_gpc.model.robot import urdf_dir

from conftest import POSE_A, POSE_B


def test_embedded_robots_have_expected_sizes(robot4, robot3):
    assert (robot4.n_y, robot4.n_u, robot4.model.nq) == (3, 4, 11)
    assert (robot3.n_y, robot3.n_u, robot3.model.nq) == (3, 3, 9)


def test_assembly_residual_on_grid_covering_a_to_b(robot):
    xs = np.linspace(POSE_A[0], POSE_B[0], 7)
    psis = np.linspace(POSE_A[2], POSE_B[2], 5)
    q = None
    for x in xs:
        for y in xs:
            for psi in psis:
                q = robot.assemble([x, y, psi], q)
                assert np.max(np.abs(robot.closure_residual(q))) <= 1e-10
                np.testing.assert_allclose(robot.platform_pose(q), [x, y, psi], atol=1e-14)
                np.testing.assert_array_equal(robot.branch_signature(q), robot.branch_signature(robot.q_home))


def test_assembly_without_warm_start_matches_warm_started(robot):
    q_cold = robot.assemble(POSE_B)
    q_warm = robot.assemble(POSE_B, robot.assemble(POSE_B + 0.01))
    np.testing.assert_allclose(q_cold, q_warm, atol=1e-10)


@pytest.mark.parametrize("pose", [[2.5, 0.5, 0.0], [0.5, -1.0, 0.0], [0.5, 1.7, 0.3]])
def test_unreachable_pose_raises_error_naming_the_pose(robot4, pose):
    with pytest.raises(UnreachablePoseError) as info:
        robot4.assemble(pose)
    assert str(pose[0]) in str(info.value) and str(pose[1]) in str(info.value)


def test_inverse_then_forward_kinematics_round_trip(robot):
    for pose in (POSE_A, POSE_B, 0.5 * (POSE_A + POSE_B)):
        drives = robot.inverse_kinematics(pose)
        np.testing.assert_allclose(robot.forward_kinematics(drives), pose, atol=1e-10)


def test_closure_jacobian_matches_finite_differences(robot4):
    q = robot4.assemble(POSE_A)
    J = robot4.closure_kinematics(q).jacobian
    eps = 1e-7
    for i in range(robot4.model.nv):
        d = np.zeros(robot4.model.nv)
        d[i] = eps
        fd = (robot4.closure_residual(q + d) - robot4.closure_residual(q - d)) / (2 * eps)
        np.testing.assert_allclose(J[:, i], fd, atol=1e-7)


def test_singularity_measures_are_moderate_on_a_to_b(robot):
    for s in np.linspace(0, 1, 11):
        cond = robot.singularity(robot.assemble(POSE_A + s * (POSE_B - POSE_A)))
        assert cond["cond_phi_z"] < 100 and cond["cond_B_r"] < 200


def test_gepetto_style_yaml_sidecar_loads_same_robot(tmp_path):
    shutil.copy(urdf_dir() / "planar_3rrr.urdf", tmp_path / "r3.urdf")
    (tmp_path / "r3.yaml").write_text(
        "closed_loop: [['tip_1', 'attach_1'], ['tip_2', 'attach_2'], ['tip_3', 'attach_3']]\n"
        "type: ['3D', '3D', '3D']\n"
        "name_mot: ['drive_1', 'drive_2', 'drive_3']\n"
        "joint_name: []\njoint_type: []\n"
        "output_joints: ['platform_x', 'platform_y', 'platform_psi']\n"
        "output_frame: platform\n"
        "home: {pose: [0.5, 0.5, 0.0], q_guess: {drive_1: -0.27, elbow_1: 2.1, drive_2: 1.3, "
        "elbow_2: 2.1, drive_3: -3.4, elbow_3: 2.1}}\n"
    )
    r = ParallelRobot.load(tmp_path / "r3.urdf")
    ref = ParallelRobot.load("planar_3rrr")
    assert r.n_u == 3 and len(r.description.closures) == 3
    np.testing.assert_allclose(r.assemble(POSE_B), ref.assemble(POSE_B), atol=1e-10)


def test_robot_file_errors_are_package_errors(tmp_path):
    shutil.copy(urdf_dir() / "planar_3rrr.urdf", tmp_path / "bad.urdf")
    (tmp_path / "bad.toml").write_text(
        'output = {joints = ["platform_x", "platform_y", "platform_psi"]}\n'
        'drives = {joints = ["drive_1", "drive_2", "drive_3"]}\n'
        '[[closures]]\nframes = ["tip_1", "no_such_frame"]\n'
    )
    with pytest.raises(RobotFormatError, match="no_such_frame"):
        ParallelRobot.load(tmp_path / "bad.urdf")
    with pytest.raises(RobotFormatError, match="nosuch"):
        load_description("nosuch")
    assert issubclass(RobotFormatError, ParallelGPCError)


def test_mass_scale_scales_reduced_mass_matrix(robot4):
    from parallel_gpc import ReducedModel

    heavy = robot4.with_mass_scale(1.2)
    X = np.concatenate([POSE_A, np.zeros(3)])
    Mr = ReducedModel(robot4).terms(X).M_r
    np.testing.assert_allclose(ReducedModel(heavy).terms(X).M_r, 1.2 * Mr, rtol=1e-12)


@pytest.mark.parametrize("edit, match", [
    (lambda s: "frobnicate = 1\n" + s, r"unknown key\(s\) \['frobnicate'\] in the top level; accepted keys are"),
    (lambda s: s.replace("[output]\n", "[output]\nframes = 'x'\n"), r"unknown key\(s\) \['frames'\] in \[output\]"),
    (lambda s: s.replace("[home]\n", "[home]\nposes = [0, 0, 0]\n"), r"unknown key\(s\) \['poses'\] in \[home\]"),
    (lambda s: s.replace("[drives]\n", "[drives]\nlimit = 3\n"), r"unknown key\(s\) \['limit'\] in \[drives\]"),
    (lambda s: s.replace('kind = "point"', 'kind = "point"\nframe = "a"', 1), r"\['frame'\] in closure 1"),
    (lambda s: s.replace("[output]\n", "[output]\nkind = 'orientation'\n"), r"output kind 'orientation' is not one of"),
    (lambda s: 'root = "floating"\n' + s, r"root = 'floating' is not one of \['fixed', 'free_flyer'\]"),
])
def test_unknown_sidecar_keys_and_values_are_errors(tmp_path, edit, match):
    shutil.copy(urdf_dir() / "planar_3rrr.urdf", tmp_path / "r3.urdf")
    (tmp_path / "r3.toml").write_text(edit((urdf_dir() / "planar_3rrr.toml").read_text()))
    with pytest.raises(RobotFormatError, match=match):
        ParallelRobot.load(tmp_path / "r3.urdf")


def test_gepetto_sidecar_with_unknown_key_or_joint_type_is_refused(tmp_path):
    shutil.copy(urdf_dir() / "planar_3rrr.urdf", tmp_path / "r3.urdf")
    base = ("closed_loop: [['tip_1', 'attach_1'], ['tip_2', 'attach_2'], ['tip_3', 'attach_3']]\n"
            "type: ['3D', '3D', '3D']\nname_mot: ['drive_1', 'drive_2', 'drive_3']\n"
            "output_joints: ['platform_x', 'platform_y', 'platform_psi']\n")
    (tmp_path / "r3.yaml").write_text(base + "joint_names: ['elbow_1']\n")
    with pytest.raises(RobotFormatError, match=r"unknown key\(s\) \['joint_names'\]"):
        ParallelRobot.load(tmp_path / "r3.urdf")
    (tmp_path / "r3.yaml").write_text(base + "joint_name: ['elbow_1']\njoint_type: ['CARDAN']\n")
    with pytest.raises(RobotFormatError, match=r"joint 'elbow_1' has unknown joint_type 'CARDAN'"):
        ParallelRobot.load(tmp_path / "r3.urdf")


def test_every_embedded_sidecar_uses_only_accepted_keys():
    from parallel_gpc.model.description import embedded_robots

    for name in embedded_robots():
        robot = ParallelRobot.load(name)
        assert robot.n_u >= robot.n_y and robot.redundancy == robot.n_u - robot.n_y


def test_embedded_planar_robots_report_redundancy(robot4, robot3):
    assert (robot4.redundancy, robot3.redundancy) == (1, 0)
    assert "redundancy=1" in repr(robot4) and "redundancy" not in repr(robot3)


def test_sidecar_default_plan_poses_are_read_and_checked(tmp_path):
    shutil.copy(urdf_dir() / "planar_3rrr.urdf", tmp_path / "r3.urdf")
    text = (urdf_dir() / "planar_3rrr.toml").read_text()
    (tmp_path / "r3.toml").write_text(text.replace("[home]\n", "[home]\nA = [0.2, 0.2, -0.3]\nB = [0.8, 0.8, 0.3]\n"))
    d = load_description(tmp_path / "r3.urdf")
    assert d.pose_a == (0.2, 0.2, -0.3) and d.pose_b == (0.8, 0.8, 0.3)
    (tmp_path / "r3.toml").write_text(text.replace("[home]\n", "[home]\nA = [0.2, 0.2]\n"))
    with pytest.raises(RobotFormatError, match=r"home.A = \[0.2, 0.2\] must hold 3 finite numbers"):
        load_description(tmp_path / "r3.urdf")


def test_output_units_are_checked_not_ignored(tmp_path):
    shutil.copy(urdf_dir() / "planar_3rrr.urdf", tmp_path / "r3.urdf")
    text = (urdf_dir() / "planar_3rrr.toml").read_text()
    (tmp_path / "r3.toml").write_text(text.replace('units = ["m", "m", "rad"]', 'units = ["m", "m", "deg"]'))
    with pytest.raises(RobotFormatError, match=r"units = \['m', 'm', 'deg'\] do not match .* \['m', 'm', 'rad'\]"):
        ParallelRobot.load(tmp_path / "r3.urdf")


def test_drive_unit_follows_the_drive_joint_type():
    from parallel_gpc.studies import metrics_table

    assert ParallelRobot.load("planar_4rrr").drive_unit == "N·m"   # revolute drives: torques
    hexapod = ParallelRobot.load("hexapod_6ups")
    assert hexapod.drive_unit == "N"                                # prismatic drives: forces
    assert "[N]" in metrics_table({}, hexapod.drive_unit).splitlines()[1]


def test_a_near_singular_home_warns_and_a_singular_one_is_refused(tmp_path):
    """Field test: a home configuration at a singularity loaded without a word. A 3-PRR whose
    rods are nearly radial (their lines almost meet at the platform centre: the drives barely
    turn the platform) warns, naming the configuration and σ_min(B_r); exactly radial rods are
    refused; the 3-PRR of the docs loads silently."""
    import warnings

    import mechanisms as mech
    from parallel_gpc.errors import ParallelGPCWarning, UnderactuatedError

    def load(rod_angle, stem):
        return ParallelRobot.load(mech.write(tmp_path, stem, mech.prr3_urdf(rod_angle), mech.prr3_sidecar()))

    with pytest.warns(ParallelGPCWarning, match=r"'prr3_test': the home configuration \(pose \[0.0, 0.0, 0.0\]; "
                                                r"drives s1 = 0, s2 = 0, s3 = 0\) is near-singular: σ_min\(B_r\) = "
                                                r".* along \[rz: \+1.000\]") as record:
        robot = load(1e-5, "prr3_near")
    # the number named is B_r's: its smallest singular value, computed here independently
    T, _ = robot.velocity_map(robot.q_home)
    s = np.linalg.svd(T.T @ robot.drive_selection, compute_uv=False)
    assert s[0] / s[-1] > 1e4
    assert f"σ_min(B_r) = {s[-1]:.3g}" in str(record[0].message)
    with pytest.raises(UnderactuatedError, match=r"rank\(B_r\) = 2 of its 3 DOF"):
        load(0.0, "prr3_radial")
    with warnings.catch_warnings():
        warnings.simplefilter("error", ParallelGPCWarning)
        assert load(mech.PRR_ROD_ANGLE, "prr3_ok").singularity(robot.q_home)["cond_B_r"] < 100
