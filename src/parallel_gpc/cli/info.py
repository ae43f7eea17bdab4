"""``parallel-gpc info [ROBOT]``: DOF, drives, redundancy, closures, conditioning, reach of A and B."""

from __future__ import annotations

import math

from .defaults import DEFAULT_ROBOT

#: The paper's poses A and B (m, m, rad).
POSE_A = (0.2, 0.2, math.radians(-20.0))
POSE_B = (0.8, 0.8, math.radians(20.0))


def robot_info(robot) -> list[tuple[str, str]]:
    """Rows (label, value) describing a :class:`~parallel_gpc.ParallelRobot`: DOF, drives,
    closures, conditioning, reach of the poses A and B."""
    import numpy as np

    from ..errors import ParallelGPCError
    from ..model.dynamics import ReducedModel

    q = robot.q_home
    terms = ReducedModel(robot).terms_at_q(q, np.zeros(robot.n_y))
    cond = robot.singularity(q)
    rows = [
        ("robot", robot.name),
        ("URDF", str(robot.description.urdf_path)),
        ("DOF (platform coordinates)", f"{robot.n_y} {list(robot.description.output_labels)}"),
        ("drives", f"{robot.n_u} {list(robot.description.drive_joints)}"),
        ("redundancy (drives - DOF)", str(robot.n_u - robot.n_y)),
        ("closures", f"{len(robot.description.closures)} ({robot.n_constraints} constraint rows)"),
        ("joints nq", str(robot.model.nq)),
        ("torque limit [N·m]", str(None if robot.torque_limit is None else robot.torque_limit.tolist())),
        ("home pose [m, m, rad]", str(np.round(robot.home_pose, 6).tolist())),
        ("closure residual at home [m]", f"{np.max(np.abs(robot.closure_residual(q))):.2e}"),
        ("cond(M) full / reduced", f"{np.linalg.cond(terms.M):.3g} / {np.linalg.cond(terms.M_r):.3g}"),
        ("cond(Phi_z) / cond(B_r) at home", f"{cond['cond_phi_z']:.3g} / {cond['cond_B_r']:.3g}"),
    ]
    for label, pose in (("A", np.array(POSE_A)), ("B", np.array(POSE_B))):
        try:
            qp = robot.assemble(pose)
            c = robot.singularity(qp)
            status = (f"reachable, residual {np.max(np.abs(robot.closure_residual(qp))):.1e} m, "
                      f"cond(Phi_z) {c['cond_phi_z']:.3g}, cond(B_r) {c['cond_B_r']:.3g}")
        except ParallelGPCError as exc:
            status = f"NOT reachable: {exc}"
        rows.append((f"pose {label} {np.round(pose, 4).tolist()}", status))
    return rows


def print_table(rows, out=None) -> None:
    """Print (label, value) rows aligned."""
    width = max(len(r[0]) for r in rows)
    for label, value in rows:
        print(f"  {label:<{width}}  {value}", file=out)


def cmd_info(args) -> int:
    from ..model.robot import ParallelRobot

    print_table(robot_info(ParallelRobot.load(args.robot)))
    return 0


def register_info(sub) -> None:
    """Add the ``info`` sub-command."""
    p = sub.add_parser("info", help="describe a robot: DOF, drives, redundancy, conditioning, reach of A/B")
    p.add_argument("robot", nargs="?", default=DEFAULT_ROBOT,
                   help=f"embedded robot name or path to a URDF/sidecar (default {DEFAULT_ROBOT})")
    p.set_defaults(func=cmd_info)
