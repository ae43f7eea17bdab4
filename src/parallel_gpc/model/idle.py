"""Idle motions of a closed chain: motions the closures allow that move neither the output nor a drive.

A rod between two ball joints can spin about its own axis, and the welded part between two
coaxial revolute joints can turn about their common axis, while the output and every drive stand
still: the closures leave these motions free, and no drive can control them. They are the null
space, at an assembled configuration q, of

    A = [Φ_q; H; S]      (closure Jacobian, output Jacobian, drive selection),  (nv columns)

(singular values below :data:`~parallel_gpc.model.checks.RANK_RCOND`·s_max count as zero).
By default (sidecar ``idle_spins = "lock"``) loading locks one joint per idle motion at its
value in q: the 1-DOF joint (neither a drive, an output nor a branch joint) with the largest
component in the idle space (the norm of its row in an orthonormal basis, which does not depend
on the basis; ties within 1e-6 go to the last joint in the model's order), then again on the
space left, until none is left. A motion that moves the output or a drive is not idle and is
never locked: it stays an under-actuation error.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .builder import joint_unit
from .checks import numerical_rank
from .description import RobotDescription

#: relative margin within which two joints' components in the idle space tie.
_TIE = 1e-6


def _null_space(A: np.ndarray) -> np.ndarray:
    """(nv, d) orthonormal basis of the null space of A (rank by :func:`~parallel_gpc.model.checks.numerical_rank`)."""
    _, s, Vt = np.linalg.svd(A)
    return Vt[numerical_rank(s):].T


def idle_locks(robot, q: np.ndarray) -> list[tuple[str, float]]:
    """The joints to lock, one per idle motion, with their values in q.

    Args:
        robot: a :class:`~parallel_gpc.model.robot.ParallelRobot` whose closures, output and
            drives are set up (its home need not be).
        q: (nq,) a configuration where the closures are assembled.

    Returns:
        [(joint name, q value in rad or m)] in the order chosen; empty when no motion is idle
        or no idle motion moves a lockable joint.
    """
    A = np.vstack([robot.closure_log_error(q).jacobian, robot.output_jacobian(q), robot.drive_selection.T])
    kept = set(robot.description.output_joints) | set(robot.description.branch_joints)
    lockable = [(name, iq, iv) for name, (iq, iv) in robot.passive_joints.items() if name not in kept]
    locks: list[tuple[str, float]] = []
    for _ in range(len(lockable)):
        N = _null_space(A)
        if N.shape[1] == 0:
            break
        weight = np.array([np.linalg.norm(N[iv]) for _, _, iv in lockable])
        if not lockable or weight.max() < 1e-6:
            break  # idle, but only through joints that cannot be locked (a multi-DOF joint, the root)
        k = int(np.flatnonzero(weight >= weight.max() * (1 - _TIE))[-1])
        name, iq, iv = lockable.pop(k)
        locks.append((name, float(q[iq])))
        row = np.zeros((1, robot.model.nv))
        row[0, iv] = 1.0
        A = np.vstack([A, row])
    return locks


def with_locks(description: RobotDescription, locks: list[tuple[str, float]]) -> RobotDescription:
    """``description`` with the ``locks`` [(joint, value)] as ``FIXED`` joints at these values."""
    names = tuple(name for name, _ in locks)
    return dataclasses.replace(
        description,
        joint_types={**description.joint_types, **{name: "FIXED" for name in names}},
        q_guess={**description.q_guess, **dict(locks)},
        locked_joints=description.locked_joints + names,
    )


def describe_locks(robot, locks: list[tuple[str, float]]) -> str:
    """The notice of locked idle motions: which joints, at which values, and how to refuse instead."""
    joints = ", ".join(f"{name!r} at {value:.6g} {joint_unit(robot.model, name)}" for name, value in locks)
    return (f"robot {robot.name!r}: {len(locks)} idle motion(s) (allowed by the closures, moving neither the "
            f"output nor a drive, e.g. a rod spinning between two ball joints) locked: {joints}; "
            "set idle_spins = \"refuse\" in the sidecar to refuse such a robot instead")
