"""meshcat view of a parallel robot: drawing, animation, offline HTML, loopback servers (DESIGN §8).

The robot is drawn from its URDF visual geometry (``pinocchio.buildGeomFromUrdf``) plus a
ground plate, the base points (drive axes) and small spheres at both frames of every loop
closure, so a closed loop shows as two coinciding spheres. A trajectory becomes one meshcat
``Animation`` (the browser interpolates between key frames); every geometry placement comes from
``pin.forwardKinematics`` + ``pin.updateGeometryPlacements`` on the full configuration q, so the
legs follow q, not only the platform.

Servers: meshcat 0.3.2's ``meshcat.Visualizer()`` starts a server that listens on all interfaces
(0.0.0.0). :class:`LiveViewer` instead runs the meshcat bridge in a thread of this process with
its web and ZeroMQ sockets bound to a loopback address only, and stops it on exit (also on
KeyboardInterrupt). :func:`export_html` uses such a viewer to write a self-contained HTML file
(the viewer bundle is inlined, nothing is loaded from the network); :class:`GalleryServer`
serves a folder of those files on 127.0.0.1.

Scene paths (under ``/meshcat``): ``robot/<geometry>`` (links, platform), ``robot/closures/*``,
``robot/saturation/<drive>`` (red overlays, visible while the drive is at its torque limit),
``base/*`` (plate, base points) and ``paths/{reference,planned}``.
"""

from __future__ import annotations

import asyncio
import html
import ipaddress
import math
import re
import socket
import sys
import threading
import time
import warnings
from dataclasses import dataclass
from functools import partial
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import coal
import numpy as np
import pinocchio as pin
import tornado.httpserver
import tornado.ioloop
import tornado.netutil
import tornado.web
import zmq

with warnings.catch_warnings():  # meshcat 0.3.2 imports the deprecated zmq.eventloop.ioloop
    warnings.simplefilter("ignore", DeprecationWarning)
    import meshcat
    import meshcat.geometry as mg
    from meshcat.animation import Animation
    from meshcat.servers.tree import SceneTree
    from meshcat.servers.zmqserver import (
        VIEWER_HTML,
        VIEWER_ROOT,
        StaticFileHandlerNoCache,
        WebSocketHandler,
        ZMQWebSocketBridge,
    )
    from meshcat.visualizer import ViewerWindow

from ..errors import InvalidParameterError, RobotFormatError, ShapeError, ViewerError
from ..model.robot import ParallelRobot, embedded_robots, urdf_dir
from ..validation import finite_matrix, finite_vector, positive

