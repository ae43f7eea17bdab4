"""The robot file's own visual geometry, as the view draws it: cylinders, spheres, boxes and the
meshes that resolve.

A ``<visual>`` mesh is drawn when its URI resolves to a file (in the robot's folder or under the
package path: :mod:`parallel_gpc.model.meshes`) in a format meshcat draws (:data:`MESH_FORMATS`:
STL, OBJ, Collada), from that file's bytes, with the visual's origin and the mesh's ``scale``.
The link of any other visual (a mesh that does not resolve, another format, a capsule, …) is left
to the stick figure (:class:`~parallel_gpc.viz.scene.StickFigure`), and the view says so in one
line (:class:`~parallel_gpc.errors.ParallelGPCWarning`). Only resolved files are ever read.
"""

from __future__ import annotations

import warnings
import xml.etree.ElementTree as ET
from io import BytesIO
from pathlib import Path

import coal
import numpy as np
import pinocchio as pin

from ..errors import ParallelGPCWarning, RobotFormatError
from ..model import ParallelRobot, read_bounded, read_text_bounded
from ..model.file_checks import URDF_MAX_BYTES
from ._meshcat import mg

#: Coal primitive shapes the viewer draws.
DRAWN_SHAPES = (coal.Cylinder, coal.Sphere, coal.Box)
#: Mesh file suffixes meshcat draws -> its format name.
MESH_FORMATS = {".stl": "stl", ".obj": "obj", ".dae": "dae"}
#: Largest mesh file read for the view, bytes (a larger one leaves its link to the stick figure).
MESH_MAX_BYTES = 64 << 20
#: three.js cylinders are along y; URDF/Coal cylinders along z: rotate y onto z.
Y_TO_Z = np.array([[1.0, 0, 0, 0], [0, 0, -1.0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])


class MeshFile(mg.MeshGeometry):
    """A mesh file's contents with a fixed 4x4 transform in the geometry's frame (the mesh's
    scale; for an overlay, a growth about the mesh's centre). meshcat puts the transform in the
    object's own matrix, so animating the object's node keeps it."""

    def __init__(self, contents, mesh_format: str, matrix: np.ndarray):
        super().__init__(contents, mesh_format)
        self.matrix = np.asarray(matrix, dtype=float)

    def intrinsic_transform(self) -> np.ndarray:
        return self.matrix

    def lower(self, object_data):
        return {"type": "_meshfile_geometry", "uuid": self.uuid, "format": self.mesh_format, "data": self.contents}


def is_mesh(g: pin.GeometryObject) -> bool:
    """True for a visual read from a mesh file (a Coal BVH model with a file path)."""
    return isinstance(g.geometry, coal.BVHModelBase) and Path(g.meshPath).suffix != ""


def _mesh_contents(path: Path):
    """The bytes of a mesh file as meshcat sends them (STL binary; OBJ and Collada text)."""
    data = read_bounded(path, MESH_MAX_BYTES, "mesh file")
    fmt = MESH_FORMATS[path.suffix.lower()]
    if fmt == "stl":
        return mg.StlMeshGeometry.from_stream(BytesIO(data)).contents
    return data.decode("utf-8", errors="replace")


def meshcat_shape(g: pin.GeometryObject, scale: float = 1.0,
                  meshes: dict | None = None) -> tuple[mg.Geometry, np.ndarray]:
    """meshcat geometry of a drawn visual and its 4x4 intrinsic transform (local frame fix-up).

    Args:
        g: a visual of :func:`visual_model` (a cylinder, sphere, box or resolved mesh).
        scale: growth factor (the saturation overlay): radii and sides times ``scale``, a mesh
            about its bounding box's centre.
        meshes: the caller's ``{path: contents}`` of the mesh files read so far: a file is read
            once per such dict (None: read here).

    Raises:
        RobotFormatError: for shapes the viewer does not draw (capsules, cones, ...).
    """
    geometry = g.geometry
    if isinstance(geometry, coal.Cylinder):
        return mg.Cylinder(2.0 * geometry.halfLength, geometry.radius * scale), Y_TO_Z
    if isinstance(geometry, coal.Sphere):
        return mg.Sphere(geometry.radius * scale), np.eye(4)
    if isinstance(geometry, coal.Box):
        return mg.Box((2.0 * np.asarray(geometry.halfSide) * scale).tolist()), np.eye(4)
    if is_mesh(g) and Path(g.meshPath).suffix.lower() in MESH_FORMATS:
        vertices = np.asarray(geometry.vertices(), dtype=float).reshape(-1, 3)  # scaled by meshScale
        centre = (vertices.min(axis=0) + vertices.max(axis=0)) / 2 if vertices.size else np.zeros(3)
        matrix = np.diag([*np.asarray(g.meshScale, dtype=float), 1.0])
        if scale != 1.0:
            grow = np.eye(4)
            grow[:3, :3] *= scale
            grow[:3, 3] = centre * (1.0 - scale)
            matrix = grow @ matrix
        path = Path(g.meshPath)
        meshes = {} if meshes is None else meshes
        if path not in meshes:
            meshes[path] = _mesh_contents(path)
        return MeshFile(meshes[path], MESH_FORMATS[path.suffix.lower()], matrix), np.eye(4)
    raise RobotFormatError(
        f"visual geometry of type {type(geometry).__name__} is not drawn by the viewer; "
        "use cylinder, sphere, box or STL/OBJ/Collada mesh visuals in the URDF"
    )


def lowest_z(geometry, oMg: pin.SE3) -> float:
    """Lowest world z (m) of a cylinder, sphere, box or mesh placed at ``oMg``."""
    R, z = oMg.rotation, oMg.translation[2]
    if isinstance(geometry, coal.Cylinder):
        az = abs(R[2, 2])
        return z - az * geometry.halfLength - geometry.radius * np.sqrt(max(0.0, 1 - az * az))
    if isinstance(geometry, coal.Sphere):
        return z - geometry.radius
    if isinstance(geometry, coal.Box):
        return z - float(np.abs(R[2]) @ np.asarray(geometry.halfSide))
    if isinstance(geometry, coal.BVHModelBase):
        vertices = np.asarray(geometry.vertices(), dtype=float).reshape(-1, 3)
        return z + float((vertices @ R[2]).min()) if vertices.size else z
    return z


def _listed(uris) -> str:
    shown = ", ".join(repr(u) for u in uris[:3])
    return shown + (f" and {len(uris) - 3} more" if len(uris) > 3 else "")


def _unreadable(path: Path, read: bool) -> str | None:
    """Why a mesh file cannot be drawn (too large, or, when ``read``, not a mesh Coal reads), or None."""
    size = path.stat().st_size
    if size > MESH_MAX_BYTES:
        return f"{size} bytes, more than {MESH_MAX_BYTES}"
    if not read:
        return None
    try:
        coal.MeshLoader().load(str(path), np.ones(3))
    except (ValueError, RuntimeError) as exc:
        return _coal_message(exc)
    return None


def _coal_message(exc: Exception) -> str:
    """A Coal loader error in one line (its message, without the source file and line)."""
    lines = [line.removeprefix("message: ") for line in str(exc).splitlines()
             if line and not line.startswith(("From file:", "in function:", "at line:", "Hint:"))]
    return "; ".join(lines) or type(exc).__name__


def _urdf_for_view(robot: ParallelRobot, notes: list[str], read: bool) -> str:
    """The robot's URDF text with each drawable mesh named by its real path, and the ``<visual>``
    of every other mesh and every ``<collision>`` removed, so that Pinocchio reads only the files
    the view draws; a note appended to ``notes`` for each kind left out. ``read``: each mesh
    file is also loaded here by Coal and left out if it cannot be (else only its size is checked)."""
    description = robot.description
    root = ET.fromstring(read_text_bounded(description.urdf_path, URDF_MAX_BYTES, "model file"))
    unresolved, undrawn, unreadable, why = [], [], [], {}
    for link in root.iter("link"):
        for collision in link.findall("collision"):
            link.remove(collision)
        for visual in link.findall("visual"):
            mesh = visual.find("geometry/mesh")
            if mesh is None:
                continue
            uri = mesh.get("filename", "")
            found = description.mesh_files.get(uri)
            if found is None:
                unresolved.append(uri)
            elif Path(found).suffix.lower() not in MESH_FORMATS:
                undrawn.append(uri)
            else:
                if found not in why:
                    why[found] = _unreadable(Path(found), read)
                if why[found] is None:
                    mesh.set("filename", str(found))
                    continue
                unreadable.append(f"{uri!r}: {why[found]}")
            link.remove(visual)
    unresolved, undrawn, unreadable = (list(dict.fromkeys(x)) for x in (unresolved, undrawn, unreadable))
    if unresolved:
        notes.append(f"{len(unresolved)} mesh(es) ({_listed(unresolved)}) do not resolve")
    if undrawn:
        notes.append(f"{len(undrawn)} mesh(es) ({_listed(undrawn)}) are not STL, OBJ or Collada files")
    if unreadable:
        notes.append(f"{len(unreadable)} mesh file(s) cannot be read ({', '.join(unreadable[:3])}"
                     f"{' and more' if len(unreadable) > 3 else ''})")
    return ET.tostring(root, encoding="unicode")


def _urdf_visuals(robot: ParallelRobot, notes: list[str]) -> pin.GeometryModel:
    """The visuals Pinocchio reads from the URDF text of :func:`_urdf_for_view`: each mesh file is
    read once, by Pinocchio; only when one of them fails is each file loaded alone by Coal first
    (then the readable ones are read again), so that one unreadable mesh leaves only its own link
    to the stick figure."""
    found: list[str] = []
    try:
        return pin.buildGeomFromUrdfString(robot.model, _urdf_for_view(robot, found, read=False),
                                           pin.GeometryType.VISUAL)
    except (ValueError, RuntimeError):
        found.clear()
        return pin.buildGeomFromUrdfString(robot.model, _urdf_for_view(robot, found, read=True),
                                           pin.GeometryType.VISUAL)
    finally:
        notes += found


def visual_model(robot: ParallelRobot) -> pin.GeometryModel:
    """The robot's drawn visual geometry (from its URDF or MJCF model file) as a
    ``pinocchio.GeometryModel``: its cylinders, spheres, boxes and resolved STL/OBJ/Collada meshes
    of at most :data:`MESH_MAX_BYTES`.

    The links of other visuals (meshes that do not resolve in the robot's folder or the package
    path, cannot be read or are larger, other mesh formats, other shapes) are drawn as the stick
    figure instead, said in one line (:class:`~parallel_gpc.errors.ParallelGPCWarning`). An MJCF file whose meshes
    do not all resolve is not read for visuals at all (Pinocchio would look for them elsewhere):
    every link is then drawn as the stick figure.
    """
    description = robot.description
    path = str(description.urdf_path)
    notes = []
    if description.model_format != "mjcf":
        geom = _urdf_visuals(robot, notes)
    elif description.unresolved_meshes:
        notes.append(f"{len(description.unresolved_meshes)} mesh(es) ({_listed(description.unresolved_meshes)}) "
                     "do not resolve")
        geom = pin.GeometryModel()
    else:
        try:
            geom = pin.buildGeomFromMJCF(robot.model, path, pin.GeometryType.VISUAL)
        except (ValueError, RuntimeError) as exc:  # a mesh file Coal cannot read
            notes.append(f"its visuals cannot be read ({_coal_message(exc)})")
            geom = pin.GeometryModel()
    allowed = {Path(f).resolve() for f in description.mesh_files.values()}
    drawn, skipped = pin.GeometryModel(), []
    for g in geom.geometryObjects:
        mesh = Path(g.meshPath) if is_mesh(g) else None
        if isinstance(g.geometry, DRAWN_SHAPES) or (
                mesh is not None and mesh.suffix.lower() in MESH_FORMATS and mesh.resolve() in allowed
                and mesh.stat().st_size <= MESH_MAX_BYTES):
            drawn.addGeometryObject(g)
        else:
            skipped.append(mesh.name if mesh is not None else type(g.geometry).__name__)
    if skipped:
        notes.append(f"{len(skipped)} visual(s) ({_listed(sorted(set(skipped)))}) are not cylinders, spheres, boxes "
                     f"or resolved STL/OBJ/Collada meshes of at most {MESH_MAX_BYTES >> 20} MiB")
    if notes:
        warnings.warn(f"the view draws the links of {path!r} without drawable visuals as a stick figure: "
                      + "; ".join(notes) + " (meshes resolve in the robot's folder or the package path: "
                      "--package-path DIR, PARALLEL_GPC_PACKAGE_PATH or package_path=)", ParallelGPCWarning,
                      stacklevel=2)
    return drawn
