"""A robot's stick figure from its joint frames: what figures and the 3-D view draw for any robot,
with or without visual geometry.

:func:`skeleton` places, at a configuration q, the origin of every joint, the bones between a
joint and its parent joint, the two frames of every loop closure (with the bone to their joint),
the output frame, the legs (joint chains ending at a closure frame outside the platform, and the
chain that carries a task-space output's platform from the base), the platform corners (closure
frames on the platform, and where that chain meets it) and the prismatic drives' rails. :func:`output_world_axes` says
which world axis each translational output moves along, so a path in output coordinates can be
drawn over the robot.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from ..validation import finite_vector

#: Characteristic length (m) of a robot whose drawn points all coincide.
DEFAULT_SIZE = 0.3
#: Half-length of a prismatic drive's rail without a finite stroke, as a fraction of the robot's size.
RAIL_HALF_LENGTH = 0.25


@dataclass(frozen=True)
class Skeleton:
    """The stick figure of a robot at one configuration (world coordinates, m).

    Attributes:
        joint_names: (n,) names of the joints (the universe excluded), in model order.
        joints: (n, 3) joint origins.
        bones: (b, 2, 3) segments: a joint's parent joint origin to its origin (joints on the
            universe: none), and a closure or output frame's joint origin to the frame.
        closures: (c, 2, 3) the two frames of each loop closure (coincide when assembled).
        closure_names: (c,) closure names.
        output: (3,) the output frame's origin (task-space outputs) or the last output joint's
            origin (joint outputs).
        legs: polylines (k_i, 3) from a leg's first joint through its joints to its closure
            frame; for a task-space output whose platform (the output frame's body, carrying two
            closure frames or more) hangs on one leg of the tree, that leg's joints up to the
            platform's joint too.
        platform: (m, 3) the platform corners: closure frames carried by the platform (the
            output joints, or the body of a task-space output frame) and the origin of the
            platform's joint when a leg carries it, ordered around their centre in the plane of
            largest spread.
        base: (p, 3) origins of the joints on the universe that are not output joints.
        rails: (r, 2, 3) the prismatic drives' rails: the positions of the drive joint's origin
            at its lower and upper stroke limit (the model file's ``<limit>``), or
            ± :data:`RAIL_HALF_LENGTH` · :attr:`size` about its position when a limit is not finite.
        rail_stroke: (r,) True where the rail is the drive's stroke from its limits.
    """

    joint_names: tuple[str, ...]
    joints: np.ndarray
    bones: np.ndarray
    closures: np.ndarray
    closure_names: tuple[str, ...]
    output: np.ndarray
    legs: list
    platform: np.ndarray
    base: np.ndarray
    rails: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))
    rail_stroke: tuple[bool, ...] = ()

    @property
    def size(self) -> float:
        """The robot's characteristic length, m: the largest extent along a world axis of its joint
        origins, closure frames and output point (the 3-D view scales every mark with it);
        :data:`DEFAULT_SIZE` when they all coincide."""
        points = np.vstack([self.joints, self.closures.reshape(-1, 3), self.output.reshape(1, 3)])
        extent = float(np.ptp(points, axis=0).max())
        return extent if extent > 0 else DEFAULT_SIZE


def _chain(model: pin.Model, joint: int) -> list[int]:
    """Joints from the universe to ``joint`` (universe excluded), root first."""
    joints = []
    while joint != 0:
        joints.append(joint)
        joint = model.parents[joint]
    return joints[::-1]


def _ordered(points: np.ndarray) -> np.ndarray:
    """Points ordered by angle about their centre in the plane of their two largest spreads."""
    if len(points) <= 2:
        return points
    centre = points.mean(axis=0)
    axes = np.argsort(np.ptp(points, axis=0))[::-1][:2]
    rel = (points - centre)[:, np.sort(axes)]
    return points[np.argsort(np.arctan2(rel[:, 1], rel[:, 0]))]


def output_joint_ids(robot) -> set[int]:
    """Model ids of the output joints (joint outputs; empty for task-space outputs)."""
    model = robot.model
    return {model.getJointId(n) for n in robot.description.output_joints} if robot.task_output is None else set()


def stick_figure(robot, q=None) -> Skeleton:
    """The stick figure of ``robot`` at configuration q (nq,) (default: home)."""
    model = robot.model
    q = robot.q_home if q is None else finite_vector("configuration q", q, model.nq)
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    origin = {j: np.array(data.oMi[j].translation) for j in range(model.njoints)}
    out_joints = output_joint_ids(robot)
    platform_joints = set().union(*(_chain(model, j) for j in out_joints)) if out_joints else set()
    carrier = []  # a task-space output's platform hung on a leg of the tree: that leg
    if not out_joints and robot.output_frame_id is not None:
        body = model.frames[robot.output_frame_id].parentJoint
        on_body = sum(body in _chain(model, model.frames[fid].parentJoint)
                      for fa, fb, _ in robot.closure_frames for fid in (fa, fb))
        if body != 0 and on_body >= 2:  # a platform closing two legs or more (a five-bar's tip link is a leg)
            platform_joints = {body}
            carrier = _chain(model, body)
    bones = [(origin[model.parents[j]], origin[j]) for j in range(1, model.njoints) if model.parents[j] != 0]
    closures, names, legs, corners = [], [], [], []
    if len(carrier) > 1:
        legs.append(np.array([origin[j] for j in carrier]))
        corners.append(origin[carrier[-1]])
    for fa, fb, closure in robot.closure_frames:
        pair = []
        for fid in (fa, fb):
            point = np.array(data.oMf[fid].translation)
            joint = model.frames[fid].parentJoint
            pair.append(point)
            if joint != 0:
                bones.append((origin[joint], point))
            chain = _chain(model, joint)
            if platform_joints.intersection(chain):
                corners.append(point)
            elif chain:
                legs.append(np.array([origin[j] for j in chain] + [point]))
        closures.append(pair)
        names.append(closure.name)
    if robot.output_frame_id is not None:
        output = np.array(data.oMf[robot.output_frame_id].translation)
        joint = model.frames[robot.output_frame_id].parentJoint
        if joint != 0:
            bones.append((origin[joint], output))
    else:
        output = origin[max(out_joints)] if out_joints else origin[0]
    base = [origin[j] for j in range(1, model.njoints) if model.parents[j] == 0 and j not in platform_joints]
    joints = np.array([origin[j] for j in range(1, model.njoints)]).reshape(-1, 3)
    closures = np.array(closures, dtype=float).reshape(-1, 2, 3)
    figure = Skeleton(
        joint_names=tuple(model.names[1:]),
        joints=joints,
        bones=np.array(bones, dtype=float).reshape(-1, 2, 3),
        closures=closures,
        closure_names=tuple(names),
        output=output,
        legs=legs,
        platform=_ordered(_distinct(np.array(corners).reshape(-1, 3))),
        base=np.array(base).reshape(-1, 3),
    )
    rails, stroke = _rails(robot, q, figure.size)
    return dataclasses.replace(figure, rails=rails, rail_stroke=stroke)


def _distinct(points: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """``points`` (n, 3) without repeats (closer than ``tol`` m to an earlier one), in order."""
    kept = []
    for p in points:
        if all(np.linalg.norm(p - k) > tol for k in kept):
            kept.append(p)
    return np.array(kept).reshape(-1, 3)


def _rails(robot, q: np.ndarray, size: float) -> tuple[np.ndarray, tuple[bool, ...]]:
    """(r, 2, 3) rails of the prismatic drives at q and (r,) whether each is the stroke from
    finite limits (see :attr:`Skeleton.rails`)."""
    model = robot.model
    data = model.createData()
    lower, upper = robot.drive_range
    rails, stroke = [], []
    for name, iq, angular, lo, hi in zip(robot.description.drive_joints, robot.drive_q_indices, robot.drive_angular,
                                         lower, upper):
        if angular:
            continue
        jid = model.getJointId(name)
        known = bool(np.isfinite(lo) and np.isfinite(hi) and lo < hi)
        if not known:  # the direction from a unit step, the length from the robot's size
            ends = []
            for step in (-1.0, 1.0):
                qs = q.copy()
                qs[iq] += step
                pin.forwardKinematics(model, data, qs)
                ends.append(np.array(data.oMi[jid].translation))
            pin.forwardKinematics(model, data, q)
            here = np.array(data.oMi[jid].translation)
            axis = (ends[1] - ends[0]) / 2.0
            rails.append([here - RAIL_HALF_LENGTH * size * axis, here + RAIL_HALF_LENGTH * size * axis])
        else:
            ends = []
            for value in (lo, hi):
                qs = q.copy()
                qs[iq] = value
                pin.forwardKinematics(model, data, qs)
                ends.append(np.array(data.oMi[jid].translation))
            rails.append(ends)
        stroke.append(known)
    return np.array(rails, dtype=float).reshape(-1, 2, 3), tuple(stroke)


def output_world_axes(robot) -> list[int | None]:
    """For each output, the world axis (0 = x, 1 = y, 2 = z) it moves along, or None (angles,
    or a joint whose axis is not along a world axis at home).

    Task-space outputs name their axis; a prismatic output joint moves along the world axis
    its origin moves along when the joint moves (at home).
    """
    if robot.task_output is not None:
        return [None if axis.startswith("r") else "xyz".index(axis) for axis in robot.description.output_axes]
    model = robot.model
    data = model.createData()
    axes = []
    for name, angle in zip(robot.description.output_joints, robot.output_angular):
        if angle:
            axes.append(None)
            continue
        jid = model.getJointId(name)
        dv = np.zeros(model.nv)
        dv[model.joints[jid].idx_v] = 1e-3
        pin.forwardKinematics(model, data, robot.q_home)
        p0 = np.array(data.oMi[jid].translation)
        pin.forwardKinematics(model, data, pin.integrate(model, robot.q_home, dv))
        d = np.array(data.oMi[jid].translation) - p0
        k = int(np.argmax(np.abs(d)))
        axes.append(k if abs(d[k]) > 0.99 * np.linalg.norm(d) > 0 else None)
    return axes
