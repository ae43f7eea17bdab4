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
``robot.yaml``) or given by an explicit path. Every key a sidecar may hold is listed in
:data:`SIDECAR_KEYS`; any other key, and any unknown joint type, is an error.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import RobotFormatError
from .file_checks import (
    SIDECAR_MAX_BYTES,
    check_description,
    check_robot_argument,
    check_sidecar_types,
    read_text_bounded,
)

#: Folder of the embedded robot files (installed with the package or at the repo top level).
_PACKAGE_URDF = Path(__file__).resolve().parents[1] / "urdf"
_REPO_URDF = Path(__file__).resolve().parents[3] / "urdf"
DEFAULT_ROBOT = "planar_4rrr"
#: constraint rows of each closure kind.
CLOSURE_ROWS = {"point": 3, "weld": 6}
#: model file suffixes and their format.
MODEL_FORMATS = {".urdf": "urdf", ".xml": "mjcf", ".mjcf": "mjcf"}
SIDECAR_SUFFIXES = (".toml", ".yaml", ".yml")
#: joint types a sidecar may set (``joint_name`` / ``joint_type``, Gepetto-compatible).
JOINT_TYPES = ("SPHERICAL", "UJOINT", "FIXED", "REVOLUTE", "PRISMATIC")
#: output kinds: joint coordinates, or the position (and orientation) of a named frame.
OUTPUT_KINDS = ("joints", "position", "pose")
#: task-space output axes; r* are the rotation-vector components of the frame's rotation
#: relative to its home orientation (rad).
POSE_AXES = ("x", "y", "z", "rx", "ry", "rz")
ROOTS = ("fixed", "free_flyer")

_COMMON_KEYS = {"name", "description", "output", "home", "joint_name", "joint_type", "root"}
#: Every key a sidecar may hold, per table; anything else is refused (never ignored).
SIDECAR_KEYS = {
    "toml": _COMMON_KEYS | {"closures", "drives"},
    "gepetto": _COMMON_KEYS | {"closed_loop", "type", "name_mot", "output_joints", "output_frame",
                               "torque_limit"},
    "closures": {"name", "kind", "frames"},
    "drives": {"joints", "torque_limit"},
    "output": {"joints", "frame", "kind", "axes", "labels", "units"},
    "home": {"pose", "q_guess", "branch_joints", "A", "B"},
}


def urdf_dir() -> Path:
    """Folder holding the embedded robots (package data first, then the repository's urdf/)."""
    return _PACKAGE_URDF if _PACKAGE_URDF.is_dir() else _REPO_URDF


def embedded_robots() -> list[str]:
    """Names of the embedded robots (``planar_4rrr``, ``planar_3rrr``, …)."""
    return sorted({p.stem for p in urdf_dir().iterdir() if p.suffix in MODEL_FORMATS
                   and any(p.with_suffix(s).exists() for s in SIDECAR_SUFFIXES)})


@dataclass(frozen=True)
class Closure:
    """One loop closure: two frames that must coincide.

    Attributes:
        name: label used in messages.
        kind: ``"point"`` (3 rows: positions coincide) or ``"weld"`` (6 rows: full pose).
        frames: the two frame names (a, b).
    """

    name: str
    kind: str
    frames: tuple[str, str]


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
        model_format: ``"urdf"`` or ``"mjcf"``.
        sidecar_path: the sidecar read.
        output_units: ``[output] units`` as written (checked against the output kinds at build
            time: "m" for lengths, "rad" for angles), or None.
        pose_a, pose_b: (n_y,) default start and end poses of point-to-point planning
            (sidecar ``[home] A = [...]``, ``B = [...]``, output units m and rad), or None.
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
    model_format: str = "urdf"
    sidecar_path: Path | None = None
    output_units: tuple[str, ...] | None = None
    pose_a: tuple[float, ...] | None = None
    pose_b: tuple[float, ...] | None = None

    @property
    def n_y(self) -> int:
        """Number of output coordinates."""
        return len(self.output_joints) if self.output_kind == "joints" else len(self.output_axes)


