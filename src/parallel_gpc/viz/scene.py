"""A robot drawn in meshcat: geometry, closures, base, paths, and one ``Animation`` per trajectory.

The robot is drawn from its model file's visual geometry (cylinders, spheres, boxes and resolved
meshes: :mod:`~parallel_gpc.viz.visuals`) plus a ground plate, the base points (drive axes) and
small spheres at both frames of every loop closure, so a closed loop shows as two coinciding
spheres. Links without visual geometry are
drawn as a stick figure from the joint frames (:mod:`parallel_gpc.model.skeleton`): a sphere at
each joint origin, a rod from a joint to each child joint and to the closure and output frames
on its link, so any robot is recognisable; the output frame (or platform joint) is a red sphere. A trajectory becomes one meshcat
``Animation`` (the browser interpolates between key frames); every geometry placement comes from
``pin.forwardKinematics`` + ``pin.updateGeometryPlacements`` on the full configuration q, so the
legs follow q, not only the platform. Every added mark (closure spheres, rods, base posts and plate,
axes, camera distance) is proportional to the robot's characteristic length (:class:`Marks`), so a
robot of a few centimetres is as recognisable as one of a metre.

Scene paths (under ``/meshcat``): ``robot/<geometry>`` (links, platform), ``robot/stick/*``
(joints ``joint_<name>``, rods ``rod_<k>``), ``robot/output``, ``robot/closures/*``,
``robot/saturation/<drive>`` (red overlays, visible while the drive is at its torque limit),
``base/*`` (plate, base points) and ``paths/{reference,planned}``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ..errors import InvalidParameterError, ShapeError
from ..model import ParallelRobot, output_joint_ids, output_world_axes, stick_figure
from ..results import check_times as _times
from ..validation import finite_matrix, finite_vector, positive
from ._meshcat import Animation, meshcat, mg
from .visuals import Y_TO_Z, lowest_z, meshcat_shape, visual_model

#: Scene roots under ``/meshcat``.
ROBOT, BASE, PATHS = "robot", "base", "paths"
#: Colours (0xRRGGBB): closure frames a and b, saturated drives, reference and planned paths.
CLOSURE_A_COLOR, CLOSURE_B_COLOR = 0xF2C12E, 0x202020
SATURATION_COLOR = 0xE01010
REFERENCE_COLOR, PLANNED_COLOR = 0x303030, 0xC000C0
PLATE_COLOR, BASE_POINT_COLOR = 0xD8D8D8, 0x4D4D4D
#: Stick figure of links without visuals: joints, rods; the output frame.
STICK_JOINT_COLOR, STICK_ROD_COLOR, OUTPUT_COLOR = 0x2F5D8A, 0x8A8A8A, 0xD03030
#: Height (m) of a planar path drawn without a robot (:func:`draw_path`) above the plane z = 0.
PATH_Z = 0.02


@dataclass(frozen=True)
class Marks:
    """Sizes (m) of the marks the view adds to a robot, all proportional to its characteristic
    length (:attr:`parallel_gpc.model.skeleton.Skeleton.size`), so that a robot of a few
    centimetres and one of a metre look alike.

    Attributes:
        size: the robot's characteristic length, m.
        rod: stick figure rod radius (joint spheres 1.7 times, the output sphere 2.2 times larger).
        closure_a, closure_b: radii of the spheres on a closure's frames a (translucent) and b.
        post: radius of the posts under the base points; post_length: their longest length (a
            base point higher above the plate gets a stub).
        margin: ground plate margin around the base points. plate: plate thickness.
        clearance: the plate's top lies this far below the robot's lowest point (its drawn
            geometry and joint spheres), and at least 4 times as far below z = 0.
        lift: height of the drawn paths above the output point's (above a planar robot's plane).
        triad: length of the axes drawn at the robot's origin.
    """

    size: float

    #: Each mark's size as a fraction of :attr:`size`.
    FRACTIONS = {"rod": 0.012, "closure_a": 0.024, "closure_b": 0.011, "post": 0.03, "post_length": 0.1,
                 "margin": 0.15, "plate": 0.01, "clearance": 0.01, "lift": 0.02, "triad": 0.2}

    def __getattr__(self, name: str) -> float:
        fraction = type(self).FRACTIONS.get(name)
        if fraction is None:
            raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")
        return fraction * self.size


def marks(robot: ParallelRobot) -> Marks:
    """The view's mark sizes for ``robot`` (from its stick figure at home)."""
    return Marks(stick_figure(robot).size)


