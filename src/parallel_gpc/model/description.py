"""Robot description: what a robot file says (model file + sidecar), no Pinocchio.

A robot file is a model file and a small sidecar (``.toml`` or ``.yaml``):

* **URDF + sidecar**: the URDF holds the open tree; the sidecar names the loop closures, the
  drives (order = order of u), the output y, optional joint-type overrides (spherical,
  universal, fixed), an optional free-flyer root, torque limits and the home pose.
  Gepetto-style YAML sidecars (``closed_loop``, ``type``, ``name_mot``, ``joint_name``,
  ``joint_type``) load as well.
* **MJCF + sidecar**: the MJCF carries its own loops (``<equality><connect/weld>``); the sidecar
  says only what the file cannot (drives, output, home, limits).

The sidecar is found next to the model file by stem (``robot.urdf`` → ``robot.toml`` /
``robot.yaml``; two of them side by side are refused as ambiguous) or given by an explicit path.
Mesh URIs of the model file resolve in its folder or under the package path
(:mod:`.meshes`); meshes do not matter for the dynamics, and those that do not resolve are listed
in ``unresolved_meshes``. Every key a sidecar may hold is listed in
:data:`SIDECAR_KEYS`; any other key, and any unknown joint type, is an error.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..errors import RobotFormatError
from .file_checks import check_description, check_robot_argument, check_sidecar_types
from .meshes import package_roots
from .sidecar import (
    CLOSURE_ROWS,
    JOINT_TYPES,
    OUTPUT_KINDS,
    POSE_AXES,
    ROOTS,
    IDLE_SPINS,
    SIDECAR_KEYS,
    Closure,
    check_keys,
    closures_from_gepetto,
    closures_from_toml,
    joint_types,
    names_field,
    output_spec,
    pose_field,
    q_guess_field,
    read_sidecar,
    require_field,
    torque_limits_field,
    read_limits,
    read_sensors,
)

# The sidecar vocabulary lives in .sidecar; re-exported here (robot, closures, outputs, builder import it from here).
__all__ = ["DEFAULT_ROBOT", "MODEL_FORMATS", "SIDECAR_SUFFIXES", "urdf_dir", "embedded_robots", "RobotDescription",
           "load_description", "CLOSURE_ROWS", "JOINT_TYPES", "OUTPUT_KINDS", "POSE_AXES", "ROOTS", "IDLE_SPINS",
           "SIDECAR_KEYS",
           "Closure"]

#: Folder of the embedded robot files (installed with the package or at the repo top level).
_PACKAGE_URDF = Path(__file__).resolve().parents[1] / "urdf"
_REPO_URDF = Path(__file__).resolve().parents[3] / "urdf"
DEFAULT_ROBOT = "planar_4rrr"
#: model file suffixes and their format.
MODEL_FORMATS = {".urdf": "urdf", ".xml": "mjcf", ".mjcf": "mjcf"}
SIDECAR_SUFFIXES = (".toml", ".yaml", ".yml")


def urdf_dir() -> Path:
    """Folder holding the embedded robots (package data first, then the repository's urdf/)."""
    return _PACKAGE_URDF if _PACKAGE_URDF.is_dir() else _REPO_URDF


def embedded_robots() -> list[str]:
    """Names of the embedded robots (``planar_4rrr``, ``planar_3rrr``, …)."""
    return sorted({p.stem for p in urdf_dir().iterdir() if p.suffix in MODEL_FORMATS
                   and any(p.with_suffix(s).exists() for s in SIDECAR_SUFFIXES)})


@dataclass(frozen=True)
class RobotDescription:
    """What a robot file says (no Pinocchio objects).

    Attributes:
        name: robot name.
        urdf_path: path of the model file (URDF, or MJCF when ``model_format == "mjcf"``).
        closures: loop closures named by the sidecar (MJCF files add their own at build time).
        drive_joints: actuated joint names, in the order of u.
        output_joints: joints whose coordinates are y (``output_kind == "joints"``), in order.
        output_frame: frame of the platform (task-space output, drawing, forward kinematics).
        output_labels: names of the y coordinates.
        torque_limit: (n_u,) symmetric drive torque limits in N·m, or None.
        home_pose: (n_y,) home output (m, rad), or None (joints: from q_guess; task space:
            the output at the configuration assembled from q_guess).
        q_guess: rough joint values at the home pose (rad or m; a list of nq values for a
            multi-DOF joint), by joint name.
        branch_joints: passive 1-DOF joints whose sign of sin(q) fixes the assembly branch.
        output_kind: ``"joints"``, ``"position"`` or ``"pose"``.
        output_axes: task-space axes of y, a subset of :data:`POSE_AXES` in that order.
        joint_types: joint-type overrides by joint name (values in :data:`JOINT_TYPES`).
        root: ``"fixed"`` or ``"free_flyer"`` (a 6-DOF root joint named ``root_joint``).
        idle_spins: ``"lock"`` (default) or ``"refuse"`` (sidecar ``idle_spins``): what loading does
            with idle motions, closure motions that move neither the output nor a drive
            (:mod:`parallel_gpc.model.idle`).
        locked_joints: the joints loading locked, one per idle motion, at their value in the
            assembled drawing (also in ``joint_types`` as ``FIXED`` and in ``q_guess``); empty
            when nothing was locked.
        model_format: ``"urdf"`` or ``"mjcf"``.
        sidecar_path: the sidecar read.
        output_units: ``[output] units`` as written (checked against the output kinds at build
            time: "m" for lengths, "rad" for angles), or None.
        pose_a, pose_b: (n_y,) default start and end poses of point-to-point planning
            (sidecar ``[home] A = [...]``, ``B = [...]``, output units m and rad), or None.
        sensors: the sidecar's ``[sensors]`` table (``counts_per_rev``, ``counts_per_m``,
            ``rates``), checked; empty: the defaults of :mod:`parallel_gpc.estimation`.
        limits: the sidecar's ``[limits]`` table (state limits: drive_position, drive_rate,
            output_box, output_velocity, soft, penalty), as written; empty: none.
        package_path: folders searched for ``package://`` meshes after the model file's folder
            (:func:`~parallel_gpc.model.meshes.package_roots`: the ``package_path`` argument,
            ``PARALLEL_GPC_PACKAGE_PATH``, ``ROS_PACKAGE_PATH``).
        mesh_files: URI → file of the model file's meshes that resolve (filled when a
            :class:`~parallel_gpc.model.robot.ParallelRobot` reads the model file; no mesh is read).
        unresolved_meshes: URIs of the meshes that do not resolve in the model file's folder or
            the package path (filled with ``mesh_files``): the view draws the robot as a stick figure.
        mesh_references: the URI of every mesh reference of the model file, in file order (one
            per ``<mesh>`` element; filled with ``mesh_files``).
    """

    name: str
    urdf_path: Path
    closures: tuple[Closure, ...]
    drive_joints: tuple[str, ...]
    output_joints: tuple[str, ...]
    output_frame: str
    output_labels: tuple[str, ...] = ("x", "y", "psi")
    torque_limit: tuple[float, ...] | None = None
    home_pose: tuple[float, ...] | None = None
    q_guess: dict = field(default_factory=dict)
    branch_joints: tuple[str, ...] = ()
    output_kind: str = "joints"
    output_axes: tuple[str, ...] = ()
    joint_types: dict = field(default_factory=dict)
    root: str = "fixed"
    idle_spins: str = "lock"
    locked_joints: tuple[str, ...] = ()
    model_format: str = "urdf"
    sidecar_path: Path | None = None
    output_units: tuple[str, ...] | None = None
    pose_a: tuple[float, ...] | None = None
    pose_b: tuple[float, ...] | None = None
    sensors: dict = field(default_factory=dict)
    limits: dict = field(default_factory=dict)
    package_path: tuple[Path, ...] = ()
    mesh_files: dict = field(default_factory=dict)
    unresolved_meshes: tuple[str, ...] = ()
    mesh_references: tuple[str, ...] = ()

    @property
    def n_y(self) -> int:
        """Number of output coordinates."""
        return len(self.output_joints) if self.output_kind == "joints" else len(self.output_axes)

    @property
    def mesh_counts(self) -> dict[str, int]:
        """The model file's meshes counted three ways (filled when a robot reads the model file).

        Returns:
            ``references`` (mesh elements in the file), ``files`` (distinct files they resolve
            to: several links may draw one file, and several URIs may name it), ``missing``
            (references whose URI does not resolve) and ``missing_uris`` (distinct such URIs).
        """
        missing = set(self.unresolved_meshes)
        return {"references": len(self.mesh_references), "files": len(set(self.mesh_files.values())),
                "missing": sum(uri in missing for uri in self.mesh_references), "missing_uris": len(missing)}


def _one(found: list[Path], what: str) -> list[Path]:
    """``found`` if it holds at most one path; several files of one stem are ambiguous."""
    if len(found) > 1:
        raise RobotFormatError(f"{' and '.join(repr(str(p)) for p in found)} are {what} of the same robot side by "
                               "side: the choice would be silent; remove all but one, or name the one to use "
                               "(sidecar=PATH)")
    return found


def _resolve_robot_path(name_or_path: str | Path, sidecar: str | Path | None = None) -> tuple[Path, Path]:
    """Return (model file, sidecar) for an embedded robot name or a path to a model file or sidecar."""
    check_robot_argument(name_or_path)
    path = Path(name_or_path)
    if path.suffix == "" and not path.exists():
        found = [urdf_dir() / f"{name_or_path}{s}" for s in MODEL_FORMATS]
        found = _one([p for p in found if p.exists()], "model files")
        if not found:
            raise RobotFormatError(
                f"unknown robot {str(name_or_path)!r}; embedded robots are "
                f"{embedded_robots()}, or give a path to a .urdf or MJCF .xml file"
            )
        path = found[0]
    if path.suffix.lower() == ".sdf":
        raise RobotFormatError(
            f"{str(path)!r}: SDF is not supported (the Pinocchio wheels are built without SDFormat); "
            f"convert it to URDF + sidecar or MJCF"
        )
    if path.suffix in SIDECAR_SUFFIXES:
        sidecar = path if sidecar is None else sidecar
        models = _one([path.with_suffix(s) for s in MODEL_FORMATS if path.with_suffix(s).exists()], "model files")
        if not models:
            raise RobotFormatError(f"no model file next to sidecar {str(path)!r}; expected "
                                   f"{[path.stem + s for s in MODEL_FORMATS]}")
        path = models[0]
    if path.suffix not in MODEL_FORMATS:
        raise RobotFormatError(f"{str(path)!r} is not a robot file; valid suffixes are "
                               f"{list(MODEL_FORMATS) + list(SIDECAR_SUFFIXES)}")
    if not path.exists():
        raise RobotFormatError(f"model file {str(path)!r} does not exist")
    if sidecar is not None:
        sidecar = Path(sidecar)
        if not sidecar.exists() or sidecar.suffix not in SIDECAR_SUFFIXES:
            raise RobotFormatError(f"sidecar {str(sidecar)!r} does not exist or is not one of "
                                   f"{list(SIDECAR_SUFFIXES)}")
        return path, sidecar
    found = _one([path.with_suffix(s) for s in SIDECAR_SUFFIXES if path.with_suffix(s).exists()], "sidecars")
    if found:
        return path, found[0]
    raise RobotFormatError(
        f"no sidecar next to {str(path)!r}; expected {path.stem}.toml or {path.stem}.yaml, or pass sidecar=PATH"
    )


def idle_advice(description: "RobotDescription") -> str:
    """What an under-actuation refusal says about idle motions (moving neither the output nor a
    drive): the sidecar option ``idle_spins`` that locks them, or why it did not."""
    if description.idle_spins == "refuse":
        return ('set idle_spins = "lock" in the sidecar (the default) to lock one joint per idle motion '
                "(one that moves neither the output nor a drive) at load")
    return ('idle_spins = "lock" found no idle motion to lock (it locks only motions that move neither the output '
            "nor a drive, through a 1-DOF joint that is neither a drive, an output nor a branch joint)")


def load_description(name_or_path: str | Path = DEFAULT_ROBOT, sidecar: str | Path | None = None,
                     package_path=None) -> RobotDescription:
    """Read a robot file: an embedded robot name, or a path to its model file or sidecar.

    Args:
        name_or_path: embedded robot name, or path of a ``.urdf`` / MJCF ``.xml`` file or of its sidecar.
        sidecar: explicit sidecar path (default: the model file's stem with ``.toml``/``.yaml``).
        package_path: folder(s) holding the packages of ``package://`` mesh URIs, searched
            before ``PARALLEL_GPC_PACKAGE_PATH`` and ``ROS_PACKAGE_PATH``
            (:func:`~parallel_gpc.model.meshes.package_roots`).

    Raises:
        RobotFormatError: missing file, two sidecars (or model files) of one stem, unparsable
            sidecar, missing or unknown keys, unknown joint types, SDF files, a package folder
            that does not exist.
    """
    model_file, sidecar = _resolve_robot_path(name_or_path, sidecar)
    roots = package_roots(package_path)
    data = read_sidecar(sidecar)
    where = repr(str(sidecar))
    check_sidecar_types(data, where)
    fmt = MODEL_FORMATS[model_file.suffix]
    gepetto = "closed_loop" in data or "name_mot" in data
    check_keys(data, SIDECAR_KEYS["gepetto" if gepetto else "toml"], "the top level", where)
    output = check_keys(data.get("output"), SIDECAR_KEYS["output"], "[output]", where)
    home = check_keys(data.get("home"), SIDECAR_KEYS["home"], "[home]", where)
    if gepetto:
        closures = closures_from_gepetto(data, where) if "closed_loop" in data or fmt == "urdf" else ()
        drives = names_field(require_field(data, "name_mot", where), "name_mot", where)
        limits = data.get("torque_limit")
    else:
        raw = data.get("closures", []) if fmt == "mjcf" else require_field(data, "closures", where)
        closures = closures_from_toml(raw, where)
        drives_tbl = check_keys(require_field(data, "drives", where), SIDECAR_KEYS["drives"], "[drives]", where)
        drives = names_field(require_field(drives_tbl, "joints", where), "drives.joints", where)
        limits = drives_tbl.get("torque_limit")
        if "output" not in data:
            raise RobotFormatError(f"sidecar {where} lacks the key 'output'")
    kind, out_joints, out_frame, axes = output_spec(output, data, where)
    root = data.get("root", "fixed")
    if root not in ROOTS:
        raise RobotFormatError(f"sidecar {where}: root = {root!r} is not one of {list(ROOTS)}")
    idle = data.get("idle_spins", "lock")
    if idle not in IDLE_SPINS:
        raise RobotFormatError(f"sidecar {where}: idle_spins = {idle!r} is not one of {list(IDLE_SPINS)}")
    n_y = len(out_joints) if kind == "joints" else len(axes)
    labels = tuple(output.get("labels", list(axes) if axes else [f"y{i}" for i in range(n_y)]))
    if len(labels) != n_y:
        raise RobotFormatError(f"sidecar {where}: output labels {list(labels)} must name the {n_y} outputs")
    pose, ends = home.get("pose"), {key: pose_field(home.get(key), f"home.{key}", n_y, where) for key in ("A", "B")}
    description = RobotDescription(
        name=str(data.get("name", model_file.stem)),
        urdf_path=model_file,
        closures=closures,
        drive_joints=drives,
        output_joints=out_joints,
        output_frame=out_frame,
        output_labels=labels,
        torque_limit=torque_limits_field(limits, len(drives), where),
        home_pose=pose_field(pose, "home.pose", n_y, where),
        q_guess=q_guess_field(home.get("q_guess"), where),
        branch_joints=names_field(home.get("branch_joints", []), "home.branch_joints", where),
        output_kind=kind,
        output_axes=axes,
        joint_types=joint_types(data, where),
        root=root,
        idle_spins=idle,
        model_format=fmt,
        sidecar_path=sidecar,
        output_units=names_field(output["units"], "output units", where) if "units" in output else None,
        pose_a=ends["A"],
        pose_b=ends["B"],
        sensors=read_sensors(data.get("sensors"), where),
        limits=read_limits(data.get("limits"), drives, where),
        package_path=roots,
    )
    check_description(description)
    return description