def _resolve_robot_path(name_or_path: str | Path, sidecar: str | Path | None = None) -> tuple[Path, Path]:
    """Return (model file, sidecar) for an embedded robot name or a path to a model file or sidecar."""
    check_robot_argument(name_or_path)
    path = Path(name_or_path)
    if path.suffix == "" and not path.exists():
        found = [urdf_dir() / f"{name_or_path}{s}" for s in MODEL_FORMATS]
        found = [p for p in found if p.exists()]
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
        models = [path.with_suffix(s) for s in MODEL_FORMATS if path.with_suffix(s).exists()]
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
    for suffix in SIDECAR_SUFFIXES:
        if path.with_suffix(suffix).exists():
            return path, path.with_suffix(suffix)
    raise RobotFormatError(
        f"no sidecar next to {str(path)!r}; expected {path.stem}.toml or {path.stem}.yaml, or pass sidecar=PATH"
    )


def _read_sidecar(path: Path) -> dict:
    text = read_text_bounded(path, SIDECAR_MAX_BYTES, "sidecar")
    try:
        if path.suffix == ".toml":
            return tomllib.loads(text)
        import yaml

        data = yaml.safe_load(text)
    except Exception as exc:  # parser errors differ per format; report them as ours
        raise RobotFormatError(f"cannot parse sidecar {str(path)!r}: {exc}") from exc
    if not isinstance(data, dict):
        raise RobotFormatError(f"sidecar {str(path)!r} must hold a mapping, got {type(data).__name__}")
    return data


def _check_keys(table, allowed: set, what: str, where: str) -> dict:
    """``table`` as a dict whose keys are all in ``allowed`` (unknown keys are errors)."""
    if table is None:
        return {}
    if not isinstance(table, dict):
        raise RobotFormatError(f"sidecar {where}: {what} = {table!r} must be a table")
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise RobotFormatError(f"sidecar {where}: unknown key(s) {unknown} in {what}; accepted keys are "
                               f"{sorted(allowed)}")
    return table


def _require(data: dict, key: str, where: str):
    if key not in data:
        raise RobotFormatError(f"sidecar {where} lacks the key {key!r}")
    return data[key]


def _names(value, key: str, where: str) -> tuple[str, ...]:
    """A list of names from the sidecar, checked (a bare string is a typo, not a list)."""
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        raise RobotFormatError(f"sidecar {where}: {key} = {value!r} must be a list of names")
    return tuple(value)


def _closures_from_gepetto(data: dict, where: str) -> tuple[Closure, ...]:
    pairs = _require(data, "closed_loop", where)
    if not isinstance(pairs, list) or not all(isinstance(p, (list, tuple)) and len(p) == 2 for p in pairs):
        raise RobotFormatError(f"sidecar {where}: closed_loop = {pairs!r} must be a list of [frame_a, frame_b] pairs")
    kinds = data.get("type", ["6d"] * len(pairs))
    if len(kinds) != len(pairs):
        raise RobotFormatError(
            f"sidecar {where}: 'type' has {len(kinds)} entries for {len(pairs)} closed_loop pairs"
        )
    closures = []
    for i, (pair, kind) in enumerate(zip(pairs, kinds)):
        mapped = {"3d": "point", "6d": "weld"}.get(str(kind).lower())
        if mapped is None:
            raise RobotFormatError(f"sidecar {where}: closure type {kind!r} is not '3D' or '6D'")
        closures.append(Closure(f"loop_{i + 1}", mapped, (str(pair[0]), str(pair[1]))))
    return tuple(closures)


