"""Validation of robot files at load: bounded reads, sidecar value types, URDF/MJCF physics, and
the consistency of a description (duplicates, identical closure frames).

Policies (docs/validation.md states them too):

* A robot file (URDF, MJCF or sidecar) must be a regular file (not a device, FIFO or folder) of at
  most :data:`URDF_MAX_BYTES` / :data:`SIDECAR_MAX_BYTES`, UTF-8 encoded. The size is checked
  before reading and the read itself is bounded.
* Every ``<inertial>`` of the URDF (and of the MJCF): mass finite and >= 0 (kg; 0 is a massless
  frame); inertia entries finite; the rotational inertia matrix (kg·m², about the centre of mass)
  symmetric positive semi-definite (all zero: a point mass) with principal moments satisfying the
  triangle inequality I₁ + I₂ ≥ I₃ (relative tolerance :data:`INERTIA_RTOL`). The built model's
  bodies are checked again (the parsers silently drop or zero some bad values).
* The URDF's joints form one tree: every joint joins two declared, different links, no link is
  the child of two joints, and exactly one link (the root) is no joint's child. (Pinocchio's
  parser crashes or silently builds a wrong model otherwise.)
* Meshes are never needed for the dynamics: each mesh URI is resolved among the allowed roots
  (:mod:`.meshes`) or recorded as unresolved; none is refused and none is read here.
* Drives, output joints and branch joints are distinct; a closure joins two different frames
  and no two closures join the same pair.

Nothing here imports Pinocchio (:func:`check_model_inertias` reads a built model).
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..errors import RobotFormatError
from ..validation import regular_file
from .meshes import resolve_meshes

#: Largest closure sidecar read, bytes.
SIDECAR_MAX_BYTES = 1 << 20
#: Largest model file (URDF, MJCF) read, bytes.
URDF_MAX_BYTES = 16 << 20
#: Relative tolerance of the inertia checks (positive definiteness, triangle inequality).
INERTIA_RTOL = 1e-9


# ---------------------------------------------------------------------------- bounded reads
def read_bounded(path, limit: int, what: str, error=RobotFormatError) -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes (size checked before reading).

    Args:
        path: the file. limit: bytes. what: its role, for the message. error: the package error
            class to raise (a robot file's by default; the sweep spec gives InvalidParameterError).

    Raises:
        error: missing, not a regular file (folder, device, FIFO), or too large.
    """
    path = Path(path)
    size = regular_file(path, what, error)
    if size > limit:
        raise error(f"{what} {str(path)!r} has {size} bytes; the limit is {limit} bytes")
    with open(path, "rb") as f:
        data = f.read(limit + 1)
    if len(data) > limit:  # grew while we looked
        raise error(f"{what} {str(path)!r} has more than {limit} bytes; the limit is {limit} bytes")
    return data


def read_text_bounded(path, limit: int, what: str, error=RobotFormatError) -> str:
    """:func:`read_bounded`, decoded as UTF-8 (an error names the first bad byte's offset)."""
    data = read_bounded(path, limit, what, error)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{what} {str(path)!r} is not UTF-8 text: byte {data[exc.start]:#04x} at offset "
                    f"{exc.start}") from None


def check_robot_argument(name_or_path) -> None:
    """A robot name or path is a non-empty str or os.PathLike naming no folder.

    Raises:
        RobotFormatError: wrong type, empty, or a folder.
    """
    if isinstance(name_or_path, bool) or not isinstance(name_or_path, (str, os.PathLike)):
        raise RobotFormatError(f"robot = {name_or_path!r} ({type(name_or_path).__name__}) must be an embedded "
                               "robot name or a path (str or os.PathLike) to a .urdf file or its sidecar")
    if not str(name_or_path).strip():
        raise RobotFormatError("robot name is empty; give an embedded robot name or a path to a .urdf file")
    if Path(name_or_path).is_dir():
        raise RobotFormatError(f"robot path {str(name_or_path)!r} is a folder; give the .urdf file or its sidecar")


# ---------------------------------------------------------------------------- sidecar value types
def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _fail(where: str, key: str, value, want: str):
    text = repr(value)
    text = text if len(text) <= 80 else text[:77] + "..."
    raise RobotFormatError(f"sidecar {where}: {key} = {text} must be {want}")


def _text(where, key, value):
    if not isinstance(value, str):
        _fail(where, key, value, "a string")


def _names(where, key, value, length=None, empty=False):
    if not isinstance(value, list) or not (value or empty) or not all(isinstance(v, str) and v for v in value):
        _fail(where, key, value, "a list of names (strings)" if empty else "a non-empty list of names (strings)")
    if length is not None and len(value) != length:
        _fail(where, key, value, f"a list of {length} names")


