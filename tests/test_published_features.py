"""Features of published robot files (issue 20, the Gepetto example-parallel-robots collection):
``package://`` meshes and a package path, point masses and massless ``<inertial>`` blocks,
universal joints with named axes (``UJOINT_XY`` … ``UJOINT_ZY``), and the checks that stay
(invalid inertias, kinematic cycles, YAML aliases, two sidecars of one stem). Every file is
written here; the collection itself is not copied into the project."""

from __future__ import annotations

import math
import os

import numpy as np
import pinocchio as pin
import pytest

from parallel_gpc import ParallelRobot, ReducedModel, cli
from parallel_gpc.errors import RobotFormatError
from parallel_gpc.model.description import urdf_dir
from parallel_gpc.model.meshes import PACKAGE_PATH_ENV, ROS_PACKAGE_PATH_ENV
from parallel_gpc.model.universal import UniversalJoints

import mechanisms as mech
import mechanisms_ups as ups

#: one leg per axis pair: every ordered pair of distinct coordinate axes
PAIRS = ("XY", "YZ", "ZY", "ZX", "XZ", "YX")
MESHES = {  # URI in the file -> where it must resolve ("robot", "package") or None (unresolved)
    "package:///local.stl": "robot",  # Gepetto's empty package name: the robot's folder
    "package://tools/meshes/leg.stl": "package",
    "meshes/rel.stl": "robot",
    "package://missing/x.stl": None,
    "../outside.stl": None,  # exists, but outside the robot's folder
    "meshes/link.stl": None,  # a symlink inside the folder to a file outside
    "file:///etc/passwd": None,
    "package://tools/../../outside.stl": None,  # escapes its package root
    "http://example.com/m.stl": None,
}


def _visuals(uris) -> str:
    return "".join(f'<visual><geometry><mesh filename="{u}"/></geometry></visual>' for u in uris)


@pytest.fixture(autouse=True)
def _no_package_env(monkeypatch):
    monkeypatch.delenv(PACKAGE_PATH_ENV, raising=False)
    monkeypatch.delenv(ROS_PACKAGE_PATH_ENV, raising=False)


@pytest.fixture(scope="module")
def published(tmp_path_factory):
    """(universal joints UJOINT_AB of every pair with point-mass rods and meshes, the same
    mechanism with two revolutes per U joint and massless cross links, package folder)."""
    top = tmp_path_factory.mktemp("published")
    robot_dir, packages = top / "robot", top / "packages"
    (robot_dir / "meshes").mkdir(parents=True)
    (packages / "tools" / "meshes").mkdir(parents=True)
    for path in (robot_dir / "local.stl", robot_dir / "meshes" / "rel.stl", packages / "tools" / "meshes" / "leg.stl",
                 top / "outside.stl"):
        path.write_text("solid m\nendsolid m\n")
    os.symlink(top / "outside.stl", robot_dir / "meshes" / "link.stl")
    extras = {"cyl1": _visuals(MESHES)}
    uni = mech.write(robot_dir, "ups_pairs", ups.ups_urdf(True, PAIRS, extras), ups.ups_sidecar(True, PAIRS),
                     ".urdf", ".yaml")
    rr = mech.write(robot_dir, "ups_pairs_rr", ups.ups_urdf(False, PAIRS), ups.ups_sidecar(False, PAIRS),
                    ".urdf", ".yaml")
    return ParallelRobot.load(uni, package_path=packages), ParallelRobot.load(rr), packages


def test_every_axis_pair_builds_a_universal_joint_about_its_axes(published):
    uni, _, _ = published
    for k, pair in enumerate(PAIRS, start=1):
        jm = uni.model.joints[uni.model.getJointId(f"u{k}")]
        assert jm.shortname() == "JointModelUniversal"
        jd = jm.createData()
        jm.calc(jd, np.zeros(uni.model.nq))  # the joint reads its own rows of q
        S = np.asarray(jd.S)  # (6, 2) motion subspace at q = 0, joint frame: angular rows 3:6
        np.testing.assert_allclose(S[3:, 0], np.eye(3)["XYZ".index(pair[0])], atol=1e-15)
        np.testing.assert_allclose(S[3:, 1], np.eye(3)["XYZ".index(pair[1])], atol=1e-15)
    assert (uni.n_y, uni.n_u, uni.redundancy) == (6, 6, 0)