def _configurations(robot: ParallelRobot, qs, n: int) -> np.ndarray:
    return finite_matrix("configurations qs", qs, (n, robot.model.nq))


def _flags(robot: ParallelRobot, saturated, n: int) -> np.ndarray | None:
    if saturated is None:
        return None
    flags = np.asarray(saturated)
    if flags.shape != (n, robot.n_u):
        raise ShapeError(f"saturated has shape {flags.shape}; expected ({n}, {robot.n_u}) (samples, drives)")
    return flags.astype(bool)


def _path_points(name: str, points, xyz_columns=None, fill=None) -> np.ndarray:
    """(K, 3) world points of a path.

    Args:
        points: (K, n) poses.
        xyz_columns: for each world axis x, y, z the pose column drawn along it, or None for an
            axis no output moves along (then ``fill`` gives its value, m). None: a planar path,
            columns x, y (m) at height :data:`PATH_Z`.
        fill: (3,) values (m) of the axes without a column.
    """
    arr = np.asarray(points, dtype=float)
    if xyz_columns is not None:
        arr = finite_matrix(name, arr, (None, None))
        fill = np.zeros(3) if fill is None else np.asarray(fill, dtype=float)
        return np.column_stack([arr[:, c] if c is not None else np.full(arr.shape[0], fill[k])
                                for k, c in enumerate(xyz_columns)])
    if arr.ndim != 2 or arr.shape[1] < 2 or arr.shape[0] < 2:
        raise ShapeError(f"{name} has shape {arr.shape}; expected (K, 2) or (K, 3) with K >= 2 "
                         "(platform x, y in m; a third column, e.g. psi, is ignored)")
    arr = finite_matrix(name, arr, (None, None))
    return np.column_stack([arr[:, 0], arr[:, 1], np.full(arr.shape[0], PATH_Z)])


def path_placement(robot: ParallelRobot, figure=None) -> tuple[list[int | None], np.ndarray]:
    """How a path in ``robot``'s outputs is drawn in the world: for each world axis the output
    column moving along it (or None), and the (3,) values (m) of the axes no output moves along:
    the output point's at home, lifted by :attr:`Marks.lift` along z (above a planar robot's plane).
    ``figure``: the robot's stick figure at home when the caller has it (else computed here)."""
    world = output_world_axes(robot)
    columns = [world.index(k) if k in world else None for k in range(3)]
    figure = stick_figure(robot) if figure is None else figure
    fill = np.array(figure.output, dtype=float)
    fill[2] += Marks(figure.size).lift
    return columns, fill


def _material(rgba, color: int | None = None) -> mg.MeshLambertMaterial:
    """Lambert material from an RGBA array (0..1), or a fixed 0xRRGGBB ``color``."""
    rgba = np.asarray(rgba, dtype=float)
    if color is None:
        r, g, b = (int(round(255 * float(np.clip(c, 0, 1)))) for c in rgba[:3])
        color = (r << 16) | (g << 8) | b
    return mg.MeshLambertMaterial(color=color, opacity=float(np.clip(rgba[3], 0, 1)))


def _translation(p) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = p
    return T