def _numbers(where, key, value, allow_scalar=False):
    if allow_scalar and _is_number(value):
        return
    if not isinstance(value, list) or not value or not all(_is_number(v) for v in value):
        _fail(where, key, value, "a non-empty list of finite numbers" + (" (or one number)" if allow_scalar else ""))


def _table(where, key, value):
    if not isinstance(value, dict):
        _fail(where, key, value, "a table (mapping)")


def _number_table(where, key, value):
    _table(where, key, value)
    for k, v in value.items():
        if not isinstance(k, str) or not (_is_number(v) or (isinstance(v, list) and v and all(map(_is_number, v)))):
            _fail(where, f"{key}.{k}", v, "a finite number, or a list of numbers for a multi-DOF joint")


#: Known keys of each table and the check of their values (unknown keys are left to the parser).
_OUTPUT = {"frame": _text, "joints": _names, "labels": _names, "units": _names, "kind": _text, "axes": _names}
_HOME = {"pose": _numbers, "branch_joints": lambda w, k, v: _names(w, k, v, empty=True), "q_guess": _number_table, "A": _numbers, "B": _numbers}
_DRIVES = {"joints": _names, "torque_limit": lambda w, k, v: _numbers(w, k, v, allow_scalar=True)}
_CLOSURE = {"name": _text, "kind": _text, "frames": lambda w, k, v: _names(w, k, v, 2)}


def _check_table(where: str, prefix: str, table: dict, spec: dict) -> None:
    for key, check in spec.items():
        if key in table:
            check(where, f"{prefix}{key}", table[key])


def _check_nested(where: str, data: dict, key: str, spec: dict) -> None:
    if key in data and data[key] is not None:
        _table(where, key, data[key])
        _check_table(where, f"{key}.", data[key], spec)


def check_sidecar_types(data: dict, where: str) -> None:
    """Check the type of every known sidecar value (native and Gepetto-style), before parsing.

    Raises:
        RobotFormatError: naming the key, its value and the expected type.
    """
    for key in ("name", "description", "output_frame", "root", "idle_spins"):
        if key in data:
            _text(where, key, data[key])
    _check_nested(where, data, "output", _OUTPUT)
    _check_nested(where, data, "home", _HOME)
    _check_nested(where, data, "drives", _DRIVES)
    if "closures" in data:
        closures = data["closures"]
        if not isinstance(closures, list) or not closures:
            _fail(where, "closures", closures, "a non-empty list of tables [[closures]]")
        for i, c in enumerate(closures):
            _table(where, f"closures[{i}]", c)
            _check_table(where, f"closures[{i}].", c, _CLOSURE)
    if "closed_loop" in data:
        pairs = data["closed_loop"]
        if not isinstance(pairs, list) or not pairs:
            _fail(where, "closed_loop", pairs, "a non-empty list of [frame_a, frame_b] pairs")
        for i, pair in enumerate(pairs):
            _names(where, f"closed_loop[{i}]", pair, 2)
        if "type" in data:
            _names(where, "type", data["type"], len(pairs))
    optional_names = lambda w, k, v: _names(w, k, v, empty=True)  # noqa: E731
    for key, check in (("name_mot", _names), ("output_joints", _names), ("joint_name", optional_names),
                       ("joint_type", optional_names),
                       ("torque_limit", lambda w, k, v: _numbers(w, k, v, allow_scalar=True))):
        if key in data and data[key] is not None:
            check(where, key, data[key])


# ---------------------------------------------------------------------------- description consistency
def _duplicates(names) -> list[str]:
    seen, dup = set(), []
    for n in names:
        if n in seen and n not in dup:
            dup.append(n)
        seen.add(n)
    return dup


def check_description(desc) -> None:
    """Distinct drives, output joints and branch joints; closures between two different frames,
    each pair once.

    Raises:
        RobotFormatError: naming the repeated joint or frame.
    """
    where = repr(desc.name)
    for role, names in (("drive joints", desc.drive_joints), ("output joints", desc.output_joints),
                        ("branch joints", desc.branch_joints)):
        dup = _duplicates(names)
        if dup:
            raise RobotFormatError(f"robot {where}: {role} {list(names)} name {dup} more than once; each joint "
                                   "may appear once")
    pairs = {}
    for c in desc.closures:
        if c.frames[0] == c.frames[1]:
            raise RobotFormatError(f"robot {where}: closure {c.name!r} joins frame {c.frames[0]!r} to itself "
                                   "(identical closure frames); a closure joins two different frames")
        key = frozenset(c.frames)
        if key in pairs:
            raise RobotFormatError(f"robot {where}: closures {pairs[key]!r} and {c.name!r} both join frames "
                                   f"{sorted(key)}; each pair of frames may be closed once")
        pairs[key] = c.name


