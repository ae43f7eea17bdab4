"""A robot drawn in meshcat: geometry, closures, base, paths, and one ``Animation`` per trajectory.

The robot is drawn from its URDF visual geometry (``pinocchio.buildGeomFromUrdf``) plus a
ground plate, the base points (drive axes) and small spheres at both frames of every loop
closure, so a closed loop shows as two coinciding spheres. Links without visual geometry are
drawn as a stick figure from the joint frames (:mod:`parallel_gpc.model.skeleton`): a sphere at
each joint origin, a rod from a joint to each child joint and to the closure and output frames
on its link, so any robot is recognisable; the output frame (or platform joint) is a red sphere. A trajectory becomes one meshcat
``Animation`` (the browser interpolates between key frames); every geometry placement comes from
``pin.forwardKinematics`` + ``pin.updateGeometryPlacements`` on the full configuration q, so the
legs follow q, not only the platform.

Scene paths (under ``/meshcat``): ``robot/<geometry>`` (links, platform), ``robot/stick/*``
(joints ``joint_<name>``, rods ``rod_<k>``), ``robot/output``, ``robot/closures/*``,
``robot/saturation/<drive>`` (red overlays, visible while the drive is at its torque limit),
``base/*`` (plate, base points) and ``paths/{reference,planned}``.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import coal
import numpy as np
import pinocchio as pin

from ..errors import InvalidParameterError, ParallelGPCWarning, RobotFormatError, ShapeError
from ..model import ParallelRobot, output_joint_ids, output_world_axes, stick_figure
from ..results import check_times as _times
from ..validation import finite_matrix, finite_vector, positive
from ._meshcat import Animation, meshcat, mg

#: Scene roots under ``/meshcat``.
ROBOT, BASE, PATHS = "robot", "base", "paths"
#: Colours (0xRRGGBB): closure frames a and b, saturated drives, reference and planned paths.
CLOSURE_A_COLOR, CLOSURE_B_COLOR = 0xF2C12E, 0x202020
SATURATION_COLOR = 0xE01010
REFERENCE_COLOR, PLANNED_COLOR = 0x303030, 0xC000C0
PLATE_COLOR, BASE_POINT_COLOR = 0xD8D8D8, 0x4D4D4D
#: Stick figure of links without visuals: joints, rods; the output frame.
STICK_JOINT_COLOR, STICK_ROD_COLOR, OUTPUT_COLOR = 0x2F5D8A, 0x8A8A8A, 0xD03030
#: Height (m) of the drawn paths above the plane z = 0 of a planar robot.
PATH_Z = 0.02
#: three.js cylinders are along y; URDF/Coal cylinders along z: rotate y onto z.
_Y_TO_Z = np.array([[1.0, 0, 0, 0], [0, 0, -1.0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])


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


def path_placement(robot: ParallelRobot) -> tuple[list[int | None], np.ndarray]:
    """How a path in ``robot``'s outputs is drawn in the world: for each world axis the output
    column moving along it (or None), and the (3,) values (m) of the axes no output moves along:
    the output point's at home, lifted by :data:`PATH_Z` along z (above a planar robot's plane)."""
    world = output_world_axes(robot)
    columns = [world.index(k) if k in world else None for k in range(3)]
    fill = np.array(stick_figure(robot).output, dtype=float)
    fill[2] += PATH_Z
    return columns, fill


#: Coal shapes the viewer draws; other visuals (meshes) leave their link to the stick figure.
DRAWN_SHAPES = (coal.Cylinder, coal.Sphere, coal.Box)


def visual_model(robot: ParallelRobot) -> pin.GeometryModel:
    """The robot's drawn visual geometry (from its URDF or MJCF model file) as a
    ``pinocchio.GeometryModel``: its cylinders, spheres and boxes.

    The links of other visuals (meshes) are drawn as the stick figure instead, and a model file
    whose meshes do not resolve in its folder or the package path is not read for visuals at all
    (Pinocchio would look for them elsewhere; they are never read): every link is then drawn as
    the stick figure. Either case is said in one line (:class:`~parallel_gpc.errors.ParallelGPCWarning`).
    """
    description = robot.description
    path = str(description.urdf_path)
    if description.unresolved_meshes:
        shown = ", ".join(repr(u) for u in description.unresolved_meshes[:3])
        more = len(description.unresolved_meshes) - 3
        warnings.warn(
            f"the view draws {path!r} as a stick figure: {len(description.unresolved_meshes)} mesh(es) "
            f"({shown}{f' and {more} more' if more > 0 else ''}) do not resolve in the robot's folder or the package "
            "path (--package-path DIR, PARALLEL_GPC_PACKAGE_PATH or package_path=)", ParallelGPCWarning, stacklevel=2)
        return pin.GeometryModel()
    if description.model_format == "mjcf":
        geom = pin.buildGeomFromMJCF(robot.model, path, pin.GeometryType.VISUAL)
    else:
        dirs = [str(Path(path).resolve().parent), *map(str, description.package_path)]
        geom = pin.buildGeomFromUrdf(robot.model, path, pin.GeometryType.VISUAL, None, dirs)
    skipped = [g for g in geom.geometryObjects if not isinstance(g.geometry, DRAWN_SHAPES)]
    if not skipped:
        return geom
    kinds = sorted({type(g.geometry).__name__ for g in skipped})
    warnings.warn(f"the view draws {len(skipped)} visual(s) of {path!r} ({', '.join(kinds)}: not cylinders, spheres "
                  "or boxes) as a stick figure of their links", ParallelGPCWarning, stacklevel=2)
    drawn = pin.GeometryModel()
    for g in geom.geometryObjects:
        if isinstance(g.geometry, DRAWN_SHAPES):
            drawn.addGeometryObject(g)
    return drawn


def _shape(geometry, scale: float = 1.0) -> tuple[mg.Geometry, np.ndarray]:
    """meshcat geometry of a Coal shape and its 4x4 intrinsic transform (local frame fix-up).

    Raises:
        RobotFormatError: for shapes the viewer does not draw (meshes, capsules, ...).
    """
    if isinstance(geometry, coal.Cylinder):
        return mg.Cylinder(2.0 * geometry.halfLength, geometry.radius * scale), _Y_TO_Z
    if isinstance(geometry, coal.Sphere):
        return mg.Sphere(geometry.radius * scale), np.eye(4)
    if isinstance(geometry, coal.Box):
        return mg.Box((2.0 * np.asarray(geometry.halfSide) * scale).tolist()), np.eye(4)
    raise RobotFormatError(
        f"visual geometry of type {type(geometry).__name__} is not drawn by the viewer; "
        "use cylinder, sphere or box visuals in the URDF"
    )


def _material(rgba, color: int | None = None) -> mg.MeshLambertMaterial:
    """Lambert material from an RGBA array (0..1), or a fixed 0xRRGGBB ``color``."""
    rgba = np.asarray(rgba, dtype=float)
    if color is None:
        r, g, b = (int(round(255 * float(np.clip(c, 0, 1)))) for c in rgba[:3])
        color = (r << 16) | (g << 8) | b
    return mg.MeshLambertMaterial(color=color, opacity=float(np.clip(rgba[3], 0, 1)))


def _lowest_z(geometry, oMg: pin.SE3) -> float:
    """Lowest world z (m) of a cylinder, sphere or box placed at ``oMg``."""
    R, z = oMg.rotation, oMg.translation[2]
    if isinstance(geometry, coal.Cylinder):
        az = abs(R[2, 2])
        return z - az * geometry.halfLength - geometry.radius * math.sqrt(max(0.0, 1 - az * az))
    if isinstance(geometry, coal.Sphere):
        return z - geometry.radius
    if isinstance(geometry, coal.Box):
        return z - float(np.abs(R[2]) @ np.asarray(geometry.halfSide))
    return z


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
        radius: rod radius in m (spheres 1.7 times larger), from the robot's size at home.
    """

    def __init__(self, robot: ParallelRobot, geom_model: pin.GeometryModel):
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
        points = stick_figure(robot).joints
        span = float(np.ptp(points, axis=0).max()) if len(points) > 1 else 0.3
        self.radius = float(np.clip(0.012 * span, 0.003, 0.015))
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
        paths: meshcat paths (relative to ``vis``) of the moving parts, in draw order.
    """

    def __init__(self, vis: meshcat.Visualizer, robot: ParallelRobot):
        self.vis = vis
        self.robot = robot
        self.geom_model = visual_model(robot)
        self.geom_data = self.geom_model.createData()
        self.data = robot.model.createData()
        self._shapes = [_shape(g.geometry) for g in self.geom_model.geometryObjects]
        self._drive_jids = [robot.model.getJointId(n) for n in robot.description.drive_joints]
        self._closure_fids = [(robot.model.getFrameId(c.frames[0]), robot.model.getFrameId(c.frames[1]))
                              for c in robot.description.closures]
        self.stick = StickFigure(robot, self.geom_model)
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
        for c in self.robot.description.closures:  # frame a: large translucent, b: small dark
            closures = self.vis[f"{ROBOT}/closures"]
            closures[f"{c.name}_a"].set_object(mg.Sphere(0.026), _material([1, 1, 1, 0.7], CLOSURE_A_COLOR))
            closures[f"{c.name}_b"].set_object(mg.Sphere(0.014), _material([1, 1, 1, 1], CLOSURE_B_COLOR))
        for i, k in self._overlays():
            shape, _ = _shape(self.geom_model.geometryObjects[k].geometry, scale=1.8)
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
        floor = min([_lowest_z(g.geometry, M) for g, M in zip(self.geom_model.geometryObjects, self.geom_data.oMg)]
                    + [-0.03]) - 0.01
        lo, hi = points[:, :2].min(axis=0) - 0.15, points[:, :2].max(axis=0) + 0.15
        plate = mg.Box([float(hi[0] - lo[0]), float(hi[1] - lo[1]), 0.01])
        self.vis[f"{BASE}/plate"].set_object(plate, _material([1, 1, 1, 1], PLATE_COLOR))
        self.vis[f"{BASE}/plate"].set_transform(_translation([*(lo + hi) / 2, floor - 0.005]))
        for i, p in enumerate(points):
            height = p[2] - floor
            post = mg.Cylinder(max(height, 0.01), 0.035)
            node = self.vis[f"{BASE}/point_{i + 1}"]
            node.set_object(post, _material([1, 1, 1, 1], BASE_POINT_COLOR))
            node.set_transform(_translation([p[0], p[1], floor + height / 2]) @ _Y_TO_Z)

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
    """Draw ``robot`` (geometry, closures, base) at configuration q (default: home) and aim the camera."""
    scene = RobotScene(vis, robot).draw(q)
    set_camera(vis, scene.base_points())
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


def set_camera(vis: meshcat.Visualizer, points: np.ndarray, elevation_deg: float = 55.0) -> None:
    """Frame ``points`` ((n, 3) m, e.g. the base points): look at their centre from -y, above.

    meshcat's orbit camera always looks at the world origin, so the scene under ``vis`` is
    shifted to put the centre of ``points`` there (the stock grid and axes are hidden and a triad is drawn
    at the robot's own origin instead). The distance grows with the spread of the points so a
    1 m x 1 m workspace fills the view.
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    center = points.mean(axis=0) if points.size else np.zeros(3)
    span = float(np.ptp(points[:, :2], axis=0).max()) if len(points) > 1 else 1.0
    distance = 1.05 * max(span, 0.3) + 0.35
    el = math.radians(elevation_deg)
    vis.set_transform(_translation([-center[0], -center[1], 0.0]))
    vis["/Axes"].set_property("visible", False)
    vis["/Grid"].set_property("visible", False)
    vis[f"{BASE}/origin"].set_object(mg.triad(0.2))
    vis["/Cameras/default"].set_transform(np.eye(4))
    # the camera lives in a y-up frame ("rotated"): (x, y, z) there is (x, -z, y) in the world
    vis["/Cameras/default/rotated/<object>"].set_property(
        "position", [0.0, distance * math.sin(el), distance * math.cos(el)])


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
    cols, fill = path_placement(robot)  # the output columns along world x, y, z
    for name, points, color in (("reference", reference, REFERENCE_COLOR), ("planned", planned, PLANNED_COLOR)):
        if points is not None:
            if np.asarray(points).ndim == 2 and np.asarray(points).shape[1] != robot.n_y:
                raise ShapeError(f"{name} poses have {np.asarray(points).shape[1]} columns; robot {robot.name!r} "
                                 f"has {robot.n_y} outputs {list(robot.description.output_labels)}")
            draw_path(vis, name, points, color, cols, fill)
    if t.size > 1:
        vis.set_animation(scene.animation(t, qs, flags, fps, max_frames), play=play, repetitions=1)
    return scene