def _rod(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """4x4 transform placing a three.js cylinder (along its y axis, centred) from point a to b."""
    d = np.asarray(b, dtype=float) - np.asarray(a, dtype=float)
    n = float(np.linalg.norm(d))
    T = _translation((np.asarray(a) + np.asarray(b)) / 2)
    if n > 0:
        T[:3, :3] = pin.Quaternion.FromTwoVectors(np.array([0.0, 1.0, 0.0]), d / n).matrix()
    return T


class StickFigure:
    """The parts of a robot drawn from its joint frames: links without visual geometry.

    A link (the body of joint j) has no visual when no geometry object hangs on j. Joints whose
    link has none get a sphere at their origin; such a link gets a rod from its joint to each
    child joint and to each closure or output frame on it. Output joints of joint outputs
    (virtual platform coordinates) are not drawn. The output frame (task-space outputs) or the
    last output joint is always marked.

    Attributes:
        joints: model ids of the joints drawn as spheres.
        rods: (parent joint id, child joint id or None, frame id or None) of each rod.
        radius: rod radius in m (spheres 1.7 times larger): :attr:`Marks.rod`.
    """

    def __init__(self, robot: ParallelRobot, geom_model: pin.GeometryModel, sizes: Marks | None = None):
        model = robot.model
        dressed = {g.parentJoint for g in geom_model.geometryObjects}
        skip = output_joint_ids(robot)
        bare = [j for j in range(1, model.njoints) if j not in dressed and j not in skip]
        self.joints = bare
        self.rods = [(model.parents[j], j, None) for j in range(1, model.njoints)
                     if model.parents[j] in bare and j not in skip]
        frames = [f for fa, fb, _ in robot.closure_frames for f in (fa, fb)]
        if robot.output_frame_id is not None:
            frames.append(robot.output_frame_id)
        for f in dict.fromkeys(frames):
            joint = model.frames[f].parentJoint
            if joint in bare:
                self.rods.append((joint, None, f))
        self.radius = (sizes or marks(robot)).rod
        self._robot = robot

    @property
    def paths(self) -> list[str]:
        names = self._robot.model.names
        return ([f"{ROBOT}/stick/joint_{names[j]}" for j in self.joints]
                + [f"{ROBOT}/stick/rod_{k}" for k in range(len(self.rods))] + [f"{ROBOT}/output"])

    def ends(self, data: pin.Data) -> list[tuple[np.ndarray, np.ndarray]]:
        """(start, end) world points of each rod (kinematics and frames of ``data`` up to date)."""
        return [(data.oMi[p].translation, data.oMi[c].translation if c is not None else data.oMf[f].translation)
                for p, c, f in self.rods]

    def output_point(self, data: pin.Data) -> np.ndarray:
        robot = self._robot
        if robot.output_frame_id is not None:
            return data.oMf[robot.output_frame_id].translation
        out = output_joint_ids(robot)
        return data.oMi[max(out)].translation if out else np.zeros(3)

    def draw(self, vis, data: pin.Data) -> None:
        """Set the meshcat objects (rod lengths from ``data``, e.g. at home: a rod lies on one link)."""
        joint = _material([1, 1, 1, 1], STICK_JOINT_COLOR)
        for path in self.paths[:len(self.joints)]:
            vis[path].set_object(mg.Sphere(1.7 * self.radius), joint)
        rod = _material([1, 1, 1, 1], STICK_ROD_COLOR)
        for k, (a, b) in enumerate(self.ends(data)):
            vis[f"{ROBOT}/stick/rod_{k}"].set_object(mg.Cylinder(max(float(np.linalg.norm(b - a)), 1e-4), self.radius),
                                                      rod)
        vis[f"{ROBOT}/output"].set_object(mg.Sphere(2.2 * self.radius), _material([1, 1, 1, 1], OUTPUT_COLOR))

    def placements(self, data: pin.Data) -> list[np.ndarray]:
        """4x4 world transforms of :attr:`paths` (kinematics and frames of ``data`` up to date)."""
        return ([_translation(data.oMi[j].translation) for j in self.joints]
                + [_rod(a, b) for a, b in self.ends(data)] + [_translation(self.output_point(data))])


class RobotScene:
    """A robot drawn in a meshcat visualizer, and the placements of its parts at any q.

    Args:
        vis: a ``meshcat.Visualizer`` (e.g. ``LiveViewer.vis``).
        robot: the robot to draw.

    Attributes:
        geom_model, geom_data: the URDF visual geometry and its workspace.
        figure: the robot's stick figure at home (:func:`~parallel_gpc.model.stick_figure`).
        marks: sizes of the added marks (closures, base, stick figure), scaled to the robot.
        paths: meshcat paths (relative to ``vis``) of the moving parts, in draw order.
    """

    def __init__(self, vis: meshcat.Visualizer, robot: ParallelRobot):
        self.vis = vis
        self.robot = robot
        self.geom_model = visual_model(robot)
        self.geom_data = self.geom_model.createData()
        self.data = robot.model.createData()
        self.figure = stick_figure(robot)
        self.marks = Marks(self.figure.size)
        self._meshes = {}  # mesh file contents by path, read once for the links and their overlays
        self._shapes = [meshcat_shape(g, meshes=self._meshes) for g in self.geom_model.geometryObjects]
        self._drive_jids = [robot.model.getJointId(n) for n in robot.description.drive_joints]
        self._closure_fids = [(robot.model.getFrameId(c.frames[0]), robot.model.getFrameId(c.frames[1]))
                              for c in robot.description.closures]
        self.stick = StickFigure(robot, self.geom_model, self.marks)
        self.paths = ([f"{ROBOT}/{g.name}" for g in self.geom_model.geometryObjects]
                      + [f"{ROBOT}/closures/{c.name}_{s}" for c in robot.description.closures for s in "ab"]
                      + [self._overlay_path(i, g) for i, g in self._overlays()] + self.stick.paths)

    # ------------------------------------------------------------------ drawing
    def _overlays(self) -> list[tuple[int, int]]:
        """(drive index, geometry index) of the geometry moved by each drive joint."""
        return [(i, k) for i, jid in enumerate(self._drive_jids)
                for k, g in enumerate(self.geom_model.geometryObjects) if g.parentJoint == jid]

    def _overlay_path(self, i: int, k: int) -> str:
        drive = self.robot.description.drive_joints[i]
        return f"{ROBOT}/saturation/{drive}/{self.geom_model.geometryObjects[k].name}"

    def draw(self, q: np.ndarray | None = None) -> "RobotScene":
        """Set every object (robot, closures, saturation overlays, base) and place them at q."""
        q = self.robot.q_home if q is None else finite_vector("configuration q", q, self.robot.model.nq)
        for g, (shape, _) in zip(self.geom_model.geometryObjects, self._shapes):
            self.vis[f"{ROBOT}/{g.name}"].set_object(shape, _material(g.meshColor))
        m = self.marks
        for c in self.robot.description.closures:  # frame a: large translucent, b: small dark
            closures = self.vis[f"{ROBOT}/closures"]
            closures[f"{c.name}_a"].set_object(mg.Sphere(m.closure_a), _material([1, 1, 1, 0.7], CLOSURE_A_COLOR))
            closures[f"{c.name}_b"].set_object(mg.Sphere(m.closure_b), _material([1, 1, 1, 1], CLOSURE_B_COLOR))
        for i, k in self._overlays():
            shape, _ = meshcat_shape(self.geom_model.geometryObjects[k], scale=1.8, meshes=self._meshes)
            self.vis[self._overlay_path(i, k)].set_object(shape, _material([1, 1, 1, 0.85], SATURATION_COLOR))
        pin.framesForwardKinematics(self.robot.model, self.data, self.robot.q_home)
        self.stick.draw(self.vis, self.data)
        self.show_saturation(np.zeros(self.robot.n_u, dtype=bool))
        self._draw_base()
        self.show(q)
        return self

    def base_points(self) -> np.ndarray:
        """(n, 3) world positions (m) of the legs' joints on the ground: the joints whose parent
        is the universe, except the platform's own (virtual output) joints."""
        model = self.robot.model
        platform = {j for name in self.robot.description.output_joints for j in model.supports[model.getJointId(name)]}
        pin.forwardKinematics(model, self.data, self.robot.q_home)
        return np.array([self.data.oMi[j].translation for j in range(1, model.njoints)
                         if model.parents[j] == 0 and j not in platform]).reshape(-1, 3)

    def _draw_base(self) -> None:
        points = self.base_points()
        pin.forwardKinematics(self.robot.model, self.data, self.robot.q_home)
        pin.updateGeometryPlacements(self.robot.model, self.data, self.geom_model, self.geom_data)
        sizes = self.marks
        lowest = [lowest_z(g.geometry, M) for g, M in zip(self.geom_model.geometryObjects, self.geom_data.oMg)]
        joints = self.figure.joints
        lowest += [float(joints[:, 2].min()) - 1.7 * sizes.rod] if len(joints) else []
        floor = min(lowest + [-3 * sizes.clearance]) - sizes.clearance
        lo, hi = points[:, :2].min(axis=0) - sizes.margin, points[:, :2].max(axis=0) + sizes.margin
        plate = mg.Box([float(hi[0] - lo[0]), float(hi[1] - lo[1]), sizes.plate])
        self.vis[f"{BASE}/plate"].set_object(plate, _material([1, 1, 1, 1], PLATE_COLOR))
        self.vis[f"{BASE}/plate"].set_transform(_translation([*(lo + hi) / 2, floor - sizes.plate / 2]))
        for i, p in enumerate(points):  # a post down to the plate, or a stub under a base point high above it
            height = float(np.clip(p[2] - floor, sizes.clearance, sizes.post_length))
            post = mg.Cylinder(height, sizes.post)
            node = self.vis[f"{BASE}/point_{i + 1}"]
            node.set_object(post, _material([1, 1, 1, 1], BASE_POINT_COLOR))
            node.set_transform(_translation([p[0], p[1], p[2] - height / 2]) @ Y_TO_Z)

    # ------------------------------------------------------------------ placements
    def placements(self, q: np.ndarray) -> list[np.ndarray]:
        """4x4 world transforms of the parts in :attr:`paths` at configuration q (m)."""
        model = self.robot.model
        pin.forwardKinematics(model, self.data, q)
        pin.updateFramePlacements(model, self.data)
        pin.updateGeometryPlacements(model, self.data, self.geom_model, self.geom_data)
        links = [M.homogeneous @ intrinsic for M, (_, intrinsic) in zip(self.geom_data.oMg, self._shapes)]
        spheres = [_translation(self.data.oMf[f].translation) for pair in self._closure_fids for f in pair]
        overlays = [links[k] for _, k in self._overlays()]
        return links + spheres + overlays + self.stick.placements(self.data)

    def show(self, q: np.ndarray) -> None:
        """Place the robot at configuration q (nq,)."""
        q = finite_vector("configuration q", q, self.robot.model.nq)
        for path, T in zip(self.paths, self.placements(q)):
            self.vis[path].set_transform(T)

    def show_saturation(self, flags) -> None:
        """Show the red overlay of each drive whose flag is True ((n_u,) bools)."""
        for drive, flag in zip(self.robot.description.drive_joints, np.asarray(flags, dtype=bool)):
            self.vis[f"{ROBOT}/saturation/{drive}"].set_property("visible", bool(flag))

    # ------------------------------------------------------------------ animation
    def animation(self, t: np.ndarray, qs: np.ndarray, saturated: np.ndarray | None = None,
                  fps: float = 30.0, max_frames: int = 300) -> Animation:
        """One meshcat ``Animation`` of the trajectory, sub-sampled to at most ``max_frames``.

        Args:
            t: (K,) strictly increasing times, s.
            qs: (K, nq) assembled configurations (rad, m).
            saturated: (K, n_u) flags, True while a drive is at its torque limit.
            fps: key-frame rate of the clip, 1/s (animation time = trajectory time - t[0]).
            max_frames: upper bound on the number of key frames.
        """
        t = _times(t)
        qs = _configurations(self.robot, qs, t.size)
        flags = _flags(self.robot, saturated, t.size)
        fps = positive("fps", fps, " 1/s")
        anim = Animation(default_framerate=fps)
        for k in frame_indices(t, fps, max_frames):
            frame = anim.at_frame(self.vis, float((t[k] - t[0]) * fps))
            for path, T in zip(self.paths, self.placements(qs[k])):
                frame[path].set_transform(T)
            if flags is not None:
                for drive, flag in zip(self.robot.description.drive_joints, flags[k]):
                    frame[f"{ROBOT}/saturation/{drive}"].set_property("visible", "boolean", bool(flag))
        return anim


def frame_indices(t: np.ndarray, fps: float, max_frames: int = 300) -> np.ndarray:
    """Indices of the samples used as key frames: about ``fps`` per second, at most ``max_frames``.

    The first and last samples are always included; each key frame is the sample nearest to a
    uniform grid over [t[0], t[-1]] (s), so configurations are shown exactly as given.
    """
    t = _times(t)
    if int(max_frames) < 2:
        raise InvalidParameterError(f"max_frames = {max_frames!r} must be >= 2")
    n = int(min(int(max_frames), t.size, math.floor((t[-1] - t[0]) * fps + 1e-9) + 1))
    n = max(n, min(2, t.size))
    grid = np.linspace(t[0], t[-1], n)
    right = np.clip(np.searchsorted(t, grid), 1, max(t.size - 1, 1))
    left = right - 1
    nearest = np.where(np.abs(t[left] - grid) <= np.abs(t[np.minimum(right, t.size - 1)] - grid), left, right)
    return np.unique(np.clip(nearest, 0, t.size - 1))


def draw_robot(vis: meshcat.Visualizer, robot: ParallelRobot, q: np.ndarray | None = None) -> RobotScene:
    """Draw ``robot`` (geometry, closures, base) at configuration q (default: home) and aim the
    camera at its stick figure at home (:func:`set_camera`, sized by :attr:`RobotScene.marks`)."""
    scene = RobotScene(vis, robot).draw(q)
    figure = scene.figure
    points = np.vstack([figure.joints, figure.closures.reshape(-1, 3), figure.output.reshape(1, 3)])
    set_camera(vis, points, size=scene.marks.size)
    return scene


def draw_path(vis: meshcat.Visualizer, name: str, points, color: int, xyz_columns=None, fill=None) -> None:
    """Draw a path as a meshcat ``Line`` at ``paths/<name>``.

    Args:
        points: (K, 2) or (K, 3) planar platform poses, columns x, y in m (a third column is
            ignored); or (K, n_y) poses with ``xyz_columns``.
        color: 0xRRGGBB.
        xyz_columns: for each world axis the pose column along it, or None for an axis filled
            with ``fill`` (m) (:func:`path_placement`); None: a planar path.
    """
    xyz = _path_points(f"{name} path", points, xyz_columns, fill)
    line = mg.Line(mg.PointsGeometry(xyz.T.astype(np.float32)), mg.LineBasicMaterial(color=color, linewidth=2))
    vis[f"{PATHS}/{name}"].set_object(line)


def set_camera(vis: meshcat.Visualizer, points: np.ndarray, elevation_deg: float = 55.0,
               size: float | None = None) -> None:
    """Frame ``points`` ((n, 3) m, e.g. a robot's joint origins): look at the centre of their
    bounding box from above and from -y, or from -x when the points spread less than half as
    much along x as along y (a mechanism in a vertical y-z plane is then seen face on).

    meshcat's orbit camera always looks at the world origin, so the scene under ``vis`` is
    shifted to put that centre there (the stock grid and axes are hidden and a triad of
    :attr:`Marks.triad` is drawn at the robot's own origin instead). The camera stands ``1.4 * size``
    away, so a robot of characteristic length ``size`` (m; default: the points' largest extent
    along a world axis, 1 m for a single point) fills the view whatever its scale.
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    center = (points.min(axis=0) + points.max(axis=0)) / 2 if points.size else np.zeros(3)
    extent = np.ptp(points, axis=0) if len(points) > 1 else np.zeros(3)
    if size is None:
        size = float(extent.max()) if extent.max() > 0 else 1.0
    size = positive("camera size", size, " m")
    distance = 1.4 * size
    el = math.radians(elevation_deg)
    vis.set_transform(_translation(-center))
    vis["/Axes"].set_property("visible", False)
    vis["/Grid"].set_property("visible", False)
    vis[f"{BASE}/origin"].set_object(mg.triad(Marks(size).triad))
    vis["/Cameras/default"].set_transform(np.eye(4))
    # the camera lives in a y-up frame ("rotated"): (x, y, z) there is (x, -z, y) in the world
    across, up = distance * math.cos(el), distance * math.sin(el)
    position = [-across, up, 0.0] if extent[0] < 0.5 * extent[1] else [0.0, up, across]
    vis["/Cameras/default/rotated/<object>"].set_property("position", position)


def animate(vis: meshcat.Visualizer, robot: ParallelRobot, t, qs, *, saturated=None, reference=None,
            planned=None, fps: float = 30.0, max_frames: int = 300, play: bool = True) -> RobotScene:
    """Draw ``robot`` and send one ``Animation`` of the trajectory (t, qs) to ``vis``.

    Args:
        vis: a ``meshcat.Visualizer``.
        robot: the robot of the trajectory.
        t: (K,) strictly increasing times, s.
        qs: (K, nq) full assembled configurations (legs included).
        saturated: optional (K, n_u) flags; a drive at its torque limit is drawn red.
        reference: optional (K_ref, n_y) reference poses, drawn as a line in the world along the
            axes the translational outputs move along (:func:`path_placement`).
        planned: optional planned platform poses, drawn as a line (shapes as ``reference``).
        fps: key-frame rate, 1/s. max_frames: at most this many key frames.
        play: start playing when a browser shows the scene.

    Returns:
        the drawn :class:`RobotScene`.
    """
    t = _times(t)
    qs = _configurations(robot, qs, t.size)
    flags = _flags(robot, saturated, t.size)
    scene = draw_robot(vis, robot, qs[0])
    if flags is not None:
        scene.show_saturation(flags[0])
    cols, fill = path_placement(robot, scene.figure)  # the output columns along world x, y, z
    for name, points, color in (("reference", reference, REFERENCE_COLOR), ("planned", planned, PLANNED_COLOR)):
        if points is not None:
            if np.asarray(points).ndim == 2 and np.asarray(points).shape[1] != robot.n_y:
                raise ShapeError(f"{name} poses have {np.asarray(points).shape[1]} columns; robot {robot.name!r} "
                                 f"has {robot.n_y} outputs {list(robot.description.output_labels)}")
            draw_path(vis, name, points, color, cols, fill)
    if t.size > 1:
        vis.set_animation(scene.animation(t, qs, flags, fps, max_frames), play=play, repetitions=1)
    return scene