#: The only address our servers bind by default.
LOOPBACK = "127.0.0.1"
#: Scene roots under ``/meshcat``.
ROBOT, BASE, PATHS = "robot", "base", "paths"
#: Colours (0xRRGGBB): closure frames a and b, saturated drives, reference and planned paths.
CLOSURE_A_COLOR, CLOSURE_B_COLOR = 0xF2C12E, 0x202020
SATURATION_COLOR = 0xE01010
REFERENCE_COLOR, PLANNED_COLOR = 0x303030, 0xC000C0
PLATE_COLOR, BASE_POINT_COLOR = 0xD8D8D8, 0x4D4D4D
#: Height (m) of the drawn paths above the plane z = 0 of a planar robot.
PATH_Z = 0.02
#: three.js cylinders are along y; URDF/Coal cylinders along z: rotate y onto z.
_Y_TO_Z = np.array([[1.0, 0, 0, 0], [0, 0, -1.0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])
_ZMQ_TIMEOUT_MS = 60_000
_START_TIMEOUT_S = 10.0


# ---------------------------------------------------------------------------------------------
# validation
# ---------------------------------------------------------------------------------------------
def loopback_host(host: str) -> str:
    """Return ``host`` as an IPv4 loopback address (``"localhost"`` becomes 127.0.0.1).

    Raises:
        InvalidParameterError: if ``host`` is not an IPv4 loopback address (127.0.0.0/8).
    """
    name = str(host).strip()
    if name.lower() == "localhost":
        return LOOPBACK
    try:
        addr = ipaddress.ip_address(name)
    except ValueError:
        addr = None
    if addr is None or addr.version != 4 or not addr.is_loopback:
        raise InvalidParameterError(
            f"bind address {host!r} is not an IPv4 loopback address; the viewer and gallery "
            f"serve on the loopback interface only (use {LOOPBACK} or localhost)"
        )
    return str(addr)


def _port(port) -> int:
    if isinstance(port, bool) or not isinstance(port, (int, np.integer)) or not 0 <= int(port) <= 65535:
        raise InvalidParameterError(f"port {port!r} must be an integer in [0, 65535] (0: any free port)")
    return int(port)


def _times(t) -> np.ndarray:
    t = finite_vector("times t", t)
    if t.size == 0:
        raise ShapeError("times t has shape (0,); expected (K,) with K >= 1 samples")
    if np.any(np.diff(t) <= 0):
        k = int(np.argmax(np.diff(t) <= 0))
        raise InvalidParameterError(
            f"times t must be strictly increasing (s); t[{k}] = {t[k]:.6g} >= t[{k + 1}] = {t[k + 1]:.6g}")
    return t


def _configurations(robot: ParallelRobot, qs, n: int) -> np.ndarray:
    return finite_matrix("configurations qs", qs, (n, robot.model.nq))


def _flags(robot: ParallelRobot, saturated, n: int) -> np.ndarray | None:
    if saturated is None:
        return None
    flags = np.asarray(saturated)
    if flags.shape != (n, robot.n_u):
        raise ShapeError(f"saturated has shape {flags.shape}; expected ({n}, {robot.n_u}) (samples, drives)")
    return flags.astype(bool)


def _path_points(name: str, points) -> np.ndarray:
    """(K, 3) points of a planar path: columns x, y (m) of ``points``, at height :data:`PATH_Z`."""
    arr = np.asarray(points, dtype=float)
    if arr.ndim != 2 or arr.shape[1] < 2 or arr.shape[0] < 2:
        raise ShapeError(f"{name} has shape {arr.shape}; expected (K, 2) or (K, 3) with K >= 2 "
                         "(platform x, y in m; a third column, e.g. psi, is ignored)")
    arr = finite_matrix(name, arr, (None, None))
    return np.column_stack([arr[:, 0], arr[:, 1], np.full(arr.shape[0], PATH_Z)])


def saturation_flags(u, torque_limit, rtol: float = 1e-6) -> np.ndarray:
    """(K, n_u) flags: True where a drive torque is at its limit.

    Args:
        u: (K, n_u) drive torques, N·m.
        torque_limit: (n_u,) or scalar symmetric limits, N·m.
        rtol: relative tolerance below the limit that still counts as saturated.
    """
    u = finite_matrix("drive torques u", u, (None, None))
    limit = finite_vector("torque_limit", np.broadcast_to(torque_limit, (u.shape[1],)), u.shape[1])
    return np.abs(u) >= limit * (1.0 - rtol)


# ---------------------------------------------------------------------------------------------
# geometry
# ---------------------------------------------------------------------------------------------
def visual_model(robot: ParallelRobot) -> pin.GeometryModel:
    """The robot's URDF visual geometry as a ``pinocchio.GeometryModel``."""
    return pin.buildGeomFromUrdf(robot.model, str(robot.description.urdf_path), pin.GeometryType.VISUAL)


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
        self.paths = ([f"{ROBOT}/{g.name}" for g in self.geom_model.geometryObjects]
                      + [f"{ROBOT}/closures/{c.name}_{s}" for c in robot.description.closures for s in "ab"]
                      + [self._overlay_path(i, g) for i, g in self._overlays()])

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
        self.show_saturation(np.zeros(self.robot.n_u, dtype=bool))
        self._draw_base()
        self.show(q)
        return self

    def base_points(self) -> np.ndarray:
        """(n, 3) world positions (m) of the drive axes fixed to the ground (parent: universe)."""
        pin.forwardKinematics(self.robot.model, self.data, self.robot.q_home)
        return np.array([self.data.oMi[j].translation for j in self._drive_jids
                         if self.robot.model.parents[j] == 0]).reshape(-1, 3)

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
        return links + spheres + overlays

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


def draw_path(vis: meshcat.Visualizer, name: str, points, color: int) -> None:
    """Draw a planar path as a meshcat ``Line`` at ``paths/<name>``.

    Args:
        points: (K, 2) or (K, 3) platform poses; columns x, y in m (a third column is ignored).
        color: 0xRRGGBB.
    """
    xyz = _path_points(f"{name} path", points)
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
        reference: optional (K_ref, 2 or 3) reference platform poses (x, y in m), drawn as a line.
        planned: optional (K_p, 2 or 3) planned platform poses, drawn as a line.
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
    if reference is not None:
        draw_path(vis, "reference", reference, REFERENCE_COLOR)
    if planned is not None:
        draw_path(vis, "planned", planned, PLANNED_COLOR)
    if t.size > 1:
        vis.set_animation(scene.animation(t, qs, flags, fps, max_frames), play=play, repetitions=1)
    return scene


# ---------------------------------------------------------------------------------------------
# offline HTML
# ---------------------------------------------------------------------------------------------
_NETWORK_PATTERNS = [
    r"""\b(?:src|href|action|poster|data)\s*=\s*["']?\s*(?:https?:)?//[^\s"'>]*""",
    r"""url\(\s*["']?\s*(?:https?:)?//[^\s"')]*""",
    r"""@import\s+["']?(?:url\()?\s*["']?(?:https?:)?//[^\s"')]*""",
    r"""\b(?:fetch|import|importScripts)\s*\(\s*["'](?:https?:)?//[^"']*""",
    r"""new\s+(?:WebSocket|EventSource)\s*\(\s*["'](?:wss?:|https?:)?//[^"']*""",
]


def network_references(page: str) -> list[str]:
    """Places in an HTML text that would load something over the network (http(s) or ws(s) URLs)."""
    return [m.group(0) for pattern in _NETWORK_PATTERNS for m in re.finditer(pattern, page, re.IGNORECASE)]


def _decorate(page: str, title: str, legend: str) -> str:
    page = page.replace("<title>MeshCat</title>", f"<title>{html.escape(title)}</title>", 1)
    caption = (
        '<div id="parallel-gpc-caption" style="position:fixed;left:8px;bottom:8px;padding:4px 8px;'
        'font:12px sans-serif;background:rgba(255,255,255,0.8);border-radius:4px;pointer-events:none">'
        f"<b>{html.escape(title)}</b><br>{html.escape(legend)}</div>"
    )
    return page.replace("</body>", caption + "</body>", 1)


def export_html(path, robot: ParallelRobot, t, qs, reference=None, planned=None, saturated=None,
                title: str | None = None, fps: float = 30.0, max_frames: int = 300) -> Path:
    """Write a self-contained HTML animation of a trajectory (works offline).

    Builds the scene on a private :class:`LiveViewer` (127.0.0.1, stopped on return) and saves
    ``vis.static_html()``, which inlines the meshcat viewer bundle.

    Args:
        path: output file (.html); parent folders are created.
        robot, t, qs, reference, planned, saturated, fps, max_frames: as in :func:`animate`.
        title: page title (default: the robot name).

    Returns:
        the written path.

    Raises:
        ViewerError: if the page would load anything from the network.
    """
    path = Path(path)
    title = title or f"parallel-gpc: {robot.name}"
    with LiveViewer() as viewer:
        animate(viewer.vis, robot, t, qs, saturated=saturated, reference=reference, planned=planned,
                fps=fps, max_frames=max_frames)
        page = viewer.vis.static_html()
    legend = "drives orange, distal links blue, platform green, closures yellow/black"
    legend += ", reference grey" if reference is not None else ""
    legend += ", planned magenta" if planned is not None else ""
    legend += ", drive at torque limit red" if saturated is not None else ""
    page = _decorate(page, title, legend)
    found = network_references(page)
    if found:
        raise ViewerError(f"exported page would load from the network: {found[:3]}; not written to {str(path)!r}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(page, encoding="utf-8")
    return path


# ---------------------------------------------------------------------------------------------
# live viewer (meshcat bridge in a thread, loopback only)
# ---------------------------------------------------------------------------------------------
class _QuietWebSocketHandler(WebSocketHandler):
    """meshcat's websocket handler without its prints to stderr."""

    def open(self):
        self.bridge.websocket_pool.add(self)
        self.bridge.send_scene(self)

    def on_close(self):
        self.bridge.websocket_pool.discard(self)


class _LoopbackBridge(ZMQWebSocketBridge):
    """meshcat's ZeroMQ/websocket bridge with its web server bound to ``host`` only.

    The stock bridge calls ``app.listen(port)``, which listens on every interface. Must be
    constructed inside a running asyncio loop (the thread's loop).
    """

    def __init__(self, host: str, port: int):  # noqa: D107 — replaces the parent's set-up
        self.host = host
        self.websocket_pool = set()
        self.tree = SceneTree()
        self.app = self.make_app()
        self.ioloop = tornado.ioloop.IOLoop.current()
        # web sockets first: if the port is taken, nothing is bound yet (libzmq would release
        # its listener only asynchronously)
        self.sockets = tornado.netutil.bind_sockets(port, address=host, family=socket.AF_INET)
        try:
            self.zmq_socket, self.zmq_stream, _ = self.setup_zmq(f"tcp://{host}:*")
        except zmq.ZMQError:
            for sock in self.sockets:
                sock.close()
            raise
        self.zmq_url = self.zmq_socket.getsockopt_string(zmq.LAST_ENDPOINT)
        self.http_server = tornado.httpserver.HTTPServer(self.app)
        self.http_server.add_sockets(self.sockets)
        self.fileserver_port = self.sockets[0].getsockname()[1]
        self.web_url = f"http://{host}:{self.fileserver_port}/static/"

    def make_app(self):
        return tornado.web.Application([
            (r"/static/(.*)", StaticFileHandlerNoCache, {"path": VIEWER_ROOT, "default_filename": VIEWER_HTML}),
            (r"/", _QuietWebSocketHandler, {"bridge": self}),
        ], log_function=lambda handler: None)

    async def shutdown(self) -> None:
        """Stop listening, close browser connections and the ZeroMQ socket."""
        self.http_server.stop()
        for ws in list(self.websocket_pool):
            ws.close(1001, "server stopping")
        for _ in range(20):
            if not self.websocket_pool:
                break
            await asyncio.sleep(0.025)
        for ws in list(self.websocket_pool):
            stream = getattr(ws.ws_connection, "stream", None)
            if stream is not None:
                stream.close()
        await self.http_server.close_all_connections()
        self.zmq_stream.close(linger=0)
        await _released(self.host, zmq_port_of(self.zmq_url))


def zmq_port_of(url: str) -> int:
    """Port of a ``tcp://host:port`` ZeroMQ endpoint."""
    return int(url.rsplit(":", 1)[1])


async def _released(host: str, port: int, timeout: float = 2.0) -> None:
    """Wait until nothing listens on (host, port): libzmq closes its listener in its I/O thread,
    after ``close()`` returns."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # ignore TIME_WAIT leftovers
            try:
                probe.bind((host, port))
                return
            except OSError:
                pass
        await asyncio.sleep(0.01)


class _Window(ViewerWindow):
    """A meshcat client window on an existing server (no subprocess, no print, closable)."""

    def __init__(self, zmq_url: str, web_url: str):  # noqa: D107 — replaces the parent's set-up
        self.server_proc = None
        self.zmq_url = zmq_url
        self.web_url = web_url
        self.connect_zmq()
        self.zmq_socket.setsockopt(zmq.RCVTIMEO, _ZMQ_TIMEOUT_MS)
        self.zmq_socket.setsockopt(zmq.SNDTIMEO, _ZMQ_TIMEOUT_MS)

    def close(self) -> None:
        self.zmq_socket.close(linger=0)


class LiveViewer:
    """Our own meshcat server on a loopback address, as a context manager.

    >>> with LiveViewer() as viewer:          # doctest: +SKIP
    ...     draw_robot(viewer.vis, robot)
    ...     print(viewer.url)

    Args:
        host: bind address; must be IPv4 loopback (default 127.0.0.1).
        port: web server port (0: any free port). The ZeroMQ command port is always a free one.

    Attributes:
        vis: the ``meshcat.Visualizer`` talking to this server (None when stopped).
        url: the viewer page, ``http://127.0.0.1:<port>/static/``.
        port: the bound web server port.
        zmq_url: the bound ZeroMQ endpoint (``tcp://127.0.0.1:<port>``).

    Raises:
        InvalidParameterError: if ``host`` is not a loopback address or ``port`` is out of range.
    """

    def __init__(self, host: str = LOOPBACK, port: int = 0):
        self.host = loopback_host(host)
        self.requested_port = _port(port)
        self.vis: meshcat.Visualizer | None = None
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop_event: asyncio.Event | None = None
        self._bridge: _LoopbackBridge | None = None
        self._error: BaseException | None = None

    @property
    def url(self) -> str:
        return self._require_bridge().web_url

    @property
    def port(self) -> int:
        return int(self._require_bridge().fileserver_port)

    @property
    def zmq_url(self) -> str:
        return self._require_bridge().zmq_url

    def _require_bridge(self) -> _LoopbackBridge:
        if self._bridge is None:
            raise ViewerError("the live viewer is not running; use it as a context manager or call start()")
        return self._bridge

    def start(self) -> "LiveViewer":
        """Start the server thread and connect :attr:`vis`.

        Raises:
            ViewerError: if the server cannot bind its sockets or does not start in 10 s.
        """
        if self._thread is not None:
            raise ViewerError("the live viewer is already running")
        ready = threading.Event()
        self._error = None
        self._thread = threading.Thread(target=self._run, args=(ready,), name="parallel-gpc-meshcat", daemon=True)
        self._thread.start()
        if not ready.wait(_START_TIMEOUT_S) or self._error is not None:
            error = self._error
            self.stop()
            raise ViewerError(
                f"cannot start the meshcat server on {self.host}:{self.requested_port}: "
                f"{error or 'no answer within 10 s'}"
            ) from error
        self.vis = meshcat.Visualizer(window=_Window(self._bridge.zmq_url, self._bridge.web_url))
        return self

    def _run(self, ready: threading.Event) -> None:
        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(self._serve(ready))
        finally:
            loop.run_until_complete(loop.shutdown_asyncgens())
            loop.close()
            ready.set()

    async def _serve(self, ready: threading.Event) -> None:
        try:
            bridge = _LoopbackBridge(self.host, self.requested_port)
        except (OSError, zmq.ZMQError) as exc:
            self._error = exc
            return
        self._stop_event = asyncio.Event()
        self._loop = asyncio.get_running_loop()
        self._bridge = bridge
        ready.set()
        try:
            await self._stop_event.wait()
        finally:
            await bridge.shutdown()

    def stop(self) -> None:
        """Disconnect :attr:`vis`, stop the server and wait for its thread (idempotent)."""
        if self.vis is not None:
            self.vis.window.close()
            self.vis = None
        thread, self._thread = self._thread, None
        if thread is None:
            return
        if self._loop is not None:
            try:
                self._loop.call_soon_threadsafe(self._stop_event.set)
            except RuntimeError:  # the loop already ended
                pass
        thread.join(_START_TIMEOUT_S)
        self._loop = self._stop_event = self._bridge = None
        if thread.is_alive():
            raise ViewerError("the meshcat server thread did not stop within 10 s")

    def __enter__(self) -> "LiveViewer":
        return self.start()

    def __exit__(self, exc_type, exc, tb) -> bool:
        self.stop()
        return False

    def __repr__(self) -> str:
        state = f"url={self._bridge.web_url!r}" if self._bridge is not None else "stopped"
        return f"LiveViewer(host={self.host!r}, {state})"


def _wait_forever(_server) -> None:
    while True:
        time.sleep(0.5)


def serve_until_interrupt(robot: ParallelRobot, t=None, qs=None, *, reference=None, planned=None,
                          saturated=None, host: str = LOOPBACK, port: int = 0, out=None,
                          wait=_wait_forever) -> None:
    """Show a trajectory (or the home pose) in a live viewer until Ctrl-C, then stop cleanly.

    Args:
        robot: the robot. t, qs, reference, planned, saturated: as in :func:`animate`; without
            ``qs`` the robot is drawn at home.
        host, port: loopback bind address and web port (0: any free port).
        out: stream for the URL message (default stdout).
        wait: blocks while serving; gets the :class:`LiveViewer` (default: sleep until Ctrl-C).
    """
    out = sys.stdout if out is None else out
    with LiveViewer(host, port) as viewer:
        if qs is None:
            draw_robot(viewer.vis, robot)
        else:
            animate(viewer.vis, robot, t, qs, saturated=saturated, reference=reference, planned=planned)
        print(f"meshcat viewer: {viewer.url}  (Ctrl-C to stop)", file=out, flush=True)
        try:
            wait(viewer)
        except KeyboardInterrupt:
            pass
    print("viewer stopped", file=out, flush=True)


# ---------------------------------------------------------------------------------------------
# gallery of exported pages
# ---------------------------------------------------------------------------------------------
def _page_title(path: Path) -> str:
    with open(path, encoding="utf-8", errors="replace") as f:
        head = f.read(4096)
    match = re.search(r"<title>(.*?)</title>", head, re.IGNORECASE | re.DOTALL)
    return html.unescape(match.group(1).strip()) if match else path.stem


def gallery_index(directory) -> str:
    """HTML index page linking every ``*.html`` file of ``directory`` (except index.html)."""
    directory = Path(directory)
    pages = sorted(p for p in directory.glob("*.html") if p.name != "index.html")
    items = "\n".join(
        f'<li><a href="{html.escape(p.name, quote=True)}">{html.escape(_page_title(p))}</a> '
        f"<small>({html.escape(p.name)})</small></li>" for p in pages
    ) or "<li>no exported animations (*.html) in this folder yet</li>"
    return (
        "<!DOCTYPE html>\n<html><head><meta charset=utf-8><title>parallel-gpc gallery</title></head>\n"
        "<body style=\"font:14px sans-serif;margin:2em\"><h1>parallel-gpc animations</h1>\n"
        f"<p>{html.escape(str(directory.resolve()))}</p>\n<ul>\n{items}\n</ul></body></html>\n"
    )


class _GalleryHandler(SimpleHTTPRequestHandler):
    """Static files of one folder, with a generated index at ``/``."""

    def do_GET(self):  # noqa: N802 — http.server naming
        if self.path.split("?", 1)[0] == "/":
            body = gallery_index(self.directory).encode("utf-8")
            self.send_response(200)
            self.send_header("Content-Type", "text/html; charset=utf-8")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)
            return
        super().do_GET()

    def log_message(self, format, *args):  # noqa: A002 — http.server signature
        pass


class GalleryServer:
    """Serve a folder of exported pages on a loopback address, as a context manager.

    Args:
        directory: folder holding the ``*.html`` files.
        host: bind address; must be IPv4 loopback (default 127.0.0.1).
        port: port (0: any free port).

    Attributes:
        url: ``http://127.0.0.1:<port>/`` (the generated index).
        server: the ``http.server.ThreadingHTTPServer`` (None when stopped).

    Raises:
        InvalidParameterError: bad host or port, or ``directory`` is not a folder.
    """

    def __init__(self, directory, host: str = LOOPBACK, port: int = 0):
        self.directory = Path(directory)
        if not self.directory.is_dir():
            raise InvalidParameterError(f"gallery folder {str(directory)!r} does not exist or is not a folder")
        self.host = loopback_host(host)
        self.requested_port = _port(port)
        self.server: ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None

    @property
    def port(self) -> int:
        if self.server is None:
            raise ViewerError("the gallery server is not running")
        return int(self.server.server_address[1])

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/"

    def start(self) -> "GalleryServer":
        """Bind and serve in a daemon thread.

        Raises:
            ViewerError: if the address cannot be bound (e.g. port in use).
        """
        handler = partial(_GalleryHandler, directory=str(self.directory))
        try:
            self.server = ThreadingHTTPServer((self.host, self.requested_port), handler)
        except OSError as exc:
            raise ViewerError(f"cannot serve the gallery on {self.host}:{self.requested_port}: {exc}") from exc
        self.server.daemon_threads = True
        self._thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.1},
                                        name="parallel-gpc-gallery", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close the socket (idempotent)."""
        server, self.server = self.server, None
        if server is None:
            return
        server.shutdown()
        server.server_close()
        self._thread.join(_START_TIMEOUT_S)

    def __enter__(self) -> "GalleryServer":
        return self.start()

    def __exit__(self, exc_type, exc, tb) -> bool:
        self.stop()
        return False


def serve_gallery(directory, port: int = 0, host: str = LOOPBACK, out=None, wait=_wait_forever) -> None:
    """Serve ``directory``'s exported pages on 127.0.0.1 until Ctrl-C (prints the URL).

    Args:
        directory: folder of ``*.html`` animations. port: 0 for any free port.
        host: loopback bind address. out: stream for messages (default stdout).
        wait: blocks while serving; gets the :class:`GalleryServer` (default: until Ctrl-C).
    """
    out = sys.stdout if out is None else out
    with GalleryServer(directory, host, port) as server:
        print(f"gallery of {server.directory.resolve()}: {server.url}  (Ctrl-C to stop)", file=out, flush=True)
        try:
            wait(server)
        except KeyboardInterrupt:
            pass
    print("gallery stopped", file=out, flush=True)


# ---------------------------------------------------------------------------------------------
# trajectory files
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Trajectory:
    """A saved trajectory (``.npz``): what ``parallel-gpc view`` shows.

    Attributes:
        robot: embedded robot name or path to its URDF/sidecar.
        t: (K,) times, s.
        q: (K, nq) assembled configurations.
        reference: (K_r, n_y) reference platform poses (m, rad), or None.
        planned: (K_p, n_y) planned platform poses, or None.
        saturated: (K, n_u) drive-at-limit flags, or None.
    """

    robot: str
    t: np.ndarray
    q: np.ndarray
    reference: np.ndarray | None = None
    planned: np.ndarray | None = None
    saturated: np.ndarray | None = None


def robot_reference(robot: ParallelRobot) -> str:
    """How a trajectory file names ``robot``: the embedded name, else the URDF path."""
    urdf = robot.description.urdf_path.resolve()
    embedded = urdf.stem in embedded_robots() and urdf.parent == urdf_dir().resolve()
    return urdf.stem if embedded else str(urdf)


def save_trajectory(path, robot: ParallelRobot, t, q, reference=None, planned=None, saturated=None) -> Path:
    """Save a trajectory as ``.npz`` (keys t, q, robot and optional reference, planned, saturated)."""
    t = _times(t)
    arrays = {"t": t, "q": _configurations(robot, q, t.size), "robot": np.array(robot_reference(robot))}
    if reference is not None:
        arrays["reference"] = finite_matrix("reference", reference, (None, None))
    if planned is not None:
        arrays["planned"] = finite_matrix("planned", planned, (None, None))
    if saturated is not None:
        arrays["saturated"] = _flags(robot, saturated, t.size)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        np.savez_compressed(f, **arrays)
    return path


def load_trajectory(path) -> Trajectory:
    """Read a trajectory ``.npz`` written by :func:`save_trajectory` (or any with the same keys).

    Raises:
        InvalidParameterError: missing file, unreadable file or missing keys.
    """
    path = Path(path)
    if not path.is_file():
        raise InvalidParameterError(f"trajectory file {str(path)!r} does not exist")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError) as exc:
        raise InvalidParameterError(f"cannot read trajectory file {str(path)!r}: {exc}") from exc
    missing = [k for k in ("t", "q", "robot") if k not in arrays]
    if missing:
        raise InvalidParameterError(
            f"trajectory file {str(path)!r} lacks the keys {missing}; it has {sorted(arrays)} "
            "(needed: t (K,), q (K, nq), robot; optional: reference, planned, saturated)"
        )
    return Trajectory(
        robot=str(arrays["robot"]),
        t=_times(arrays["t"]),
        q=finite_matrix("q", arrays["q"], (arrays["t"].shape[0], None)),
        reference=arrays.get("reference"),
        planned=arrays.get("planned"),
        saturated=arrays.get("saturated"),
    )