def _closures_from_toml(raw, where: str) -> tuple[Closure, ...]:
    if not isinstance(raw, list) or not all(isinstance(c, dict) for c in raw):
        raise RobotFormatError(f"sidecar {where}: closures = {raw!r} must be a list of tables [[closures]]")
    closures = []
    for i, c in enumerate(raw):
        _check_keys(c, SIDECAR_KEYS["closures"], f"closure {i + 1}", where)
        kind = c.get("kind", "point")
        if kind not in CLOSURE_ROWS:
            raise RobotFormatError(
                f"sidecar {where}: closure {i + 1} kind {kind!r} is not one of {sorted(CLOSURE_ROWS)}"
            )
        frames = c.get("frames")
        if not isinstance(frames, list) or len(frames) != 2 or not all(isinstance(f, str) for f in frames):
            raise RobotFormatError(f"sidecar {where}: closure {i + 1} needs frames = [a, b], got {frames!r}")
        closures.append(Closure(c.get("name", f"loop_{i + 1}"), kind, (frames[0], frames[1])))
    return tuple(closures)


def _joint_types(data: dict, where: str) -> dict:
    names = _names(data.get("joint_name", []) or [], "joint_name", where)
    types = data.get("joint_type", []) or []
    if not isinstance(types, list) or len(types) != len(names):
        raise RobotFormatError(f"sidecar {where}: joint_type = {types!r} must be a list of {len(names)} types, "
                               f"one per joint_name")
    out = {}
    for name, kind in zip(names, types):
        k = str(kind).upper()
        if k not in JOINT_TYPES:
            raise RobotFormatError(f"sidecar {where}: joint {name!r} has unknown joint_type {kind!r}; "
                                   f"valid types are {list(JOINT_TYPES)}")
        out[name] = k
    return out


def _output_spec(output: dict, data: dict, where: str):
    """(kind, joints, frame, axes) of the output table."""
    kind = output.get("kind", "joints")
    if kind not in OUTPUT_KINDS:
        raise RobotFormatError(f"sidecar {where}: output kind {kind!r} is not one of {list(OUTPUT_KINDS)}")
    frame = output.get("frame") or data.get("output_frame", "")
    if kind == "joints":
        if "axes" in output:
            raise RobotFormatError(f"sidecar {where}: output axes need kind = 'position' or 'pose'")
        joints = output.get("joints") or data.get("output_joints")
        if joints is None:
            raise RobotFormatError(f"sidecar {where}: the output needs joints = [...] (joint coordinates) or "
                                   f"frame = NAME with kind = 'position' | 'pose'")
        return kind, _names(joints, "output joints", where), frame, ()
    if "joints" in output or "output_joints" in data:
        raise RobotFormatError(f"sidecar {where}: output kind {kind!r} takes a frame, not joints")
    if not frame:
        raise RobotFormatError(f"sidecar {where}: output kind {kind!r} needs frame = NAME")
    valid = POSE_AXES[:3] if kind == "position" else POSE_AXES
    axes = _names(output.get("axes", list(valid)), "output axes", where)
    if not axes or any(a not in valid for a in axes) or list(axes) != [a for a in valid if a in axes]:
        raise RobotFormatError(f"sidecar {where}: output axes {list(axes)} must be a non-empty subset of "
                               f"{list(valid)} in that order")
    return kind, (), frame, axes


def _torque_limits(limits, n: int, where: str):
    if limits is None:
        return None
    try:
        limits = tuple(float(x) for x in (limits if isinstance(limits, list) else [limits] * n))
    except (TypeError, ValueError):
        raise RobotFormatError(f"sidecar {where}: torque_limit {limits!r} must hold {n} numbers > 0 (N·m)") from None
    if len(limits) != n or any(not (x > 0 and math.isfinite(x)) for x in limits):
        raise RobotFormatError(f"sidecar {where}: torque_limit {list(limits)} must hold {n} finite values > 0 (N·m)")
    return limits


def _pose(value, key: str, n_y: int, where: str) -> tuple[float, ...] | None:
    """An optional pose of ``n_y`` finite numbers from the sidecar (None if absent)."""
    if value is None:
        return None
    try:
        pose = tuple(float(x) for x in value)
    except (TypeError, ValueError):
        pose = ()
    if len(pose) != n_y or not all(math.isfinite(x) for x in pose):
        raise RobotFormatError(f"sidecar {where}: {key} = {value!r} must hold {n_y} finite numbers "
                               f"(one per output coordinate, m or rad)")
    return pose


