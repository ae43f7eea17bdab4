"""The sidecar's vocabulary and its field readers: what a sidecar may say and how each field is read.

A sidecar (``.toml`` or Gepetto-style ``.yaml``) names the loop closures, drives, output, joint-type
overrides, root, torque limits and home pose of a robot file; :mod:`.description` assembles the
fields read here into a :class:`~parallel_gpc.model.RobotDescription`. Every reader checks its
field and raises :class:`~parallel_gpc.errors.RobotFormatError` naming the sidecar, the key, the
bad value and what would be valid; nothing is ignored.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

from ..errors import RobotFormatError
from .file_checks import SIDECAR_MAX_BYTES, read_text_bounded

#: constraint rows of each closure kind.
CLOSURE_ROWS = {"point": 3, "weld": 6}
#: universal joints with named axes (Gepetto's ``UJOINT_XY`` …): about the first coordinate axis of
#: the joint frame, then the second (``UJOINT_ZY``: z then y); every pair of distinct axes.
UJOINT_AXES = tuple(f"UJOINT_{a}{b}" for a in "XYZ" for b in "XYZ" if a != b)
#: joint types a sidecar may set (``joint_name`` / ``joint_type``, Gepetto-compatible).
JOINT_TYPES = ("SPHERICAL", "UJOINT", *UJOINT_AXES, "FIXED", "REVOLUTE", "PRISMATIC")
#: output kinds: joint coordinates, or the position (and orientation) of a named frame.
OUTPUT_KINDS = ("joints", "position", "pose")
#: task-space output axes; r* are the rotation-vector components of the frame's rotation
#: relative to its home orientation (rad).
POSE_AXES = ("x", "y", "z", "rx", "ry", "rz")
ROOTS = ("fixed", "free_flyer")
#: what loading does with idle motions (closure motions that move neither the output nor a drive,
#: such as a rod spinning between two ball joints): lock one joint per motion, or refuse the robot.
IDLE_SPINS = ("lock", "refuse")

_COMMON_KEYS = {"name", "description", "output", "home", "joint_name", "joint_type", "root", "sensors", "limits",
                "idle_spins"}
#: Every key a sidecar may hold, per table; anything else is refused (never ignored).
SIDECAR_KEYS = {
    "toml": _COMMON_KEYS | {"closures", "drives"},
    "gepetto": _COMMON_KEYS | {"closed_loop", "type", "name_mot", "output_joints", "output_frame",
                               "torque_limit"},
    "closures": {"name", "kind", "frames"},
    "drives": {"joints", "torque_limit"},
    "output": {"joints", "frame", "kind", "axes", "labels", "units"},
    "home": {"pose", "q_guess", "branch_joints", "A", "B"},
    "sensors": {"counts_per_rev", "counts_per_m", "rates"},
    "limits": {"drive_position", "drive_rate", "output_box", "output_velocity", "joint_position", "joint_ranges",
               "soft", "penalty"},
}



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


def _yaml_load(text: str, path: Path):
    """``yaml.safe_load`` refusing aliases (``*name``, also in ``<<: *name`` merges): a chain of
    aliases expands exponentially (a 1 KB "billion laughs" file took minutes and gigabytes), and
    a sidecar never needs one. The events are scanned first (libyaml's C parser when PyYAML has
    it: a 1 MB sidecar parses in a fraction of a second)."""
    import yaml

    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    for event in yaml.parse(text, Loader=loader):
        if isinstance(event, yaml.AliasEvent):
            raise RobotFormatError(
                f"sidecar {str(path)!r} line {event.start_mark.line + 1}: YAML alias *{event.anchor} is not "
                "accepted (aliases can expand exponentially); write the values out")
    return yaml.load(text, Loader=loader)


def read_sidecar(path: Path) -> dict:
    text = read_text_bounded(path, SIDECAR_MAX_BYTES, "sidecar")
    try:
        data = tomllib.loads(text) if path.suffix == ".toml" else _yaml_load(text, path)
    except RobotFormatError:
        raise
    except Exception as exc:  # parser errors differ per format; report them as ours
        raise RobotFormatError(f"cannot parse sidecar {str(path)!r}: {exc}") from exc
    if not isinstance(data, dict):
        raise RobotFormatError(f"sidecar {str(path)!r} must hold a mapping, got {type(data).__name__}")
    return data


def check_keys(table, allowed: set, what: str, where: str) -> dict:
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


def require_field(data: dict, key: str, where: str):
    if key not in data:
        raise RobotFormatError(f"sidecar {where} lacks the key {key!r}")
    return data[key]


def names_field(value, key: str, where: str) -> tuple[str, ...]:
    """A list of names from the sidecar as a tuple. Its type (a list of strings; a bare string
    is a typo, not a list) was checked for every key by
    :func:`~parallel_gpc.model.file_checks.check_sidecar_types` before parsing."""
    return tuple(value)


def closures_from_gepetto(data: dict, where: str) -> tuple[Closure, ...]:
    pairs = require_field(data, "closed_loop", where)
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


def closures_from_toml(raw, where: str) -> tuple[Closure, ...]:
    if not isinstance(raw, list) or not all(isinstance(c, dict) for c in raw):
        raise RobotFormatError(f"sidecar {where}: closures = {raw!r} must be a list of tables [[closures]]")
    closures = []
    for i, c in enumerate(raw):
        check_keys(c, SIDECAR_KEYS["closures"], f"closure {i + 1}", where)
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


def joint_types(data: dict, where: str) -> dict:
    names = names_field(data.get("joint_name", []) or [], "joint_name", where)
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


def output_spec(output: dict, data: dict, where: str):
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
        return kind, names_field(joints, "output joints", where), frame, ()
    if "joints" in output or "output_joints" in data:
        raise RobotFormatError(f"sidecar {where}: output kind {kind!r} takes a frame, not joints")
    if not frame:
        raise RobotFormatError(f"sidecar {where}: output kind {kind!r} needs frame = NAME")
    valid = POSE_AXES[:3] if kind == "position" else POSE_AXES
    axes = names_field(output.get("axes", list(valid)), "output axes", where)
    if not axes or any(a not in valid for a in axes) or list(axes) != [a for a in valid if a in axes]:
        raise RobotFormatError(f"sidecar {where}: output axes {list(axes)} must be a non-empty subset of "
                               f"{list(valid)} in that order")
    return kind, (), frame, axes


def torque_limits_field(limits, n: int, where: str):
    if limits is None:
        return None
    try:
        limits = tuple(float(x) for x in (limits if isinstance(limits, list) else [limits] * n))
    except (TypeError, ValueError):
        raise RobotFormatError(f"sidecar {where}: torque_limit {limits!r} must hold {n} numbers > 0 (N·m)") from None
    if len(limits) != n or any(not (x > 0 and math.isfinite(x)) for x in limits):
        raise RobotFormatError(f"sidecar {where}: torque_limit {list(limits)} must hold {n} finite values > 0 (N·m)")
    return limits


def pose_field(value, key: str, n_y: int, where: str) -> tuple[float, ...] | None:
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


def q_guess_field(raw, where: str) -> dict:
    out = {}
    for k, v in (raw or {}).items():
        try:
            out[str(k)] = tuple(float(x) for x in v) if isinstance(v, (list, tuple)) else float(v)
        except (TypeError, ValueError):
            raise RobotFormatError(f"sidecar {where}: home.q_guess {k} = {v!r} must be a number "
                                   f"(or a list of nq numbers for a multi-DOF joint)") from None
    return out


def read_limits(raw, drives: tuple[str, ...], where: str) -> dict:
    """The ``[limits]`` table as plain values (checked for kind and shape here; the numbers are
    validated when the robot makes its :class:`~parallel_gpc.limits.Limits`):

    * ``drive_position``: ``"urdf"`` (the drives' ``<limit>`` ranges of the model file), one pair
      ``[lo, hi]`` for every drive, one pair per drive, or a table ``{drive_joint = [lo, hi]}``
      (m or rad); ``drive_rate`` (m/s or rad/s), ``output_box`` (pairs, m and rad),
      ``output_velocity`` (m/s, rad/s) as in :class:`~parallel_gpc.limits.Limits`;
    * ``joint_ranges``: ``"urdf"`` (every passive one-DOF joint's ``<limit>`` range of the model
      file; opt-in) and/or ``joint_position``: a table ``{joint = [lo, hi]}`` (rad or m; the
      names are checked against the model's passive joints when the robot makes its limits);
    * ``soft``: the kinds relaxed by slack variables (default every state kind), ``penalty`` ρ.

    Raises:
        RobotFormatError: an unknown key, a drive_position table naming a joint that is not a
            drive, a value of the wrong type.
    """
    table = check_keys(raw, SIDECAR_KEYS["limits"], "[limits]", where)
    out = dict(table)
    dp = table.get("drive_position")
    if isinstance(dp, str) and dp != "urdf":
        raise RobotFormatError(f"sidecar {where}: limits.drive_position = {dp!r}; valid: \"urdf\" (the model "
                               "file's ranges), [lo, hi], one pair per drive, or a table {drive_joint = [lo, hi]}")
    if isinstance(dp, dict):
        unknown = sorted(set(dp) - set(drives))
        if unknown:
            raise RobotFormatError(f"sidecar {where}: limits.drive_position names {unknown}, which are not drive "
                                   f"joints; the drives are {list(drives)}")
    if "joint_ranges" in table and table["joint_ranges"] != "urdf":
        raise RobotFormatError(f"sidecar {where}: limits.joint_ranges = {table['joint_ranges']!r}; valid: \"urdf\" "
                               "(the model file's passive joint ranges), or leave it out")
    jp = table.get("joint_position")
    if jp is not None and not isinstance(jp, dict):
        raise RobotFormatError(f"sidecar {where}: limits.joint_position = {jp!r} must be a table "
                               "{joint_name = [lo, hi]} (rad or m)")
    if "soft" in table and (not isinstance(table["soft"], list) or not all(isinstance(k, str) for k in table["soft"])):
        raise RobotFormatError(f"sidecar {where}: limits.soft = {table['soft']!r} must be a list of kind names")
    return out


def read_sensors(raw, where: str) -> dict:
    """The ``[sensors]`` table: ``counts_per_rev`` (revolute drive encoders) and ``counts_per_m``
    (prismatic drives' scales), numbers > 0; ``rates`` (drive rates measured), a boolean."""
    table = check_keys(raw, SIDECAR_KEYS["sensors"], "[sensors]", where)
    out = {}
    for key in ("counts_per_rev", "counts_per_m"):
        if key in table:
            value = table[key]
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (0 < value < math.inf):
                raise RobotFormatError(f"sidecar {where}: sensors.{key} = {value!r} must be a finite number > 0")
            out[key] = float(value)
    if "rates" in table:
        if not isinstance(table["rates"], bool):
            raise RobotFormatError(f"sidecar {where}: sensors.rates = {table['rates']!r} must be true or false")
        out["rates"] = table["rates"]
    return out
