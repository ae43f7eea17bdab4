"""``parallel-gpc info [ROBOT]``: DOF, drives, redundancy, closures, conditioning, reach of A and B."""

from __future__ import annotations

from .defaults import DEFAULT_ROBOT
from .vocabulary import PACKAGE_PATH


def _reach(robot, pose) -> str:
    import numpy as np

    qp = robot.assemble(pose)
    c = robot.singularity(qp)
    return (f"reachable, residual {np.max(np.abs(robot.closure_residual(qp))):.1e} m, "
            f"cond(Phi_z) {c['cond_phi_z']:.3g}, cond(B_r) {c['cond_B_r']:.3g}")


def _segment(robot, A, B, n: int = 21) -> str:
    """Reach and worst conditioning along the straight segment A → B in output coordinates."""
    import numpy as np

    q, worst = None, {"cond_phi_z": 0.0, "cond_B_r": 0.0}
    for s in np.linspace(0.0, 1.0, n):
        q = robot.assemble(A + s * (B - A), q)
        worst = {k: max(v, robot.singularity(q)[k]) for k, v in worst.items()}
    return f"reachable ({n} poses), max cond(Phi_z) {worst['cond_phi_z']:.3g}, max cond(B_r) {worst['cond_B_r']:.3g}"


def robot_info(robot) -> list[tuple[str, str]]:
    """Rows (label, value) describing a :class:`~parallel_gpc.ParallelRobot`: DOF, drives,
    closures, conditioning, reach of the poses A and B (the sidecar's, or the paper's for planar
    robots) and of the segment between them."""
    import numpy as np

    from ..errors import ParallelGPCError
    from ..model import ReducedModel
    from ..validation import rounded
    from .plan import default_poses

    from ..model import native_status

    q = robot.q_home
    model = ReducedModel(robot)
    terms = model.terms_at_q(q, np.zeros(robot.n_y))
    cond = robot.singularity(q)
    rows = [
        ("robot", robot.name),
        ("URDF", str(robot.description.urdf_path)),
        ("DOF (output coordinates)", f"{robot.n_y}: {robot.output_space.describe()}"),
        ("drives", f"{robot.n_u} {list(robot.description.drive_joints)}, efforts in {robot.drive_unit}"),
        ("redundancy (drives - DOF)", str(robot.n_u - robot.n_y)),
        ("closures", f"{len(robot.description.closures)} ({robot.n_constraints} constraint rows)"),
        ("joints nq", str(robot.model.nq)),
        (f"drive limit [{robot.drive_unit}]", str(None if robot.torque_limit is None else robot.torque_limit.tolist())),
        (f"home pose [{', '.join(robot.output_space.units)}]", str(rounded(robot.home_pose, 6))),
        ("closure residual at home [m]", f"{np.max(np.abs(robot.closure_residual(q))):.2e}"),
        ("cond(M) full / reduced", f"{np.linalg.cond(terms.M):.3g} / {np.linalg.cond(terms.M_r):.3g}"),
        ("cond(Phi_z) / cond(B_r) at home", f"{cond['cond_phi_z']:.3g} / {cond['cond_B_r']:.3g}"),
        ("compiled core", native_status()),
        ("model update", model.native_reason),
    ]
    d = robot.description
    if d.locked_joints:
        rows.append(("locked joints (idle motions)", ", ".join(
            f"{name} = {d.q_guess[name]:.6g}" for name in d.locked_joints)))
    if d.mesh_references:
        n = d.mesh_counts
        missing = f" ({', '.join(d.unresolved_meshes)}; see --package-path)" if d.unresolved_meshes else ""
        counted = {k: f"{v} {noun}{'s' * (v != 1)}" for (k, v), noun in
                   zip(n.items(), ("reference", "distinct file", "reference", "URI"))}
        rows.append(("meshes", f"{counted['references']} to {counted['files']}, "
                               f"{counted['missing']} missing ({counted['missing_uris']}){missing}"))
    A, B = default_poses(robot)
    checks = [(f"pose {label} {rounded(pose, 4)}", _reach, (pose,))
              for label, pose in (("A", A), ("B", B)) if pose is not None]
    if A is not None and B is not None:
        checks.append(("segment A -> B", _segment, (A, B)))
    for label, check, poses in checks:
        try:
            status = check(robot, *poses)
        except ParallelGPCError as exc:
            status = f"NOT reachable: {exc}"
        rows.append((label, status))
    return rows


def print_table(rows, out=None) -> None:
    """Print (label, value) rows aligned."""
    width = max(len(r[0]) for r in rows)
    for label, value in rows:
        print(f"  {label:<{width}}  {value}", file=out)


def cmd_info(args) -> int:
    from ..model import ParallelRobot

    print_table(robot_info(ParallelRobot.load(args.robot)))
    return 0


def register_info(sub) -> None:
    """Add the ``info`` sub-command."""
    p = sub.add_parser("info", parents=[PACKAGE_PATH],
                       help="describe a robot: DOF, drives, redundancy, conditioning, reach of A/B")
    p.add_argument("robot", nargs="?", default=DEFAULT_ROBOT,
                   help=f"embedded robot name or path to a URDF/sidecar (default {DEFAULT_ROBOT})")
    p.set_defaults(func=cmd_info)
