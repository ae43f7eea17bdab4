"""Robot description: what a robot file says (URDF open tree + closure sidecar), no Pinocchio.

A robot file is a URDF open tree and a sidecar of the same stem (``.toml`` or ``.yaml``)
naming the loop closures, the drives (order = order of u), the output coordinates (platform
pose y) and optional drive torque limits and home pose. Gepetto-style YAML sidecars
(``closed_loop``, ``type``, ``name_mot``) load as well.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import RobotFormatError

#: Folder of the embedded robot files (installed with the package or at the repo top level).
_PACKAGE_URDF = Path(__file__).resolve().parents[1] / "urdf"
_REPO_URDF = Path(__file__).resolve().parents[3] / "urdf"
DEFAULT_ROBOT = "planar_4rrr"
#: constraint rows of each closure kind.
CLOSURE_ROWS = {"point": 3, "weld": 6}
_CLOSURE_ROWS = CLOSURE_ROWS


def urdf_dir() -> Path:
    """Folder holding the embedded robots (package data first, then the repository's urdf/)."""
    return _PACKAGE_URDF if _PACKAGE_URDF.is_dir() else _REPO_URDF


def embedded_robots() -> list[str]:
    """Names of the embedded robots (``planar_4rrr``, ``planar_3rrr``)."""
    return sorted(p.stem for p in urdf_dir().glob("*.urdf"))


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
        urdf_path: path of the URDF open tree.
        closures: loop closures.
        drive_joints: actuated joint names, in the order of u.
        output_joints: joints whose coordinates are y (platform pose), in order.
        output_frame: frame of the platform (for drawing and forward kinematics).
        output_labels: names of the y coordinates.
        torque_limit: (n_u,) symmetric drive torque limits in N·m, or None.
        home_pose: (n_y,) home platform pose (m, rad).
        q_guess: rough joint values at the home pose (rad or m), by joint name.
        branch_joints: passive joints whose sign of sin(q) fixes the assembly branch.
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


def _resolve_robot_path(name_or_path: str | Path) -> tuple[Path, Path]:
    """Return (urdf, sidecar) for an embedded robot name or a path to a URDF or sidecar."""
    path = Path(name_or_path)
    if path.suffix == "" and not path.exists():
        path = urdf_dir() / f"{name_or_path}.urdf"
        if not path.exists():
            raise RobotFormatError(
                f"unknown robot {str(name_or_path)!r}; embedded robots are "
                f"{embedded_robots()}, or give a path to a .urdf file"
            )
    urdf = path if path.suffix == ".urdf" else path.with_suffix(".urdf")
    if not urdf.exists():
        raise RobotFormatError(f"URDF file {str(urdf)!r} does not exist")
    for suffix in (".toml", ".yaml", ".yml"):
        sidecar = urdf.with_suffix(suffix)
        if path.suffix == suffix:
            sidecar = path
        if sidecar.exists():
            return urdf, sidecar
    raise RobotFormatError(
        f"no closure sidecar next to {str(urdf)!r}; expected {urdf.stem}.toml or {urdf.stem}.yaml"
    )


def _read_sidecar(path: Path) -> dict:
    text = path.read_text()
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


def _require(data: dict, key: str, where: str):
    if key not in data:
        raise RobotFormatError(f"sidecar {where} lacks the key {key!r}")
    return data[key]


def _names(value, key: str, where: str) -> tuple[str, ...]:
    """A list of joint names from the sidecar, checked (a bare string is a typo, not a list)."""
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        raise RobotFormatError(f"sidecar {where}: {key} = {value!r} must be a list of joint names")
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
        k = str(kind).lower()
        mapped = {"3d": "point", "6d": "weld"}.get(k)
        if mapped is None:
            raise RobotFormatError(f"sidecar {where}: closure type {kind!r} is not '3D' or '6D'")
        closures.append(Closure(f"loop_{i + 1}", mapped, (str(pair[0]), str(pair[1]))))
    return tuple(closures)


def load_description(name_or_path: str | Path = DEFAULT_ROBOT) -> RobotDescription:
    """Read a robot file: an embedded robot name, or a path to its URDF or sidecar.

    Raises:
        RobotFormatError: missing file, unparsable sidecar or missing keys.
    """
    urdf, sidecar = _resolve_robot_path(name_or_path)
    data = _read_sidecar(sidecar)
    where = repr(str(sidecar))
    if "closed_loop" in data:  # Gepetto-style
        closures = _closures_from_gepetto(data, where)
        drives = _names(_require(data, "name_mot", where), "name_mot", where)
        output = data.get("output") or {}
        out_joints = _names(output.get("joints") or _require(data, "output_joints", where), "output joints", where)
        out_frame = output.get("frame") or data.get("output_frame", "")
        limits = data.get("torque_limit")
        home = data.get("home", {}) or {}
    else:
        raw = _require(data, "closures", where)
        if not isinstance(raw, list) or not all(isinstance(c, dict) for c in raw):
            raise RobotFormatError(f"sidecar {where}: closures = {raw!r} must be a list of tables [[closures]]")
        closures = []
        for i, c in enumerate(raw):
            kind = c.get("kind", "point")
            if kind not in _CLOSURE_ROWS:
                raise RobotFormatError(
                    f"sidecar {where}: closure {i + 1} kind {kind!r} is not one of {sorted(_CLOSURE_ROWS)}"
                )
            frames = c.get("frames")
            if not isinstance(frames, list) or len(frames) != 2 or not all(isinstance(f, str) for f in frames):
                raise RobotFormatError(f"sidecar {where}: closure {i + 1} needs frames = [a, b], got {frames!r}")
            closures.append(Closure(c.get("name", f"loop_{i + 1}"), kind, (frames[0], frames[1])))
        closures = tuple(closures)
        drives_tbl = _require(data, "drives", where)
        drives = _names(_require(drives_tbl, "joints", where), "drives.joints", where)
        limits = drives_tbl.get("torque_limit")
        output = _require(data, "output", where)
        out_joints = _names(_require(output, "joints", where), "output.joints", where)
        out_frame = output.get("frame", "")
        home = data.get("home", {})
    if limits is not None:
        try:
            limits = tuple(float(x) for x in (limits if isinstance(limits, list) else [limits] * len(drives)))
        except (TypeError, ValueError):
            raise RobotFormatError(
                f"sidecar {where}: torque_limit {limits!r} must hold {len(drives)} numbers > 0 (N·m)"
            ) from None
        if len(limits) != len(drives) or any(not (x > 0 and math.isfinite(x)) for x in limits):
            raise RobotFormatError(
                f"sidecar {where}: torque_limit {list(limits)} must hold {len(drives)} finite values > 0 (N·m)"
            )
    pose = home.get("pose")
    return RobotDescription(
        name=str(data.get("name", urdf.stem)),
        urdf_path=urdf,
        closures=closures,
        drive_joints=drives,
        output_joints=out_joints,
        output_frame=out_frame,
        output_labels=tuple(output.get("labels", [f"y{i}" for i in range(len(out_joints))])),
        torque_limit=limits,
        home_pose=tuple(float(x) for x in pose) if pose is not None else None,
        q_guess={str(k): float(v) for k, v in (home.get("q_guess") or {}).items()},
        branch_joints=tuple(home.get("branch_joints", ())),
    )