# ---------------------------------------------------------------------------- URDF physics
def _attr_float(elem, name: str, link: str, path: Path) -> float:
    raw = elem.get(name, "0")
    try:
        value = float(raw)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise RobotFormatError(f"URDF {str(path)!r}: link {link!r} {elem.tag} {name} = {raw!r} must be a finite "
                               "number")
    return value


def _check_inertial(inertial, link: str, path: Path) -> None:
    mass_el, inertia_el = inertial.find("mass"), inertial.find("inertia")
    if mass_el is None or inertia_el is None:
        raise RobotFormatError(f"URDF {str(path)!r}: link {link!r} has an <inertial> without <mass> or <inertia>")
    mass = _attr_float(mass_el, "value", link, path)
    if not mass >= 0:
        raise RobotFormatError(f"URDF {str(path)!r}: link {link!r} mass = {mass!r} kg must be >= 0 (0: a massless "
                               "frame)")
    v = {k: _attr_float(inertia_el, k, link, path) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
    inertia = np.array([[v["ixx"], v["ixy"], v["ixz"]], [v["ixy"], v["iyy"], v["iyz"]],
                        [v["ixz"], v["iyz"], v["izz"]]])
    _check_rotational(inertia, f"link {link!r}", v, path)


def _check_rotational(inertia: np.ndarray, who: str, shown, path: Path) -> None:
    """A (3, 3) rotational inertia (kg·m²): symmetric positive semi-definite (zero: a point mass),
    triangle inequality."""
    moments = np.linalg.eigvalsh(0.5 * (inertia + inertia.T))
    scale = float(np.abs(inertia).max())
    if moments[0] < -INERTIA_RTOL * scale or np.abs(inertia - inertia.T).max() > INERTIA_RTOL * scale:
        raise RobotFormatError(f"{str(path)!r}: {who} inertia {shown} (kg·m²) is not symmetric positive "
                               f"semi-definite (principal moments {np.round(moments, 12).tolist()})")
    if moments[0] + moments[1] < moments[2] * (1.0 - INERTIA_RTOL):
        raise RobotFormatError(f"{str(path)!r}: {who} inertia {shown} (kg·m²) violates the triangle "
                               f"inequality I1 + I2 >= I3 of a physical body (principal moments "
                               f"{np.round(moments, 12).tolist()})")


def check_urdf_text(text: str, path) -> None:
    """Check a URDF's XML, tree, masses and inertias (policy in the module docstring).

    Returns:
        The parsed XML root element (``<robot>``).

    Raises:
        RobotFormatError: naming the link or joint and the bad value.
    """
    path = Path(path)
    root = _xml_root(text, path, "robot")
    for link in root.iter("link"):
        name = link.get("name", "?")
        for inertial in link.findall("inertial"):
            _check_inertial(inertial, name, path)
    _check_urdf_tree(root, path)
    return root


def _check_urdf_tree(root, path: Path) -> None:
    """The joints of a URDF form one tree over its links (policy in the module docstring)."""
    links = [link.get("name") for link in root.findall("link")]
    dup = _duplicates(links)
    if dup:
        raise RobotFormatError(f"URDF {str(path)!r}: link names {dup} are declared more than once")
    parent_of, known = {}, set(links)
    for joint in root.findall("joint"):
        name = joint.get("name", "?")
        ends = {}
        for end in ("parent", "child"):
            el = joint.find(end)
            ends[end] = None if el is None else el.get("link")
            if ends[end] not in known:
                raise RobotFormatError(f"URDF {str(path)!r}: joint {name!r} {end} link = {ends[end]!r} is not a "
                                       f"declared <link>")
        parent, child = ends["parent"], ends["child"]
        if parent == child:
            raise RobotFormatError(f"URDF {str(path)!r}: joint {name!r} joins link {child!r} to itself")
        if child in parent_of:
            raise RobotFormatError(
                f"URDF {str(path)!r}: link {child!r} is the child of two joints ({parent_of[child][1]!r} from "
                f"{parent_of[child][0]!r} and {name!r} from {parent!r}): a URDF is a tree; declare the extra "
                "joint as a loop closure in the sidecar instead")
        parent_of[child] = (parent, name)
    roots = [link for link in links if link not in parent_of]
    if len(roots) != 1:
        cycle = _cycle(parent_of) if not roots else None
        what = (f"its joints form a kinematic cycle through links {cycle}" if cycle
                else f"it has {len(roots)} root links {roots[:10]} (links that are no joint's child)")
        raise RobotFormatError(f"URDF {str(path)!r}: {what}; a URDF is one tree with one root link (close "
                               "loops in the sidecar)")
    cycle = _cycle(parent_of)
    if cycle:  # unreachable with one root and one parent per link, kept as a guard
        raise RobotFormatError(f"URDF {str(path)!r}: its joints form a kinematic cycle through links {cycle}")


def _cycle(parent_of: dict) -> list[str] | None:
    """Links of a parent cycle (each link's parent link in ``parent_of``), or None."""
    done = set()
    for start in parent_of:
        seen, link = [], start
        while link in parent_of and link not in done and link not in seen:
            seen.append(link)
            link = parent_of[link][0]
        if link in seen:
            return seen[seen.index(link):]
        done.update(seen)
    return None


def _xml_root(text: str, path: Path, tag: str):
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise RobotFormatError(f"{path.suffix[1:].upper()} {str(path)!r} is not well-formed XML: {exc}") from None
    if root.tag != tag:
        raise RobotFormatError(f"{str(path)!r}: the root element is <{root.tag}>, not <{tag}>")
    return root


def check_model_file(description):
    """Bounded read and checks of a description's model file before Pinocchio parses it (URDF:
    :func:`check_urdf_text`; MJCF: the inertials), and where its meshes are.

    Returns:
        (resolved, unresolved, references): the meshes that resolve among the model file's folder
        and the description's ``package_path`` (dict URI → file), the URIs that do not, and every
        mesh reference's URI in file order (:func:`~parallel_gpc.model.meshes.resolve_meshes`;
        no mesh is read).

    Raises:
        RobotFormatError: not a regular file, larger than :data:`URDF_MAX_BYTES`, not UTF-8,
            or failing a check.
    """
    path = Path(description.urdf_path)
    text = read_text_bounded(path, URDF_MAX_BYTES, "model file")
    if description.model_format == "urdf":
        root = check_urdf_text(text, path)
    else:
        root = _xml_root(text, path, "mujoco")
        for body in root.iter("body"):
            for inertial in body.findall("inertial"):
                _check_mjcf_inertial(inertial, body.get("name", "?"), path)
    return resolve_meshes(root, description.model_format, path, description.package_path)


def _check_mjcf_inertial(inertial, body: str, path: Path) -> None:
    """An MJCF ``<inertial mass= diaginertia=|fullinertia=>``: the same policy as the URDF's."""
    values = {}
    for key in ("mass", "diaginertia", "fullinertia"):
        raw = inertial.get(key)
        if raw is None:
            continue
        try:
            values[key] = [float(x) for x in raw.split()]
        except ValueError:
            values[key] = [math.nan]
        want = {"mass": 1, "diaginertia": 3, "fullinertia": 6}[key]
        if len(values[key]) != want or not all(map(math.isfinite, values[key])):
            raise RobotFormatError(f"{str(path)!r}: body {body!r} inertial {key} = {raw!r} must be {want} finite "
                                   "number(s)")
    mass = values.get("mass", [math.nan])[0]
    if not mass >= 0:
        raise RobotFormatError(f"{str(path)!r}: body {body!r} inertial mass = {inertial.get('mass')!r} kg must be "
                               ">= 0 (0: a massless body)")
    if "fullinertia" in values:
        ixx, iyy, izz, ixy, ixz, iyz = values["fullinertia"]
        rot = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    elif "diaginertia" in values:
        rot = np.diag(values["diaginertia"])
    else:
        return
    _check_rotational(rot, f"body {body!r}", rot.tolist(), path)


def check_model_inertias(model, path) -> None:
    """Every body of a built model: mass finite and ≥ 0 (0: massless), and with mass > 0 a
    rotational inertia that is a valid inertia (positive semi-definite, triangle inequality).

    Raises:
        RobotFormatError: naming the body (joint) and its values.
    """
    for j in range(1, model.njoints):
        inertia = model.inertias[j]
        mass, rot = float(inertia.mass), np.array(inertia.inertia)
        if not (math.isfinite(mass) and mass >= 0 and np.all(np.isfinite(rot))):
            raise RobotFormatError(f"{str(path)!r}: body of joint {model.names[j]!r} has mass {mass!r} kg and "
                                   f"inertia {rot.tolist()}; both must be finite, the mass >= 0")
        if mass > 0:
            _check_rotational(rot, f"body of joint {model.names[j]!r}", rot.tolist(), Path(path))
