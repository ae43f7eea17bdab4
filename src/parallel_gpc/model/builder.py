"""Pinocchio model of a robot description: URDF open tree or closed-chain MJCF.

* URDF: ``pin.buildModelFromUrdf`` (with a free-flyer root if the sidecar says
  ``root = "free_flyer"``), then the sidecar's joint-type overrides: ``SPHERICAL`` becomes a
  ``JointModelSpherical`` at the joint's placement, ``UJOINT`` a ``JointModelUniversal`` turning
  about the URDF axis (a coordinate axis of the joint frame) then the next coordinate axis
  (x→y, y→z, z→x; Gepetto's RX·RY for axis x), ``UJOINT_AB`` (``UJOINT_XY``, ``UJOINT_ZY``, …,
  every pair of distinct axes, Gepetto's naming) a ``JointModelUniversal`` about the joint
  frame's axis A then B whatever the URDF axis (as Gepetto's loader), ``FIXED`` is locked at its ``home.q_guess`` value
  (0 by default) by ``pin.buildReducedModel``; ``REVOLUTE``/``PRISMATIC`` only assert the URDF type.
* MJCF: ``pin.buildModelAndLegacyConstraintsFromMJCF`` gives the model and one
  ``RigidConstraintModel`` per ``<equality><connect/weld>``; each becomes a :class:`Closure`
  between two frames added to the model at the constraint anchors (``<name>_a``, ``<name>_b``).
  The file is drawn at ``qpos0`` (joint ``ref`` values), which Pinocchio keeps in
  ``model.referenceConfigurations["qpos0"]``; :func:`drawn_configuration` returns it.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin

from ..errors import RobotFormatError
from .description import Closure, RobotDescription
from .sidecar import UJOINT_AXES

#: Key of the drawn configuration in ``model.referenceConfigurations`` (MJCF ``qpos0``).
DRAWN = "qpos0"

_KIND_OF_CONTACT = {pin.ContactType.CONTACT_3D: "point", pin.ContactType.CONTACT_6D: "weld"}


def build_model(description: RobotDescription) -> tuple[pin.Model, tuple[Closure, ...]]:
    """(open-tree model, all closures) of a description (the file's own loops included).

    Raises:
        RobotFormatError: the file cannot be parsed, a joint override names an unknown joint or
            does not fit it, or an MJCF file has several bodies under ``<worldbody>``.
    """
    path = str(description.urdf_path)
    root = pin.JointModelFreeFlyer() if description.root == "free_flyer" else None
    closures = description.closures
    try:
        if description.model_format == "mjcf":
            _check_single_world_body(path)
            args = (path,) if root is None else (path, root)
            model, constraints = pin.buildModelAndLegacyConstraintsFromMJCF(*args)
            closures = closures + _mjcf_closures(model, constraints)
        else:
            model = pin.buildModelFromUrdf(path) if root is None else pin.buildModelFromUrdf(path, root)
    except (ValueError, RuntimeError, IndexError) as exc:  # Pinocchio reports parse errors with its own text
        raise RobotFormatError(f"cannot build a model from {description.model_format.upper()} {path!r}: {exc}") from exc
    if description.joint_types:
        model = _override_joints(model, description)
    return model, closures


def _check_single_world_body(path: str) -> None:
    """Pinocchio 4.1's MJCF parser keeps only the first body under <worldbody>: refuse more."""
    try:
        tree = ET.parse(path)
    except ET.ParseError as exc:
        raise RobotFormatError(f"cannot parse MJCF {path!r}: {exc}") from exc
    bodies = [b.get("name", "?") for w in tree.getroot().iter("worldbody") for b in w.findall("body")]
    if len(bodies) > 1:
        raise RobotFormatError(
            f"MJCF {path!r} has {len(bodies)} bodies directly under <worldbody> {bodies}; Pinocchio's MJCF "
            f"parser keeps only the first one and silently drops the others. Wrap them in one root body "
            f"(<worldbody><body name=\"base\"> … </body></worldbody>)"
        )


def _mjcf_closures(model: pin.Model, constraints) -> tuple[Closure, ...]:
    """Closures (with frames added to ``model``) for the file's equality constraints."""
    closures = []
    for i, cm in enumerate(constraints):
        kind = _KIND_OF_CONTACT.get(cm.type)
        if kind is None:  # pragma: no cover - the legacy builder gives 3-D and 6-D contacts only
            raise RobotFormatError(f"MJCF equality constraint {i + 1} has unsupported type {cm.type}")
        name = cm.name or f"equality_{i + 1}"
        frames = []
        for side, joint, placement in (("a", cm.joint1_id, cm.joint1_placement), ("b", cm.joint2_id, cm.joint2_placement)):
            fname = f"{name}_{side}"
            if model.existFrame(fname):
                raise RobotFormatError(f"MJCF frame {fname!r} exists already; rename equality {name!r}")
            parent = model.getFrameId(model.names[joint], pin.FrameType.JOINT) if joint > 0 else 0
            model.addFrame(pin.Frame(fname, joint, parent, placement, pin.FrameType.OP_FRAME))
            frames.append(fname)
        closures.append(Closure(name, kind, (frames[0], frames[1])))
    return tuple(closures)


def joint_unit(model: pin.Model, joint: str | int) -> str:
    """Unit of a 1-DOF joint's position: ``"m"`` for a prismatic joint, ``"rad"`` for a revolute one.

    Args:
        model: the Pinocchio model.
        joint: the joint's name or id in ``model``.
    """
    jid = model.getJointId(joint) if isinstance(joint, str) else joint
    return "m" if model.joints[jid].shortname().startswith("JointModelP") else "rad"


def _joint_axis(model: pin.Model, jid: int) -> np.ndarray:
    """(3,) unit axis (joint frame) of a 1-DOF joint, from its motion subspace at q = 0."""
    jm = model.joints[jid]
    jd = jm.createData()
    q = np.zeros(jm.nq)
    q[0] = 1.0 if jm.nq == 2 else 0.0  # unbounded revolute: (cos, sin) = (1, 0)
    jm.calc(jd, q)
    S = np.asarray(jd.S).reshape(6, -1)[:, 0]
    return S[3:] if np.linalg.norm(S[3:]) > 0.5 else S[:3]


def _replacement(model: pin.Model, jid: int, kind: str, where: str):
    """The joint model replacing joint ``jid`` for override ``kind`` (None: keep it)."""
    jm = model.joints[jid]
    short = jm.shortname()
    is_revolute = jm.nv == 1 and ("JointModelR" in short)
    if kind == "SPHERICAL":
        return pin.JointModelSpherical()
    if (kind in ("REVOLUTE", "UJOINT") or kind in UJOINT_AXES) and not is_revolute:
        raise RobotFormatError(f"{where}: joint {model.names[jid]!r} is a {short} in the file, not a revolute joint")
    if kind == "PRISMATIC" and not (jm.nv == 1 and joint_unit(model, jid) == "m"):
        raise RobotFormatError(f"{where}: joint {model.names[jid]!r} is a {short} in the file, not a prismatic joint")
    if kind in UJOINT_AXES:  # Gepetto's UJOINT_AB: axes A then B of the joint frame
        first, second = ("XYZ".index(c) for c in kind[-2:])
        return pin.JointModelUniversal(np.eye(3)[first], np.eye(3)[second])
    if kind != "UJOINT":
        return None
    axis = _joint_axis(model, jid)
    k = int(np.argmax(np.abs(axis)))
    if abs(abs(axis[k]) - 1.0) > 1e-12:
        raise RobotFormatError(f"{where}: UJOINT {model.names[jid]!r} has axis {np.round(axis, 6).tolist()}; a UJOINT "
                               f"turns about a coordinate axis of its joint frame, then the next one (x→y, y→z, z→x)")
    second = np.zeros(3)
    second[(k + 1) % 3] = 1.0
    return pin.JointModelUniversal(np.sign(axis[k]) * np.eye(3)[k], second)


def _override_joints(model: pin.Model, description: RobotDescription) -> pin.Model:
    """The model with the sidecar's joint-type overrides applied."""
    where = f"sidecar {str(description.sidecar_path)!r}"
    for name in description.joint_types:
        if not model.existJointName(name):
            raise RobotFormatError(f"{where}: joint_name {name!r} is not a joint of the model; joints are "
                                   f"{list(model.names)[1:]}")
    replaced = {}
    for name, kind in description.joint_types.items():
        if kind != "FIXED":
            jm = _replacement(model, model.getJointId(name), kind, where)
            if jm is not None:
                replaced[model.getJointId(name)] = jm
    if replaced:
        model = _rebuild(model, replaced)
    fixed = [model.getJointId(n) for n, k in description.joint_types.items() if k == "FIXED"]
    if fixed:
        q_ref = pin.neutral(model)
        for jid in fixed:
            jm = model.joints[jid]
            value = description.q_guess.get(model.names[jid], 0.0)
            if jm.nq == 1:
                q_ref[jm.idx_q] = float(value)
        model = pin.buildReducedModel(model, fixed, q_ref)
    return model


def _rebuild(model: pin.Model, replaced: dict) -> pin.Model:
    """A copy of ``model`` with the joints in ``replaced`` (id → JointModel) swapped in place; its
    drawn configuration keeps the values of the joints not replaced (neutral for the others)."""
    new = pin.Model()
    new.name = model.name
    new.gravity = model.gravity
    for jid in range(1, model.njoints):
        jm = replaced.get(jid, model.joints[jid])
        new_id = new.addJoint(model.parents[jid], jm, model.jointPlacements[jid], model.names[jid])
        new.appendBodyToJoint(new_id, model.inertias[jid], pin.SE3.Identity())
    for f in list(model.frames)[1:]:  # same order: frame and joint indices are unchanged
        new.addFrame(pin.Frame(f), False)  # the inertias came with appendBodyToJoint
    if _has_drawing(model):
        old, q = model.referenceConfigurations[DRAWN], pin.neutral(new)
        for jid in range(1, model.njoints):
            if jid not in replaced:
                a, b = model.joints[jid], new.joints[jid]
                q[b.idx_q:b.idx_q + b.nq] = old[a.idx_q:a.idx_q + a.nq]
        new.referenceConfigurations[DRAWN] = q
    return new


def _has_drawing(model: pin.Model) -> bool:
    return any(entry.key() == DRAWN for entry in model.referenceConfigurations)


def drawn_configuration(model: pin.Model) -> np.ndarray:
    """(nq,) the configuration the model file is drawn at: MJCF ``qpos0`` (joint ``ref`` values,
    rad or m), else Pinocchio's neutral configuration (a URDF is drawn at q = 0)."""
    if _has_drawing(model):
        q = np.array(model.referenceConfigurations[DRAWN], dtype=float)
        if q.shape == (model.nq,):
            return q
    return pin.neutral(model)
