"""Load-time checks of a closed-chain robot: the output parametrizes it, the drives actuate it.

Both are rank tests at the home configuration (SVD, singular values below ``1e-9·s_max``
count as zero), with messages that name the numbers and the offending direction. A home
configuration that passes them but is near-singular (condition number above
:data:`NEAR_SINGULAR_COND`) loads with a :class:`~parallel_gpc.errors.ParallelGPCWarning`.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..errors import ParallelGPCWarning, RobotFormatError, UnderactuatedError
from ..validation import rounded
from .description import idle_advice

#: relative singular-value cut of the load-time rank tests.
RANK_RCOND = 1e-9
#: condition number of Φ_z or B_r above which a pose counts as near-singular: the home pose
#: warns at load, :meth:`~parallel_gpc.model.robot.ParallelRobot.check_pose` refuses a pose.
NEAR_SINGULAR_COND = 1e4


def numerical_rank(s: np.ndarray) -> int:
    """Rank from singular values ``s`` (descending): those above ``RANK_RCOND``·s_max."""
    return int(np.count_nonzero(s > RANK_RCOND * s[0])) if s.size and s[0] > 0 else 0


def describe_direction(robot, dv: np.ndarray, top: int = 6) -> str:
    """Joint velocity direction ``dv`` (nv,) as ``joint: component`` pairs, largest first."""
    names = []
    for j in range(1, robot.model.njoints):
        jm = robot.model.joints[j]
        names += [robot.model.names[j] if jm.nv == 1 else f"{robot.model.names[j]}[{k}]" for k in range(jm.nv)]
    order = np.argsort(-np.abs(dv))[:top]
    return ", ".join(f"{names[i]}: {dv[i]:+.3f}" for i in order if abs(dv[i]) > 1e-3 * np.abs(dv).max())


def _labelled(robot, w: np.ndarray) -> str:
    return ", ".join(f"{lab}: {c:+.3f}" for lab, c in zip(robot.description.output_labels, w) if abs(c) > 1e-3)


def check_parametrization(robot) -> None:
    """The output y must be a local chart of the closed mechanism at home.

    With K = [Φ_q; H] (closure Jacobian stacked with the output Jacobian), the mechanism has
    DOF = nv − rank Φ_q; the output parametrizes it iff n_y = DOF and rank K = nv.

    Raises:
        RobotFormatError: naming the DOF, n_y and the joint direction that moves the mechanism
            without changing the output (or the output combination no motion can change).
    """
    q = robot.q_home
    Phi = robot.closure_kinematics(q).jacobian
    H = robot.output_jacobian(q)
    nv = robot.model.nv
    _, s, Vt = np.linalg.svd(Phi) if Phi.size else (None, np.zeros(0), np.eye(nv))
    dof = nv - numerical_rank(s)
    labels = list(robot.description.output_labels)
    head = (f"the output {labels} of {robot.name!r} does not parametrize the mechanism at home: it has "
            f"{dof} DOF (nv − rank Φ_q = {nv} − {nv - dof}) and the output has {robot.n_y} coordinates")
    _, sK, VtK = np.linalg.svd(np.vstack([Phi, H]))
    if numerical_rank(sK) < nv:
        raise UnderactuatedError(f"{head}; the joints can move along [{describe_direction(robot, VtK[-1])}] "
                                 "without changing the closures or the output: choose an output that moves along "
                                 f"this direction; {idle_advice(robot.description)}")
    if robot.n_y != dof:
        N = Vt[nv - dof:].T  # (nv, dof) free motions of the closed mechanism
        U, _, _ = np.linalg.svd(H @ N)
        raise RobotFormatError(f"{head}; no motion changes the output combination [{_labelled(robot, U[:, -1])}] "
                               f"(remove a dependent output coordinate)")


def check_actuation(robot) -> int:
    """Rank of the actuation map B_r = Tᵀ Sᵀ at home against the DOF.

    Returns:
        redundancy: n_u − rank B_r (drives beyond the DOF; 0 for a non-redundant robot).

    Raises:
        UnderactuatedError: rank B_r < n_y, naming the numbers and the uncontrolled output direction.

    Warns:
        ParallelGPCWarning: the home configuration is near-singular (:func:`warn_near_singular`).
    """
    T, _ = robot.velocity_map(robot.q_home)
    B = T.T @ robot.drive_selection
    U, s, _ = np.linalg.svd(B)
    r = numerical_rank(s)
    if r < robot.n_y:
        raise UnderactuatedError(
            f"{robot.name!r} is under-actuated: its {robot.n_u} drives {list(robot.description.drive_joints)} "
            f"span rank(B_r) = {r} of its {robot.n_y} DOF at the home pose (B_r = Tᵀ Sᵀ); no drive torque "
            f"accelerates the output along [{_labelled(robot, U[:, -1])}] (add or move a drive)"
        )
    warn_near_singular(robot, s[:robot.n_y], U[:, robot.n_y - 1])
    return robot.n_u - r


def warn_near_singular(robot, s_B: np.ndarray, weak: np.ndarray) -> None:
    """Warn when the home configuration is near a singularity: cond(B_r) or cond(Φ_z) above
    :data:`NEAR_SINGULAR_COND` (the reduced model's gains grow as 1/σ_min there).

    Args:
        robot: the robot being loaded (``q_home`` assembled).
        s_B: (n_y,) the largest n_y singular values of B_r at home, descending (N·m or N to
            output accelerations' generalized forces).
        weak: (n_y,) the output direction of B_r's smallest of them.
    """
    cond_z = robot.singularity(robot.q_home)["cond_phi_z"]
    cond_b = float(s_B[0] / s_B[-1])
    if max(cond_z, cond_b) <= NEAR_SINGULAR_COND:
        return
    drives = ", ".join(f"{name} = {value:g}" for name, value in
                       zip(robot.description.drive_joints, rounded(robot.q_home[robot.drive_q_indices], 6)))
    warnings.warn(
        f"{robot.name!r}: the home configuration (pose {rounded(robot.home_pose, 6)}; drives "
        f"{drives}) is near-singular: σ_min(B_r) = {s_B[-1]:.3g} = {1 / cond_b:.2e}·σ_max along "
        f"[{_labelled(robot, weak)}], cond(Φ_z) = {cond_z:.3g} (a condition number above "
        f"{NEAR_SINGULAR_COND:.0e} warns; poses past it are refused by check_pose); the controller's gains "
        "grow as 1/σ_min here: choose a home pose away from the singularity (sidecar [home] pose)",
        ParallelGPCWarning, stacklevel=2)