def test_point_masses_and_massless_inertials_load_with_their_masses(published):
    uni, rr, _ = published
    rod = uni.model.inertias[uni.model.getJointId("p1")]
    assert rod.mass == pytest.approx(ups.M_ROD) and not np.asarray(rod.inertia).any()  # a point mass
    cross = rr.model.inertias[rr.model.getJointId("u1a")]
    assert cross.mass == 0.0  # <inertial> with mass 0: a massless frame
    np.testing.assert_allclose(uni.home_pose, rr.home_pose, atol=1e-12)


def test_reduced_accelerations_equal_constraint_dynamics_for_every_axis_pair(published):
    mech.assert_reduced_matches_constraint_dynamics(published[0], n=6, seed=31)


def test_universal_pairs_and_two_revolutes_give_the_same_reduced_dynamics(published):
    uni, rr, _ = published
    np.testing.assert_allclose(uni.home_pose, [0, 0, ups.UPS_H, 0, 0, 0], atol=1e-9)
    mech.assert_same_reduced_dynamics(uni, rr, n=5, seed=32)


def test_universal_pair_derivatives_match_finite_differences(published):
    uni = published[0]
    model, data = uni.model, uni.model.createData()
    universal = UniversalJoints(model)
    lwa = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    frames = [model.getFrameId(n) for n in ("platform", "tip3", "tip4", "tip6")]

    def jacobians(q):
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        return [pin.getFrameJacobian(model, data, f, lwa).copy() for f in frames]

    rng, eps = np.random.default_rng(33), 1e-6
    reduced = ReducedModel(uni)
    for X in mech.random_output_states(uni, rng, 2, speed=1.0):
        q, v = reduced.terms(X).q, rng.uniform(-1, 1, model.nv)
        plus, minus = jacobians(pin.integrate(model, q, eps * v)), jacobians(pin.integrate(model, q, -eps * v))
        pin.computeJointJacobiansTimeVariation(model, data, q, v)
        pin.updateFramePlacements(model, data)
        for f, Jp, Jm in zip(frames, plus, minus):
            np.testing.assert_allclose(universal.frame_jacobian_rate(model, data, f, v), (Jp - Jm) / (2 * eps),
                                       atol=1e-7)
        W, zero = rng.uniform(-1, 1, (model.nv, 2)), np.zeros(model.nv)
        fd = np.column_stack([(pin.rnea(model, data, q, v + eps * w, zero) - pin.rnea(model, data, q, v - eps * w, zero))
                              / (2 * eps) for w in W.T])
        np.testing.assert_allclose(universal.bias_derivative(model, q, v, W), fd, rtol=1e-7, atol=1e-7)
        # h_r is quadratic in ẏ with C_r = ½ ∂h_r/∂ẏ: ∂ÿ/∂ẏ (central differences of ÿ) = 2 A₂₂ of (3)
        u = rng.uniform(-5, 5, uni.n_u)
        A_fd, _, _ = reduced.linearize(X, u, eps=1e-6)
        A, _, _ = reduced.factorize(X)
        n = uni.n_y
        np.testing.assert_allclose(A_fd[n:, n:], 2 * A[n:, n:], rtol=1e-5, atol=1e-6 * np.abs(A[n:, n:]).max())


def test_meshes_resolve_only_inside_the_robot_folder_or_a_package_root(published):
    uni, _, packages = published
    folder = uni.description.urdf_path.resolve().parent
    where = {"robot": folder, "package": packages.resolve()}
    expected = {u: w for u, w in MESHES.items() if w is not None}
    assert set(uni.description.mesh_files) == set(expected)
    for uri, root in expected.items():
        assert uni.description.mesh_files[uri].is_relative_to(where[root])
    assert uni.description.unresolved_meshes == tuple(u for u, w in MESHES.items() if w is None)