def _q_guess(raw, where: str) -> dict:
    out = {}
    for k, v in (raw or {}).items():
        try:
            out[str(k)] = tuple(float(x) for x in v) if isinstance(v, (list, tuple)) else float(v)
        except (TypeError, ValueError):
            raise RobotFormatError(f"sidecar {where}: home.q_guess {k} = {v!r} must be a number "
                                   f"(or a list of nq numbers for a multi-DOF joint)") from None
    return out


def load_description(name_or_path: str | Path = DEFAULT_ROBOT, sidecar: str | Path | None = None) -> RobotDescription:
    """Read a robot file: an embedded robot name, or a path to its model file or sidecar.

    Args:
        name_or_path: embedded robot name, or path of a ``.urdf`` / MJCF ``.xml`` file or of its sidecar.
        sidecar: explicit sidecar path (default: the model file's stem with ``.toml``/``.yaml``).

    Raises:
        RobotFormatError: missing file, unparsable sidecar, missing or unknown keys, unknown
            joint types, SDF files.
    """
    model_file, sidecar = _resolve_robot_path(name_or_path, sidecar)
    data = _read_sidecar(sidecar)
    where = repr(str(sidecar))
    check_sidecar_types(data, where)
    fmt = MODEL_FORMATS[model_file.suffix]
    gepetto = "closed_loop" in data or "name_mot" in data
    _check_keys(data, SIDECAR_KEYS["gepetto" if gepetto else "toml"], "the top level", where)
    output = _check_keys(data.get("output"), SIDECAR_KEYS["output"], "[output]", where)
    home = _check_keys(data.get("home"), SIDECAR_KEYS["home"], "[home]", where)
    if gepetto:
        closures = _closures_from_gepetto(data, where) if "closed_loop" in data or fmt == "urdf" else ()
        drives = _names(_require(data, "name_mot", where), "name_mot", where)
        limits = data.get("torque_limit")
    else:
        raw = data.get("closures", []) if fmt == "mjcf" else _require(data, "closures", where)
        closures = _closures_from_toml(raw, where)
        drives_tbl = _check_keys(_require(data, "drives", where), SIDECAR_KEYS["drives"], "[drives]", where)
        drives = _names(_require(drives_tbl, "joints", where), "drives.joints", where)
        limits = drives_tbl.get("torque_limit")
        if "output" not in data:
            raise RobotFormatError(f"sidecar {where} lacks the key 'output'")
    kind, out_joints, out_frame, axes = _output_spec(output, data, where)
    root = data.get("root", "fixed")
    if root not in ROOTS:
        raise RobotFormatError(f"sidecar {where}: root = {root!r} is not one of {list(ROOTS)}")
    n_y = len(out_joints) if kind == "joints" else len(axes)
    labels = tuple(output.get("labels", list(axes) if axes else [f"y{i}" for i in range(n_y)]))
    if len(labels) != n_y:
        raise RobotFormatError(f"sidecar {where}: output labels {list(labels)} must name the {n_y} outputs")
    pose, ends = home.get("pose"), {key: _pose(home.get(key), f"home.{key}", n_y, where) for key in ("A", "B")}
    description = RobotDescription(
        name=str(data.get("name", model_file.stem)),
        urdf_path=model_file,
        closures=closures,
        drive_joints=drives,
        output_joints=out_joints,
        output_frame=out_frame,
        output_labels=labels,
        torque_limit=_torque_limits(limits, len(drives), where),
        home_pose=_pose(pose, "home.pose", n_y, where),
        q_guess=_q_guess(home.get("q_guess"), where),
        branch_joints=_names(home.get("branch_joints", []), "home.branch_joints", where),
        output_kind=kind,
        output_axes=axes,
        joint_types=_joint_types(data, where),
        root=root,
        model_format=fmt,
        sidecar_path=sidecar,
        output_units=_names(output["units"], "output units", where) if "units" in output else None,
        pose_a=ends["A"],
        pose_b=ends["B"],
    )
    check_description(description)
    return description
