"""One result file format (``.npz``) for every command, and its one loader.

``track``, ``demo`` and ``plan`` write it; ``parallel-gpc view`` opens it. The file is a plain
NumPy archive read with ``allow_pickle=False``:

========================  ==============================================================
key                       content
========================  ==============================================================
``format``                ``"parallel-gpc-result"``
``format_version``        ``1``
``kind``                  what wrote it: ``"tracking"``, ``"plan"``, ``"reference"``,
                          ``"trajectory"``
``robot``                 an embedded robot name (``planar_4rrr``) or an absolute path
                          to the robot's URDF; ``""`` when there is no robot (a linear
                          test system)
``t``                     (K,) strictly increasing times, s
``q``                     (K, nq) assembled configurations (what the view animates)
``reference``             optional (K_r, n_y) reference platform poses (m, rad)
``planned``               optional (K_p, n_y) planned platform poses (m, rad)
``saturated``             optional (K, n_u) bools, True while a drive is at its limit
``meta``                  JSON text of the settings that produced the file
anything else             extra arrays of the writer (``u``, ``pose``, ``status``, …)
========================  ==============================================================

Files written before the format was versioned still load, as version 0: trajectories (keys
``t``, ``q``, ``robot``) and plans or references (``t``, ``poses``: read as ``planned``; they
name no robot, so ``view`` needs ``--robot``). This module depends only on NumPy, the error types and the robot description,
so every layer (``gpc.planning``, ``studies``, ``viz``, ``cli``) can use it.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .limits import Limits, as_limits
from .errors import InvalidParameterError, ResultFormatError, ShapeError, writing
from .model.description import embedded_robots, urdf_dir
from .validation import finite_matrix, finite_vector, regular_file

#: Value of the ``format`` key.
FORMAT = "parallel-gpc-result"
#: Version written by :func:`save_result`; :func:`load_result` reads versions 0 … this one.
FORMAT_VERSION = 1
#: Largest result file read: total unpacked size of its arrays, bytes (checked before reading).
MAX_RESULT_BYTES = 1 << 30
#: Keys with a fixed meaning (everything else is an extra array of the writer).
STANDARD_KEYS = ("format", "format_version", "kind", "robot", "t", "q", "reference", "planned", "saturated",
                 "meta")


@dataclass(frozen=True)
class ResultFile:
    """A result file's content, as :func:`load_result` returns it.

    Attributes:
        robot: embedded robot name or absolute URDF path; ``""`` if the file names no robot.
        t: (K,) times, s.
        q: (K, nq) assembled configurations, or None.
        reference, planned: (K', n_y) platform poses (m, rad), or None.
        saturated: (K, n_u) drive-at-limit flags, or None.
        kind: what wrote the file (``"tracking"``, ``"plan"``, …; ``"trajectory"`` for version 0).
        meta: the writer's settings (from the JSON ``meta`` key; empty if absent).
        arrays: every other array of the file, by key.
        version: the file's format version (0: written before versioning).
    """

    robot: str
    t: np.ndarray
    q: np.ndarray | None = None
    reference: np.ndarray | None = None
    planned: np.ndarray | None = None
    saturated: np.ndarray | None = None
    kind: str = "trajectory"
    meta: dict = field(default_factory=dict)
    arrays: dict = field(default_factory=dict)
    version: int = FORMAT_VERSION


def robot_reference(robot) -> str:
    """How a result file names a robot: its embedded name, else the absolute URDF path.

    Args:
        robot: a ``ParallelRobot``, a ``RobotDescription``, an embedded robot name, a path to
            a URDF or sidecar, or None (no robot: ``""``).
    """
    if robot is None:
        return ""
    description = getattr(robot, "description", robot)
    urdf = getattr(description, "urdf_path", None)
    if urdf is None:
        text = str(robot)
        if text in embedded_robots():
            return text
        urdf = Path(text).with_suffix(".urdf")
    urdf = Path(urdf).resolve()
    embedded = urdf.stem in embedded_robots() and urdf.parent == urdf_dir().resolve()
    return urdf.stem if embedded else str(urdf)


def saturation_flags(u, limits: Limits, rtol: float = 1e-6) -> np.ndarray | None:
    """(K, n_u) flags: True where a drive torque is at its limit; None without a torque limit.

    Args:
        u: (K, n_u) drive torques, N·m.
        limits: the input :class:`~parallel_gpc.limits.Limits` (its torque limit, a scalar or (n_u,)).
        rtol: relative tolerance below the limit that still counts as saturated.

    Raises:
        InvalidParameterError: limits that are not a Limits. ShapeError: per-drive limits not n_u long.
    """
    if as_limits(limits).torque is None:
        return None
    u = finite_matrix("drive torques u", u, (None, None))
    return np.abs(u) >= limits.for_drives(u.shape[1]).torque * (1.0 - rtol)


def check_times(t) -> np.ndarray:
    """(K,) float times, K >= 1, strictly increasing (s).

    Raises:
        ShapeError: no samples. InvalidParameterError: times not strictly increasing.
    """
    t = finite_vector("times t", t)
    if t.size == 0:
        raise ShapeError("times t has shape (0,); expected (K,) with K >= 1 samples")
    if np.any(np.diff(t) <= 0):
        k = int(np.argmax(np.diff(t) <= 0))
        raise InvalidParameterError(
            f"times t must be strictly increasing (s); t[{k}] = {t[k]:.6g} >= t[{k + 1}] = {t[k + 1]:.6g}")
    return t


def json_default(value):
    """``default=`` of ``json.dumps`` for the package's records: numpy arrays become lists, numpy
    scalars Python numbers, anything else its ``str``."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return str(value)


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return json_default(value)


def _standard_arrays(robot, t, q, reference, planned, saturated) -> dict:
    nq = getattr(getattr(robot, "model", None), "nq", None)
    n_u = getattr(robot, "n_u", None)
    arrays = {"t": t}
    if q is not None:
        arrays["q"] = finite_matrix("configurations q", q, (t.size, nq))
    if reference is not None:
        arrays["reference"] = finite_matrix("reference", reference, (None, None))
    if planned is not None:
        arrays["planned"] = finite_matrix("planned", planned, (None, None))
    if saturated is not None:
        flags = np.asarray(saturated)
        if flags.ndim != 2 or flags.shape[0] != t.size or (n_u is not None and flags.shape[1] != n_u):
            raise ShapeError(f"saturated has shape {flags.shape}; expected ({t.size}, "
                             f"{'n_u' if n_u is None else n_u}) (samples, drives)")
        arrays["saturated"] = flags.astype(bool)
    return arrays


def save_result(path, robot, t, q=None, *, reference=None, planned=None, saturated=None,
                kind: str = "trajectory", meta: dict | None = None, arrays: dict | None = None) -> Path:
    """Write a result file (format above); parent folders are created.

    Args:
        path: output ``.npz`` file.
        robot: the robot (``ParallelRobot``, description, name or path; None: no robot).
        t: (K,) strictly increasing times, s.
        q: (K, nq) assembled configurations, or None.
        reference, planned: optional (K', n_y) platform poses (m, rad).
        saturated: optional (K, n_u) drive-at-limit flags.
        kind: what writes the file. meta: JSON-able settings. arrays: extra named arrays
            (numbers, bools or strings; no Python objects).

    Returns:
        the written path.

    Raises:
        ShapeError, InvalidParameterError: inconsistent arrays; an extra array that reuses a
            standard key or holds Python objects.
        OutputError: the file cannot be written (the path and the reason named).
    """
    t = check_times(t)
    content = _standard_arrays(robot, t, q, reference, planned, saturated)
    for key, value in (arrays or {}).items():
        value = np.asarray(value)
        if key in STANDARD_KEYS or value.dtype == object:
            raise InvalidParameterError(f"extra array {key!r} is a standard key or holds Python objects "
                                        f"(dtype {value.dtype}); standard keys are {list(STANDARD_KEYS)}")
        content[key] = value
    content.update(format=np.array(FORMAT), format_version=np.array(FORMAT_VERSION), kind=np.array(str(kind)),
                   robot=np.array(robot_reference(robot)), meta=np.array(json.dumps(_jsonable(meta or {}))))
    path = Path(path)
    with writing(path, "result file"):
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "wb") as f:
            np.savez_compressed(f, **content)
    return path


