"""Command-line interface: a thin layer over the library (``parallel-gpc --help``).

Each sub-command is a ``register_*`` function that adds its parser and sets ``func``; the
function receives the parsed arguments and returns an exit code. Package errors end the
program with a one-line message and exit code 2 (a traceback only with ``--debug``).
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from .track import register_demo, register_track
from .view import register_view
from .plan import register_plan
from .robustness import register_robustness
from ..studies.bench import register_bench
from ..errors import ParallelGPCError
from ..model.robot import DEFAULT_ROBOT, ParallelRobot

#: The paper's poses A and B (m, m, rad).
POSE_A = np.array([0.2, 0.2, math.radians(-20.0)])
POSE_B = np.array([0.8, 0.8, math.radians(20.0)])


def robot_info(robot: ParallelRobot) -> list[tuple[str, str]]:
    """Rows (label, value) describing a robot: DOF, drives, closures, conditioning, A/B reach."""
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
    for label, pose in (("A", POSE_A), ("B", POSE_B)):
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
    robot = ParallelRobot.load(args.robot)
    print_table(robot_info(robot))
    return 0


def register_info(sub) -> None:
    p = sub.add_parser("info", help="describe a robot: DOF, drives, redundancy, conditioning, reach of A/B")
    p.add_argument("robot", nargs="?", default=DEFAULT_ROBOT,
                   help=f"embedded robot name or path to a URDF/sidecar (default {DEFAULT_ROBOT})")
    p.set_defaults(func=cmd_info)


#: Sub-command registrars, in help order.
REGISTRARS = [register_info, register_demo, register_track, register_plan, register_robustness, register_bench, register_view]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="parallel-gpc",
        description="Generalized Predictive Control of parallel robots (Pinocchio closed-chain models).",
    )
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for register in REGISTRARS:
        register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 1
    try:
        return int(args.func(args) or 0)
    except (ParallelGPCError, OSError) as exc:  # bad input or an unreadable/unwritable file
        if args.debug:
            raise
        message = " ".join(str(exc).split())  # one line, even for multi-line parser messages
        print(f"parallel-gpc: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("parallel-gpc: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
