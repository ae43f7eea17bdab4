"""The view draws what the robot file dresses its links with, and every added mark in proportion:
resolved STL/OBJ meshes with their scale and the visual's origin (the stick figure for the links
of other visuals, said in one line), and the same picture, scaled, for a robot scaled by k."""

from __future__ import annotations

import base64
import re
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import umsgpack

from parallel_gpc import ParallelRobot, viz
from parallel_gpc.errors import ParallelGPCWarning
from parallel_gpc.model import stick_figure
from parallel_gpc.model.meshes import PACKAGE_PATH_ENV, ROS_PACKAGE_PATH_ENV
import mechanisms as mech

mg = viz.meshcat.geometry

#: link -> (mesh URI, scale, origin xyz, origin rpy); the 3-RRR's platform and first proximal link
MESHES = {
    "platform": ("package://pkg/meshes/plate.stl", (0.15, 0.12, 0.03), (0.01, -0.02, 0.005), (0.1, -0.2, 0.3)),
    "proximal_1": ("meshes/bar.obj", (0.6, 0.03, 0.02), (0.0, 0.0, 0.0), (0.0, 0.0, 0.4)),
    "distal_1": ("meshes/bar.ply", (1.0, 1.0, 1.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),  # a format meshcat cannot draw
    "distal_2": ("package://nowhere/x.stl", (1.0, 1.0, 1.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),  # unresolved
}
COMMAND = re.compile(r'fetch\("data:application/octet-binary;base64,([A-Za-z0-9+/=]+)"\)')


@pytest.fixture(autouse=True)
def _no_package_env(monkeypatch):
    monkeypatch.delenv(PACKAGE_PATH_ENV, raising=False)
    monkeypatch.delenv(ROS_PACKAGE_PATH_ENV, raising=False)


@pytest.fixture
def meshed(tmp_path):
    """(robot, package folder): planar_3rrr whose links in MESHES are dressed with meshes."""
    path, packages = mech.meshed_3rrr(tmp_path, MESHES, {
        "packages/pkg/meshes/plate.stl": mech.prism_stl(), "robot/meshes/bar.obj": mech.BOX_OBJ,
        "robot/meshes/bar.ply": "ply\nformat ascii 1.0\nend_header\n"})
    return ParallelRobot.load(path, package_path=packages), packages


def commands(page: str) -> list[dict]:
    """The scene commands of an exported page, decoded."""
    return [umsgpack.unpackb(base64.b64decode(b)) for b in COMMAND.findall(page)]


def visual_placement(robot: ParallelRobot, q: np.ndarray, link: str) -> np.ndarray:
    """4x4 world placement of ``link``'s visual (MESHES) at q: the link's body frame times the
    visual's origin, from the model's frames (not from the geometry model under test)."""
    _, _, xyz, rpy = MESHES[link]
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    frame = data.oMf[robot.model.getFrameId(link, pin.FrameType.BODY)]
    return (frame * pin.SE3(pin.rpy.rpyToMatrix(*rpy), np.array(xyz))).homogeneous


def test_resolved_meshes_are_drawn_with_their_scale_and_origin(meshed, tmp_path):
    robot, _ = meshed
    with pytest.warns(ParallelGPCWarning) as caught:
        geom = viz.visual_model(robot)
    (note,) = [str(w.message) for w in caught]
    assert "1 mesh(es) ('package://nowhere/x.stl') do not resolve" in note
    assert "1 mesh(es) ('meshes/bar.ply') are not STL, OBJ or Collada files" in note
    by_file = {Path(g.meshPath).name: g for g in geom.geometryObjects if g.meshPath.endswith((".stl", ".obj"))}
    assert set(by_file) == {"plate.stl", "bar.obj"}
    np.testing.assert_allclose(by_file["plate.stl"].meshScale, MESHES["platform"][1])

    q = robot.q_home
    t = np.array([0.0, 0.5])
    with pytest.warns(ParallelGPCWarning):
        page = viz.export_html(tmp_path / "meshes.html", robot, t, np.array([q, q])).read_text(encoding="utf-8")
    sent = commands(page)
    objects = {c["path"]: c["object"] for c in sent if c["type"] == "set_object"}
    placed = {c["path"]: np.array(c["matrix"]).reshape(4, 4).T for c in sent if c["type"] == "set_transform"}
    for link, name, fmt, contents in (("platform", "plate.stl", "stl", None), ("proximal_1", "bar.obj", "obj",
                                                                                  mech.BOX_OBJ)):
        g = by_file[name]
        path = f"/meshcat/robot/{g.name}"
        obj = objects[path]
        (geometry,) = obj["geometries"]
        assert (geometry["type"], geometry["format"]) == ("_meshfile_geometry", fmt)
        if contents is not None:
            assert geometry["data"] == contents  # the file itself
        else:
            assert bytes(geometry["data"].data) == Path(g.meshPath).read_bytes()
        # the mesh's scale in the object's own matrix (kept when its node is animated)
        np.testing.assert_allclose(np.array(obj["object"]["matrix"]).reshape(4, 4).T, np.diag([*MESHES[link][1], 1.0]))
        # its node at the visual's placement
        np.testing.assert_allclose(placed[path], visual_placement(robot, q, link), atol=1e-9)
    stick_joints = {p.rsplit("joint_", 1)[1] for p in objects if "/robot/stick/joint_" in p}
    model = robot.model
    link_joint = {link: model.names[model.frames[model.getFrameId(link, pin.FrameType.BODY)].parentJoint]
                  for link in MESHES}
    assert link_joint["distal_1"] in stick_joints and link_joint["distal_2"] in stick_joints
    assert link_joint["platform"] not in stick_joints and link_joint["proximal_1"] not in stick_joints


def test_an_unreadable_mesh_leaves_its_link_to_the_stick_figure(meshed):
    robot, packages = meshed
    (packages / "pkg" / "meshes" / "plate.stl").write_text("solid m\nendsolid m\n")  # no facet: not a mesh
    with pytest.warns(ParallelGPCWarning, match=r"1 mesh file\(s\) cannot be read \('package://pkg/meshes/plate.stl'"):
        geom = viz.visual_model(robot)
    assert [Path(g.meshPath).name for g in geom.geometryObjects if g.meshPath.endswith((".stl", ".obj"))] == ["bar.obj"]


# ------------------------------------------------------------------------- marks scale with the robot
class Recorder:
    """A stand-in for ``meshcat.Visualizer`` that records what is drawn: (kind, path, value)."""

    def __init__(self, log=None, path=""):
        self.log = [] if log is None else log
        self.path = path

    def __getitem__(self, key: str) -> "Recorder":
        return Recorder(self.log, key if key.startswith("/") else f"{self.path}/{key}")

    def set_object(self, geometry, material=None):
        self.log.append(("object", self.path, geometry))

    def set_transform(self, matrix=np.eye(4)):
        self.log.append(("transform", self.path, np.asarray(matrix, dtype=float)))

    def set_property(self, key, value):
        self.log.append(("property", f"{self.path}:{key}", value))


def lengths(geometry) -> np.ndarray:
    """Every length (m) of a drawn meshcat object."""
    if isinstance(geometry, mg.Sphere):
        return np.array([geometry.radius])
    if isinstance(geometry, mg.Cylinder):
        return np.array([geometry.height, geometry.radiusTop, geometry.radiusBottom])
    if isinstance(geometry, mg.Box):
        return np.asarray(geometry.lengths, dtype=float)
    if isinstance(geometry, mg.Object):  # lines: the triad
        return np.asarray(geometry.geometry.position, dtype=float).ravel()
    raise AssertionError(f"unexpected object {geometry!r}")


def scaled_fivebar(folder: Path, k: float) -> Path:
    """docs/your-robot's five-bar with every length (joint origins, home pose, plan points) times k."""
    docs = Path(__file__).resolve().parents[1] / "docs" / "your-robot"
    times = lambda m: " ".join(repr(k * float(x)) for x in m.group(1).split())  # noqa: E731
    urdf = re.sub(r'<origin xyz="([^"]*)"', lambda m: f'<origin xyz="{times(m)}"', (docs / "fivebar.urdf").read_text())
    toml = re.sub(r"^(pose|A|B) = \[([^\]]*)\]",
                  lambda m: f"{m.group(1)} = [{', '.join(repr(k * float(x)) for x in m.group(2).split(','))}]",
                  (docs / "fivebar.toml").read_text(), flags=re.MULTILINE)
    folder.mkdir()
    (folder / "fivebar.urdf").write_text(urdf)
    (folder / "fivebar.toml").write_text(toml)
    return folder / "fivebar.urdf"


def test_a_robot_scaled_by_k_is_drawn_scaled_by_k(tmp_path):
    """Every mark the view adds (closure spheres, joints and rods, base posts and plate, axes,
    camera distance, the scene's offset) is proportional to the robot's size: the drawing of the
    five-bar scaled to 4 cm is the drawing of the 0.4 m one scaled by 0.1, so a small robot is
    not hidden under fixed-size marks."""
    k = 0.1
    big, small = (ParallelRobot.load(scaled_fivebar(tmp_path / name, s)) for name, s in (("big", 1.0), ("small", k)))
    assert stick_figure(small).size == pytest.approx(k * stick_figure(big).size, rel=1e-9)
    np.testing.assert_allclose(small.q_home, big.q_home, atol=1e-9)  # the same pose, smaller
    drawn = []
    for robot in (big, small):
        vis = Recorder()
        viz.draw_robot(vis, robot)
        drawn.append(vis.log)
    assert [(kind, path) for kind, path, _ in drawn[0]] == [(kind, path) for kind, path, _ in drawn[1]]
    for (kind, path, a), (_, _, b) in zip(*drawn):
        if kind == "object":
            np.testing.assert_allclose(lengths(b), k * lengths(a), rtol=1e-6, atol=1e-12, err_msg=path)
        elif kind == "transform":
            np.testing.assert_allclose(b[:3, :3], a[:3, :3], atol=1e-6, err_msg=path)
            np.testing.assert_allclose(b[:3, 3], k * a[:3, 3], rtol=1e-6, atol=1e-9, err_msg=path)
        elif path.endswith(":position"):  # the camera
            np.testing.assert_allclose(b, k * np.asarray(a), rtol=1e-9, err_msg=path)
        else:
            assert a == b, path