def _read(path: Path) -> dict:
    """The arrays of a result file, read within :data:`MAX_RESULT_BYTES` (checked before reading)."""
    regular_file(path, "result file", ResultFormatError)
    if not zipfile.is_zipfile(path):
        raise ResultFormatError(f"cannot read result file {str(path)!r}: not a NumPy .npz (zip) archive")
    try:
        with zipfile.ZipFile(path) as archive:
            size = sum(member.file_size for member in archive.infolist())
        if size > MAX_RESULT_BYTES:
            raise ResultFormatError(f"result file {str(path)!r} unpacks to {size} bytes; the limit is "
                                    f"{MAX_RESULT_BYTES} bytes")
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in data.files}
    except ResultFormatError:
        raise
    except Exception as exc:  # zipfile/NumPy errors differ (BadZipFile, EOFError, ValueError …): report them as ours
        raise ResultFormatError(f"cannot read result file {str(path)!r} (truncated or not written by "
                                f"parallel-gpc): {type(exc).__name__}: {exc}") from None


def _text(path: Path, arrays: dict, key: str, default: str) -> str:
    """A 0-d string entry (``format``, ``kind``, ``robot``, ``meta``)."""
    if key not in arrays:
        return default
    value = arrays[key]
    if value.ndim != 0 or value.dtype.kind not in "U":
        raise ResultFormatError(f"{str(path)!r}: key {key!r} has dtype {value.dtype} and shape {value.shape}; "
                                "expected one string")
    return str(value)