def test_info_counts_mesh_references_distinct_files_and_missing_ones_apart(tmp_path, capsys):
    """Field test: ``info`` said "2 resolved" for a file whose links drew two files many times.
    References (mesh elements), distinct files (two URIs may name one file) and missing
    references are three numbers."""
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "rel.stl").write_text("solid m\nendsolid m\n")
    uris = ["meshes/rel.stl", "meshes/rel.stl", "./meshes/rel.stl", "package://missing/x.stl",
            "package://missing/x.stl"]
    path = mech.write(tmp_path, "ups_mesh_counts", ups.ups_urdf(True, PAIRS, {"cyl1": _visuals(uris)}),
                      ups.ups_sidecar(True, PAIRS), ".urdf", ".yaml")
    d = ParallelRobot.load(path).description
    assert d.mesh_references == tuple(uris)
    assert d.mesh_counts == {"references": 5, "files": 1, "missing": 2, "missing_uris": 1}
    assert cli.main(["info", str(path)]) == 0
    meshes = next(line for line in capsys.readouterr().out.splitlines() if line.strip().startswith("meshes"))
    assert "5 references to 1 distinct file, 2 references missing (1 URI)" in meshes, meshes


def test_the_package_path_comes_from_the_environment_then_ros(published, monkeypatch, tmp_path):
    uni, _, packages = published
    path = uni.description.urdf_path
    for variable in (PACKAGE_PATH_ENV, ROS_PACKAGE_PATH_ENV):
        monkeypatch.setenv(variable, str(packages))
        assert "package://tools/meshes/leg.stl" in ParallelRobot.load(path).description.mesh_files
        monkeypatch.delenv(variable)
    assert "package://tools/meshes/leg.stl" in ParallelRobot.load(path).description.unresolved_meshes
    monkeypatch.setenv(ROS_PACKAGE_PATH_ENV, str(tmp_path / "gone"))  # ROS's list may name missing folders
    assert ParallelRobot.load(path).description.package_path == ()
    monkeypatch.setenv(PACKAGE_PATH_ENV, str(tmp_path / "gone"))  # ours may not
    with pytest.raises(RobotFormatError, match=rf"{PACKAGE_PATH_ENV} entry .*gone.* not an existing folder"):
        ParallelRobot.load(path)
    monkeypatch.delenv(PACKAGE_PATH_ENV)
    with pytest.raises(RobotFormatError, match=r"package_path entry .*nowhere.* not an existing folder"):
        ParallelRobot.load(path, package_path=tmp_path / "nowhere")


def test_a_robot_with_unresolved_meshes_is_drawn_as_a_stick_figure(published):
    """Issue 20: meshes that do not resolve are never read; the view draws every link as the stick
    figure and says so in one line (it refused the robot before)."""
    from parallel_gpc.errors import ParallelGPCWarning
    from parallel_gpc.viz.scene import StickFigure, visual_model

    robot = published[0]
    with pytest.warns(ParallelGPCWarning, match=r"stick figure: 6 mesh\(es\) \('package://missing/x.stl'.*do not resolve"):
        geom = visual_model(robot)
    assert len(geom.geometryObjects) == 0
    stick = StickFigure(robot, geom)
    assert len(stick.joints) >= robot.model.njoints - 1 - robot.n_y and stick.rods


# ---------------------------------------------------------------- what stays refused
URDF = (urdf_dir() / "planar_3rrr.urdf").read_text()
TOML = (urdf_dir() / "planar_3rrr.toml").read_text()
INERTIA = '<inertia ixx="0.028125" ixy="0" ixz="0" iyy="0.028125" iyz="0" izz="0.05625"/>'
REVOLUTE = 'type="revolute"><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/>'


def _joint(name: str, parent: str, child: str) -> str:
    return f'<joint name="{name}" {REVOLUTE}<parent link="{parent}"/><child link="{child}"/></joint>'


def _write(tmp_path, urdf: str, toml: str = TOML, stem: str = "r") -> str:
    (tmp_path / f"{stem}.urdf").write_text(urdf)
    (tmp_path / f"{stem}.toml").write_text(toml)
    return str(tmp_path / f"{stem}.urdf")


@pytest.mark.parametrize("inertia, needles", [
    (INERTIA.replace('ixy="0"', 'ixy="0.5"'), ["'ixy': 0.5", "positive semi-definite"]),
    (INERTIA.replace('0.028125', '0.01'), ["'ixx': 0.01", "triangle inequality"]),
    (INERTIA.replace('izz="0.05625"', 'izz="-1e-3"'), ["'izz': -0.001", "semi-definite"]),
])
def test_invalid_inertias_stay_refused(tmp_path, inertia, needles):
    with pytest.raises(RobotFormatError) as info:
        ParallelRobot.load(_write(tmp_path, URDF.replace(INERTIA, inertia, 1)))
    assert all(n in str(info.value) for n in needles), str(info.value)


