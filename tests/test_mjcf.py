"""Closed-chain MJCF files: loops from ``<equality><connect/weld>`` (Pinocchio's legacy
constraint builder), a small sidecar for drives/outputs, and the parser pitfalls."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from parallel_gpc import ParallelRobot, ReducedModel, load_description
from parallel_gpc.errors import AssemblyError, RobotFormatError

import mechanisms as mech


@pytest.fixture(scope="module")
def fivebars(tmp_path_factory):
    folder = tmp_path_factory.mktemp("mjcf")
    urdf = ParallelRobot.load(mech.write(folder, "fb", mech.fivebar_urdf(), mech.fivebar_sidecar()))
    mjcf = ParallelRobot.load(mech.write(folder, "fbm", mech.fivebar_mjcf(), mech.fivebar_mjcf_sidecar(), ".xml"))
    return urdf, mjcf


def test_mjcf_equality_connect_becomes_a_point_closure(fivebars):
    _, mjcf = fivebars
    assert mjcf.description.model_format == "mjcf"
    assert [c.kind for c in mjcf.description.closures] == ["point"]
    assert (mjcf.n_y, mjcf.n_u, mjcf.model.nv) == (2, 2, 4)
    np.testing.assert_allclose(mjcf.home_pose, mech.FIVEBAR_HOME, atol=1e-12)
    assert np.max(np.abs(mjcf.closure_residual(mjcf.q_home))) <= 1e-10


def test_mjcf_reduced_dynamics_equal_the_urdf_model(fivebars):
    urdf, mjcf = fivebars
    mu, mm = ReducedModel(urdf), ReducedModel(mjcf)
    rng = np.random.default_rng(11)
    for X in mech.random_output_states(urdf, rng, 6):
        u = rng.uniform(-5, 5, 2)
        np.testing.assert_allclose(mm.acceleration(X, u), mu.acceleration(X, u), rtol=1e-9, atol=1e-10)


def test_mjcf_reduced_accelerations_equal_constraint_dynamics_with_the_files_constraints(fivebars, tmp_path):
    _, mjcf = fivebars
    path = tmp_path / "fbm.xml"
    path.write_text(mech.fivebar_mjcf())
    model, cms = pin.buildModelAndLegacyConstraintsFromMJCF(str(path))
    assert len(cms) == 1 and model.nv == mjcf.model.nv
    mech.assert_reduced_matches_constraint_dynamics(mjcf, cms=list(cms))


def test_second_world_body_is_refused_with_the_pitfall_named(tmp_path):
    text = mech.fivebar_mjcf()
    # unwrap the legs from the root body: two bodies directly under <worldbody>
    text = text.replace('<body name="base">', "").replace("    </body>\n  </worldbody>", "  </worldbody>")
    path = mech.write(tmp_path, "two", text, mech.fivebar_mjcf_sidecar(), ".xml")
    with pytest.raises(RobotFormatError, match=r"2 bodies directly under <worldbody> \['prox1', 'prox2'\].*keeps only "
                                               r"the first one.*Wrap them in one root body"):
        ParallelRobot.load(path)


def test_sidecar_by_explicit_path(tmp_path):
    model = tmp_path / "fivebar_model.xml"
    model.write_text(mech.fivebar_mjcf())
    side = tmp_path / "config" / "drives.toml"
    side.parent.mkdir()
    side.write_text(mech.fivebar_mjcf_sidecar())
    with pytest.raises(RobotFormatError, match="no sidecar next to"):
        ParallelRobot.load(model)
    robot = ParallelRobot.load(model, sidecar=side)
    assert robot.n_y == 2 and robot.description.sidecar_path == side


def test_ball_joint_becomes_spherical(tmp_path):
    text = mech.fivebar_mjcf().replace('<joint name="e2" type="hinge" axis="0 1 0"/>', '<joint name="e2" type="ball"/>')
    # with a ball elbow the second leg can turn out of the plane: a 3-D output and more drives
    side = ('name = "ball"\n[output]\nframe = "ee"\nkind = "position"\n'
            '[drives]\njoints = ["a1", "a2", "e1"]\n')
    path = mech.write(tmp_path, "ball", text, side, ".xml")
    model, _ = pin.buildModelAndLegacyConstraintsFromMJCF(str(path))
    assert model.joints[model.getJointId("e2")].shortname() == "JointModelSpherical"
    with pytest.raises(RobotFormatError, match="does not parametrize"):
        ParallelRobot.load(path)  # the ball elbow lets the distal link spin about itself


def test_sdf_is_refused_clearly(tmp_path):
    path = tmp_path / "robot.sdf"
    path.write_text("<sdf/>")
    with pytest.raises(RobotFormatError, match="SDF is not supported"):
        load_description(path)


def test_spatial_mjcf_with_a_ball_joint_equals_the_urdf_model_and_constraint_dynamics(tmp_path):
    mjcf = ParallelRobot.load(mech.write(tmp_path, "rpsm", mech.rps_mjcf(), mech.rps_mjcf_sidecar(), ".xml"))
    urdf = ParallelRobot.load(mech.write(tmp_path, "rps", mech.rps_urdf(True), mech.rps_sidecar(True), ".urdf", ".yaml"))
    assert mjcf.model.joints[mjcf.model.getJointId("s1")].shortname() == "JointModelSpherical"
    assert (mjcf.model.nq, mjcf.model.nv, mjcf.n_y) == (10, 9, 3)
    mm, mu = ReducedModel(mjcf), ReducedModel(urdf)
    rng = np.random.default_rng(12)
    for X in mech.random_output_states(urdf, rng, 5):
        u = rng.uniform(-5, 5, 3)
        np.testing.assert_allclose(mm.acceleration(X, u), mu.acceleration(X, u), rtol=1e-9, atol=1e-10)
    _, cms = pin.buildModelAndLegacyConstraintsFromMJCF(str(tmp_path / "rpsm.xml"))
    assert len(cms) == 2
    mech.assert_reduced_matches_constraint_dynamics(mjcf, cms=list(cms))


def test_the_view_reads_the_visual_geometry_of_an_mjcf_model(fivebars):
    from parallel_gpc.viz.scene import visual_model

    _, mjcf = fivebars
    geometry = visual_model(mjcf)  # a URDF parser would refuse the MJCF file
    assert isinstance(geometry, pin.GeometryModel)


# ---------------------------------------------------------------- a loop closed by an equality weld
@pytest.fixture(scope="module")
def welded(tmp_path_factory):
    """The 5-bar with distal link 2 cut at its middle and the halves welded: MJCF (the weld from
    the file, with its own constraint models) and URDF + sidecar ``kind = "weld"``."""
    folder = tmp_path_factory.mktemp("weld")
    path = mech.write(folder, "fbw", mech.fivebar_mjcf(split=True), mech.fivebar_mjcf_sidecar(), ".xml")
    mjcf = ParallelRobot.load(path)
    urdf = ParallelRobot.load(mech.write(folder, "fbwu", mech.fivebar_urdf(split=True), mech.fivebar_sidecar(split=True)))
    _, cms = pin.buildModelAndLegacyConstraintsFromMJCF(str(path))
    return mjcf, urdf, list(cms)


def test_mjcf_equality_weld_becomes_a_weld_closure(welded):
    mjcf, urdf, cms = welded
    assert [c.kind for c in mjcf.description.closures] == ["weld"] == [c.kind for c in urdf.description.closures]
    assert len(cms) == 1 and cms[0].type == pin.ContactType.CONTACT_6D
    assert (mjcf.model.nv, mjcf.n_constraints, mjcf.n_y, mjcf.n_u) == (5, 6, 2, 2)
    np.testing.assert_allclose(mjcf.home_pose, mech.FIVEBAR_HOME, atol=1e-12)
    assert np.max(np.abs(mjcf.closure_residual(mjcf.q_home))) <= 1e-10
    # away from home the weld still holds the halves at their drawn relative pose: the two
    # frames at the cut coincide in position and orientation
    data = mjcf.model.createData()
    q = mjcf.assemble(mjcf.home_pose + [0.03, -0.02])
    pin.framesForwardKinematics(mjcf.model, data, q)
    a, b = (data.oMf[mjcf.model.getFrameId(f)] for f in mjcf.description.closures[0].frames)
    np.testing.assert_allclose(a.homogeneous, b.homogeneous, atol=1e-10)


def test_mjcf_weld_reduced_accelerations_equal_constraint_dynamics_with_the_files_constraints(welded):
    mjcf, _, cms = welded
    mech.assert_reduced_matches_constraint_dynamics(mjcf, cms=cms)


def test_mjcf_weld_equals_urdf_weld_and_the_uncut_fivebar(welded, fivebars):
    mjcf, urdf, _ = welded
    point = fivebars[0]  # the same mechanism closed at the end-effector by a point closure
    mm, mu, mp = ReducedModel(mjcf), ReducedModel(urdf), ReducedModel(point)
    rng = np.random.default_rng(13)
    for X in mech.random_output_states(point, rng, 6):
        tm, tu, tp = mm.terms(X), mu.terms(X), mp.terms(X)
        u = rng.uniform(-5, 5, 2)
        # relative to the norm; the files write inertias to 9 digits: 1e-9 against the uncut one
        for other, rtol in ((tu, 1e-12), (tp, 1e-9)):
            for a, b in ((tm.M_r, other.M_r), (tm.h_r, other.h_r), (tm.B_r, other.B_r),
                         (tm.acceleration(u), other.acceleration(u))):
                assert np.linalg.norm(a - b) <= rtol * np.linalg.norm(b)


# ---------------------------------------------------------------- view geometry of an MJCF file
def test_the_view_draws_the_geoms_of_an_mjcf_ball_joint_mechanism(tmp_path):
    from types import SimpleNamespace

    from parallel_gpc import viz

    robot = ParallelRobot.load(mech.write(tmp_path, "rpsg", mech.rps_mjcf(geoms=True), mech.rps_mjcf_sidecar(), ".xml"))
    plain = ParallelRobot.load(mech.write(tmp_path, "rps", mech.rps_mjcf(), mech.rps_mjcf_sidecar(), ".xml"))
    for a, b in zip(robot.model.inertias, plain.model.inertias):  # explicit <inertial>: geoms add no mass
        np.testing.assert_array_equal(a.toDynamicParameters(), b.toDynamicParameters())
    scene = viz.RobotScene(SimpleNamespace(path=viz.meshcat.path.Path(("meshcat",))), robot)
    geoms = {g.name: g for g in scene.geom_model.geometryObjects}
    assert sorted(geoms) == sorted(["plate", "ball1"] + [f"{p}{k}" for p in ("cyl", "rod") for k in (1, 2, 3)])
    model = robot.model
    assert model.names[geoms["plate"].parentJoint] == model.names[geoms["ball1"].parentJoint] == "s1"
    assert [model.names[geoms[f"cyl{k}"].parentJoint] for k in (1, 2, 3)] == ["r1", "r2", "r3"]
    assert (geoms["cyl1"].geometry.radius, geoms["cyl1"].geometry.halfLength) == (0.025, 0.1)
    np.testing.assert_allclose(2 * geoms["plate"].geometry.halfSide, [0.24, 0.2, 0.02])
    # placed with the bodies: the plate at the platform frame, the ball at leg 1's end
    q = robot.assemble(robot.home_pose + [0.02, 0.05, -0.04])
    T = dict(zip(scene.paths, scene.placements(q)))
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    np.testing.assert_allclose(T["robot/plate"], data.oMf[model.getFrameId("platform")].homogeneous, atol=1e-12)
    np.testing.assert_allclose(T["robot/ball1"][:3, 3], data.oMi[model.getJointId("s1")].translation, atol=1e-12)


# ---------------------------------------------------------------- drawn configuration (qpos0)
BRANCH = '[home]\nbranch_joints = ["e1", "e2"]\n'
DRAWN = [mech.fivebar_q_guess()[n] for n in ("a1", "e1", "a2", "e2")]  # qpos0 = the joints' ref values


def _drawn_fivebar(tmp_path, home: str = "", stem: str = "ref"):
    side = mech.fivebar_mjcf_sidecar() + BRANCH + home
    return ParallelRobot.load(mech.write(tmp_path, stem, mech.fivebar_mjcf(ref=True), side, ".xml"))


def test_mjcf_drawn_with_joint_refs_assembles_on_the_drawn_branch(tmp_path):
    robot = _drawn_fivebar(tmp_path)
    model, _ = pin.buildModelAndLegacyConstraintsFromMJCF(str(tmp_path / "ref.xml"))
    np.testing.assert_allclose(model.referenceConfigurations["qpos0"], DRAWN, atol=1e-12)
    # q = 0 is not the drawing (every link upright, the loop open by 0.4 m) ...
    assert np.max(np.abs(robot.closure_residual(np.zeros(4)))) > 0.3
    # ... home is the drawing: the same configuration, branch and output as the URDF 5-bar at home
    np.testing.assert_allclose(robot.q_home, DRAWN, atol=1e-9)
    np.testing.assert_allclose(robot.home_pose, mech.FIVEBAR_HOME, atol=1e-9)
    np.testing.assert_array_equal(robot.branch_signature(robot.q_home), [-1.0, 1.0])
    _, cms = pin.buildModelAndLegacyConstraintsFromMJCF(str(tmp_path / "ref.xml"))
    mech.assert_reduced_matches_constraint_dynamics(robot, cms=list(cms), n=6, seed=41)
    urdf = ParallelRobot.load(mech.write(tmp_path, "fb", mech.fivebar_urdf(), mech.fivebar_sidecar()))
    rng = np.random.default_rng(42)
    for X in mech.random_output_states(urdf, rng, 3):
        u = rng.uniform(-5, 5, 2)
        np.testing.assert_allclose(ReducedModel(robot).acceleration(X, u), ReducedModel(urdf).acceleration(X, u),
                                   rtol=1e-9, atol=1e-10)


def test_starting_from_q_zero_instead_lands_on_another_branch(tmp_path):
    # what assembly from the neutral configuration gives (a q_guess of zeros): elbows flipped
    zeros = "[home.q_guess]\na1 = 0.0\ne1 = 0.0\na2 = 0.0\ne2 = 0.0\n"
    robot = _drawn_fivebar(tmp_path, zeros)
    assert not np.array_equal(robot.branch_signature(robot.q_home), [-1.0, 1.0])
    assert np.linalg.norm(robot.home_pose - mech.FIVEBAR_HOME) > 0.1


def test_a_home_far_from_the_drawing_across_the_workspace_is_refused(tmp_path):
    # the straight path from the drawn pose (0.02, 0.5) to (-0.332, -0.3) crosses the hole of
    # leg 1's annulus around its base pivot (-0.2, 0): no configuration on the drawn branch joins them
    with pytest.raises(AssemblyError, match=r"home pose \[-0.332, -0.3\] of 'fivebar_mjcf' and the configuration "
                                            r"the file is drawn at \(output \[0.02, 0.5\]\) are not joined on one "
                                            r"assembly branch: the straight path stops at .*home.q_guess"):
        _drawn_fivebar(tmp_path, "pose = [-0.332, -0.3]\n")
    # a home reachable from the drawing keeps its branch
    robot = _drawn_fivebar(tmp_path, "pose = [-0.15, 0.2]\n", stem="near")
    np.testing.assert_array_equal(robot.branch_signature(robot.q_home), [-1.0, 1.0])


def test_an_mjcf_without_loops_is_refused_in_one_line(tmp_path, capfd):
    from parallel_gpc import cli

    text = mech.fivebar_mjcf().replace(
        f'<connect name="close" body1="dist1" body2="dist2" anchor="0 0 {mech.L_DIST}"/>', "")
    path = mech.write(tmp_path, "open", text, mech.fivebar_mjcf_sidecar(), ".xml")
    capfd.readouterr()
    assert cli.main(["info", str(path)]) == 2
    err = capfd.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "has no loop closure" in err[0] and "<equality><connect/weld>" in err[0], err