def _float_array(path: Path, arrays: dict, key: str, ndim: int, columns: int | None = None):
    """A finite float array entry of ``ndim`` dimensions (and ≥ ``columns`` columns), or None."""
    if key not in arrays:
        return None
    value = arrays[key]
    if value.dtype.kind not in "biuf" or value.ndim != ndim or (columns and value.shape[-1] < columns):
        want = "(K,)" if ndim == 1 else f"(K, n) with n ≥ {columns or 1}"
        raise ResultFormatError(f"{str(path)!r}: key {key!r} has dtype {value.dtype} and shape {value.shape}; "
                                f"expected numbers of shape {want}")
    value = value.astype(float)
    if not np.all(np.isfinite(value)):
        raise ResultFormatError(f"{str(path)!r}: key {key!r} contains NaN or inf")
    return value


def _version(path: Path, arrays: dict) -> int:
    if "format" not in arrays:  # version 0: a trajectory (t, q, robot) or a plan/reference (t, poses)
        needed = ("t", "poses") if "poses" in arrays else ("t", "q", "robot")
        missing = [k for k in needed if k not in arrays]
        if missing:
            raise ResultFormatError(
                f"result file {str(path)!r} lacks the keys {missing}; it has {sorted(arrays)} "
                f"(a {FORMAT!r} file has format and format_version; an older trajectory file "
                "t (K,), q (K, nq) and robot)")
        return 0
    name = _text(path, arrays, "format", "")
    raw = arrays.get("format_version", np.array(-1))
    version = int(raw) if raw.ndim == 0 and raw.dtype.kind in "iu" else -1
    if name != FORMAT or not 1 <= version <= FORMAT_VERSION:
        raise ResultFormatError(f"{str(path)!r} has format {name!r} version {version}; this parallel-gpc "
                                f"reads {FORMAT!r} versions 0 to {FORMAT_VERSION}")
    return version


def load_result(path) -> ResultFile:
    """Read a result file written by :func:`save_result` (or a version-0 trajectory file).

    Raises:
        ResultFormatError: missing, not a regular file, larger than MAX_RESULT_BYTES unpacked,
            unreadable, of an unknown format or version, or with missing or ill-typed keys.
    """
    path = Path(path)
    arrays = _read(path)
    version = _version(path, arrays)
    t = _float_array(path, arrays, "t", 1)
    try:
        t = check_times(t)
    except InvalidParameterError as exc:
        raise ResultFormatError(f"{str(path)!r}: {exc}") from None
    if version == 0 and "poses" in arrays and "planned" not in arrays:
        arrays["planned"] = arrays.pop("poses")  # a plan written before version 1
    q = _float_array(path, arrays, "q", 2)
    if q is not None and q.shape[0] != t.size:
        raise ResultFormatError(f"{str(path)!r}: q has shape {q.shape}; expected ({t.size}, nq), one row per time")
    saturated = arrays.get("saturated")
    if saturated is not None and (saturated.dtype.kind != "b" or saturated.ndim != 2 or saturated.shape[0] != t.size):
        raise ResultFormatError(f"{str(path)!r}: saturated has dtype {saturated.dtype} and shape {saturated.shape}; "
                                f"expected bools of shape ({t.size}, n_u)")
    meta_text = _text(path, arrays, "meta", "{}") if version >= 1 else "{}"
    try:
        meta = json.loads(meta_text)
    except (json.JSONDecodeError, RecursionError) as exc:
        raise ResultFormatError(f"{str(path)!r}: the meta key is not valid JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise ResultFormatError(f"{str(path)!r}: the meta key holds {type(meta).__name__}; expected a JSON object")
    standard = {"t", "q", "saturated", "reference", "planned", "robot", "kind", "format", "format_version"}
    standard |= {"meta"} if version >= 1 else set()
    return ResultFile(
        robot=_text(path, arrays, "robot", ""),
        t=t,
        q=q,
        reference=_float_array(path, arrays, "reference", 2, 2),
        planned=_float_array(path, arrays, "planned", 2, 2),
        saturated=saturated,
        kind=_text(path, arrays, "kind", "trajectory"),
        meta=meta,
        arrays={k: v for k, v in arrays.items() if k not in standard},
        version=version,
    )