def test_a_point_mass_platform_loads_and_matches_the_kkt_equations(tmp_path):
    zero = '<inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/>'
    robot = ParallelRobot.load(_write(tmp_path, URDF.replace(INERTIA, zero, 1)))
    model, data = robot.model, robot.model.createData()
    lwa = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    reduced, rng = ReducedModel(robot), np.random.default_rng(34)
    for X in mech.random_output_states(robot, rng, 4):
        u = rng.uniform(-5, 5, robot.n_u)
        terms = reduced.terms(X)
        q, v = terms.q, terms.v
        M = pin.crba(model, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        # the open tree's ψ direction has no inertia at all: M is singular (pin.constraintDynamics
        # returns NaN here), the closed chain is not; the oracle is the KKT system of the closures
        assert np.linalg.eigvalsh(M)[0] < 1e-12
        h = pin.rnea(model, data, q, v, np.zeros(model.nv))
        pin.computeJointJacobians(model, data, q)
        pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
        pin.updateFramePlacements(model, data)
        J = np.vstack([(pin.getFrameJacobian(model, data, a, lwa) - pin.getFrameJacobian(model, data, b, lwa))[:3]
                       for a, b, _ in robot.closure_frames])
        gamma = np.concatenate([pin.getFrameClassicalAcceleration(model, data, a, lwa).linear
                                - pin.getFrameClassicalAcceleration(model, data, b, lwa).linear
                                for a, b, _ in robot.closure_frames])
        U, s, W = np.linalg.svd(J, full_matrices=False)  # planar point closures: the z rows are zero
        rows = int(np.count_nonzero(s > 1e-10 * s[0]))
        Jr, gr = s[:rows, None] * W[:rows], U[:, :rows].T @ gamma
        K = np.block([[M, Jr.T], [Jr, np.zeros((rows, rows))]])
        assert np.linalg.cond(K) < 1e8
        ddq = np.linalg.solve(K, np.concatenate([robot.drive_selection @ u - h, -gr]))[:model.nv]
        a = terms.T @ terms.acceleration(u) + terms.ell
        assert np.linalg.norm(a - ddq) <= 1e-9 * np.linalg.norm(ddq)


@pytest.mark.parametrize("joints, needles", [
    (_joint("extra", "world", "platform"), ["link 'platform' is the child of two joints", "'extra'"]),
    (_joint("self", "attach_1", "attach_1"), ["joint 'self' joins link 'attach_1' to itself"]),
    (_joint("dangling", "world", "nowhere"), ["joint 'dangling' child link = 'nowhere'", "not a declared <link>"]),
])
def test_a_urdf_that_is_not_a_tree_is_refused_before_pinocchio(tmp_path, capfd, joints, needles):
    path = _write(tmp_path, URDF.replace("</robot>", joints + "</robot>"))
    capfd.readouterr()
    assert cli.main(["info", path]) == 2
    err = capfd.readouterr().err.strip().splitlines()
    assert len(err) == 1 and all(n in err[0] for n in needles), err


def test_a_kinematic_cycle_without_root_is_named(tmp_path):
    links = "".join(f'<link name="{n}"/>' for n in "abc")
    cycle = _joint("j1", "a", "b") + _joint("j2", "b", "c") + _joint("j3", "c", "a")
    with pytest.raises(RobotFormatError, match=r"kinematic cycle through links \['a', 'c', 'b'\]|"
                                               r"kinematic cycle through links \[.*'a'.*\]"):
        ParallelRobot.load(_write(tmp_path, f'<robot name="cyc">{links}{cycle}</robot>'))


def test_yaml_aliases_are_refused_at_once(tmp_path):
    bomb = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    bomb += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, 10)]
    (tmp_path / "b.urdf").write_text(URDF)
    (tmp_path / "b.yaml").write_text("\n".join(bomb) + "\nclosed_loop: *a9\nname_mot: [drive_1]\n")
    assert len((tmp_path / "b.yaml").read_bytes()) < 1024
    with pytest.raises(RobotFormatError, match=r"b.yaml' line 2: YAML alias \*a0 is not accepted"):
        ParallelRobot.load(tmp_path / "b.urdf")


def test_two_sidecars_of_one_stem_are_ambiguous(tmp_path):
    path = _write(tmp_path, URDF)
    (tmp_path / "r.yaml").write_text("closed_loop: [[tip_1, attach_1]]\nname_mot: [drive_1]\n")
    with pytest.raises(RobotFormatError, match=r"r.toml' and .*r.yaml' are sidecars of the same robot side by side"):
        ParallelRobot.load(path)
    assert ParallelRobot.load(path, sidecar=tmp_path / "r.toml").n_y == 3  # naming one is fine


def test_a_branch_joint_stretched_at_home_is_refused(tmp_path):
    toml = TOML.replace('branch_joints = ["elbow_1", "elbow_2", "elbow_3"]',
                        'branch_joints = ["elbow_1", "platform_psi"]')
    with pytest.raises(RobotFormatError, match=r"branch joint 'platform_psi' is at q = 0 rad at the home pose.*"
                                               r"cannot tell the assembly branch"):
        ParallelRobot.load(_write(tmp_path, URDF, toml))


def test_the_cli_package_path_flag_resolves_package_meshes(published, tmp_path, capsys, monkeypatch):
    """``--package-path DIR`` (repeatable) resolves a ``package://`` mesh that resolves nowhere
    without it; a folder that does not exist is one error line, exit 2."""
    monkeypatch.setenv(PACKAGE_PATH_ENV, "")  # the flag sets it for the process: restored after the test
    uni, _, packages = published
    path = str(uni.description.urdf_path)
    uri = "package://tools/meshes/leg.stl"
    assert cli.main(["info", path]) == 0
    meshes = next(line for line in capsys.readouterr().out.splitlines() if line.strip().startswith("meshes"))
    assert uri in meshes and "9 references to 2 distinct files, 7 references missing (7 URIs)" in meshes, meshes
    assert cli.main(["info", path, "--package-path", str(tmp_path), "--package-path", str(packages)]) == 0
    meshes = next(line for line in capsys.readouterr().out.splitlines() if line.strip().startswith("meshes"))
    assert uri not in meshes and "9 references to 3 distinct files, 6 references missing (6 URIs)" in meshes, meshes
    assert os.environ.get(PACKAGE_PATH_ENV, "").split(os.pathsep)[:2] == [str(tmp_path.resolve()),
                                                                         str(packages.resolve())]
    assert cli.main(["info", path, "--package-path", str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err
    assert "nowhere" in err and "not an existing folder" in err and len(err.strip().splitlines()) == 1


def test_inconsistent_welds_are_refused_with_the_globalized_minimum(tmp_path):
    """The failure of Gepetto's kangaroo robots in small: a 6-D weld between frames drawn turned
    by 0.3 rad about x, in a planar 5-bar whose hinges all turn about y. As a point closure it
    loads; as a weld no configuration closes it, and the refusal says what the globalized solve
    reached: the 0.3 rad no joint can absorb (positions met)."""
    import re

    from parallel_gpc.errors import AssemblyError

    tip = '<child link="tip2"/>\n    <origin xyz="0 0 0.35"/>'
    urdf = mech.fivebar_urdf().replace(tip, tip.replace('"/>', '" rpy="0.3 0 0"/>'))
    assert 'rpy="0.3 0 0"' in urdf
    sidecar = re.sub(r"\[home\]\n.*\n\[home.q_guess\]\n(?:\w+ = .*\n)+", "", mech.fivebar_sidecar(closures=False))
    assert "q_guess" not in sidecar  # assembled from the drawing (q = 0), as the collection's files are

    def closure(kind):
        return sidecar + f'[[closures]]\nname = "close"\nkind = "{kind}"\nframes = ["ee", "tip2"]\n'

    robot = ParallelRobot.load(mech.write(tmp_path, "points", urdf, closure("point")))
    assert np.max(np.abs(robot.closure_residual(robot.q_home))) <= 1e-12
    with pytest.raises(AssemblyError, match="globalized least-squares solve") as info:
        ParallelRobot.load(mech.write(tmp_path, "weld", urdf, closure("weld")))
    message = str(info.value)
    reached = float(re.search(r"no closer than a residual of ([0-9.e+-]+)", message).group(1))
    assert abs(reached - 0.3) <= 1e-3, message
    assert "likely inconsistent" in message and "'close' ['ee', 'tip2']" in message


def test_a_weld_that_misses_at_home_is_reported_in_m_and_rad(tmp_path):
    """The same weld turned by 0.3 rad about x, with home.q_guess given (so home is assembled from
    the guess, not searched from the drawing): the refusal names the closure and says by how much
    it misses, positions in m and the rotation in rad apart (the positions meet: the hinges about y
    cannot absorb the 0.3 rad)."""
    import re

    from parallel_gpc.errors import AssemblyError

    tip = '<child link="tip2"/>\n    <origin xyz="0 0 0.35"/>'
    urdf = mech.fivebar_urdf().replace(tip, tip.replace('"/>', '" rpy="0.3 0 0"/>'))
    sidecar = mech.fivebar_sidecar(closures=False)
    assert "[home.q_guess]" in sidecar
    weld = sidecar + '[[closures]]\nname = "close"\nkind = "weld"\nframes = ["ee", "tip2"]\n'
    with pytest.raises(AssemblyError, match="cannot be assembled") as info:
        ParallelRobot.load(mech.write(tmp_path, "weld", urdf, weld))
    found = re.search(r"'close' \['ee', 'tip2'\] by ([0-9.e+-]+) m and ([0-9.e+-]+) rad", str(info.value))
    assert found is not None, str(info.value)
    assert float(found.group(1)) <= 1e-9 and abs(float(found.group(2)) - 0.3) <= 1e-3, str(info.value)


def test_the_globalized_solve_rescues_a_stalled_newton_on_a_robot_that_assembles(tmp_path, monkeypatch):
    """A 5-bar drawn (q = 0) with both legs stretched flat towards each other: the tips miss by
    0.9 m along x, and every joint moves them along z only, so Jᵀr = 0 and Newton's least-squares
    step from the drawing is zero (it stalls). The Levenberg–Marquardt starts perturbed from the
    drawing close the loop; the robot loads, assembled at its output. With the drawing
    as the only start it is refused: the perturbed starts are what rescue it."""
    import re

    from parallel_gpc.errors import AssemblyError, UnreachablePoseError
    from parallel_gpc.model import assembly
    from parallel_gpc.model.builder import drawn_configuration

    urdf = mech.fivebar_urdf()
    for k, turn in ((1, math.pi / 2), (2, -math.pi / 2)):  # leg 1 points to +x, leg 2 to -x at q = 0
        origin = f'<origin xyz="{mech.FIVEBAR_BASE[k - 1]} 0 0"/>'
        assert origin in urdf
        urdf = urdf.replace(origin, origin.replace('"/>', f'" rpy="0 {turn!r} 0"/>'))
    sidecar = re.sub(r"\[home\.q_guess\]\n(?:\w+ = .*\n)+", "", mech.fivebar_sidecar())
    assert "q_guess" not in sidecar  # assembled from the drawing
    path = mech.write(tmp_path, "flat", urdf, sidecar)

    # the oracle of the stall, from Pinocchio alone: at the drawing the residual is orthogonal to the Jacobian
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    q0 = pin.neutral(model)
    pin.computeJointJacobians(model, data, q0)
    pin.framesForwardKinematics(model, data, q0)
    ee, tip = model.getFrameId("ee"), model.getFrameId("tip2")
    r = data.oMf[ee].translation - data.oMf[tip].translation
    J = [pin.getFrameJacobian(model, data, f, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3] for f in (ee, tip)]
    assert abs(r[0] - 2 * (mech.L_PROX + mech.L_DIST - mech.FIVEBAR_BASE[1])) <= 1e-12 and abs(r[2]) <= 1e-12
    assert np.max(np.abs((J[0] - J[1]).T @ r)) <= 1e-12

    robot = ParallelRobot.load(path)
    with pytest.raises(UnreachablePoseError, match="stalls"):  # Newton alone from the drawing
        robot._newton_projection(drawn_configuration(robot.model), 1e-12, 100)
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, robot.q_home)
    gap = data.oMf[robot.model.getFrameId("ee")].translation - data.oMf[robot.model.getFrameId("tip2")].translation
    assert np.linalg.norm(gap) <= 1e-9  # assembled
    np.testing.assert_allclose(data.oMf[robot.model.getFrameId("ee")].translation[[0, 2]], robot.home_pose, atol=1e-9)
    assert robot.model.nq == 4 and robot.n_y == 2  # loaded whole: nothing locked or dropped

    monkeypatch.setattr(assembly, "GLOBAL_STARTS", 1)
    with pytest.raises(AssemblyError, match="globalized least-squares solve"):
        ParallelRobot.load(path)
