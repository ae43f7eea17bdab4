"""``parallel-gpc plan``: quadratically-optimal A → B planning, modes (a), (b) and the single
open-loop solve "once" (the paper's Fig. 3/4). A thin layer over
:func:`parallel_gpc.plan_point_to_point`; writes ``plan_a.npz``, ``plan_b.npz`` and ``plan_once.npz``
(result files that ``parallel-gpc view`` opens) and the two figures.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from ..errors import InvalidParameterError
from .outputs import check_view_outputs, prepare_out_dir
from .view import add_view_arguments, show_trajectory
from .vocabulary import ROBOT, add_limit_arguments, limits_line

if TYPE_CHECKING:  # numpy is imported inside the handlers: --help stays fast
    import numpy as np

#: The paper's poses, in the units of the command line (m, m, deg).
DEFAULT_A = (0.2, 0.2, -20.0)
DEFAULT_B = (0.8, 0.8, 20.0)


def default_poses(robot) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(A, B) in m and rad: the sidecar's ``[home] A``, ``B``; for a robot without them whose
    outputs are planar [x m, y m, ψ rad] about the paper's home (0.5 m, 0.5 m, 0), the paper's
    poses; else None."""
    import numpy as np

    from ..gpc.references import is_paper_planar

    d = robot.description
    planar = is_paper_planar(robot.home_pose, robot.output_angular)
    paper = [np.array([*p[:2], math.radians(p[2])]) if planar else None for p in (DEFAULT_A, DEFAULT_B)]
    return tuple(np.array(p, dtype=float) if p is not None else fallback
                 for p, fallback in zip((d.pose_a, d.pose_b), paper))


def _pose_rad(robot, values, default, name: str) -> np.ndarray:
    """A pose from the command line (m, angles in deg) in m and rad, or ``default``."""
    import numpy as np

    if values is None:
        if default is None:
            raise InvalidParameterError(f"robot {robot.name!r} has no default pose {name} in its sidecar "
                                        f"([home] {name} = [...]); give --{name} with {robot.n_y} values")
        return default
    if len(values) != robot.n_y:
        raise InvalidParameterError(f"--{name} has {len(values)} values; robot {robot.name!r} has {robot.n_y} "
                                    f"outputs {list(robot.description.output_labels)} (m, angles in deg)")
    return np.where(robot.output_angular, np.radians(values), np.asarray(values, dtype=float))


def cmd_plan(args) -> int:
    import numpy as np

    from ..gpc import MODES, PlanSettings, Weights, plan_modes, plan_table
    from ..limits import Limits
    from ..model import ParallelRobot
    from ..plots import plot_fig3, plot_fig4, save_figure
    from ..studies import run_limits
    from ..validation import rounded

    out = prepare_out_dir(args.out)
    check_view_outputs(args)
    robot = ParallelRobot.load(args.robot)
    A, B = (_pose_rad(robot, values, default, name)
            for values, default, name in zip((args.A, args.B), default_poses(robot), "AB"))
    velocity = None if args.velocity_limit is None else (
        args.velocity_limit[0] if len(args.velocity_limit) == 1 else args.velocity_limit)
    limits = run_limits(robot, args.limits, Limits(torque=args.torque_limit), args.output_box, velocity,
                        args.hard_limits)
    limits.check_pose(A, robot.output_space.labels)
    settings = PlanSettings(Nmax=args.Nmax, Nmin=args.Nmin, Ts=args.Ts, weights=Weights(args.Qy, args.Qu),
                            limits=limits, solver=args.solver, settle_steps=args.settle)
    print(f"planning {robot.name}: A = {rounded(A, 4)} → B = {rounded(B, 4)} (m, rad); "
          f"Nmax = {settings.Nmax}, Nmin = {settings.Nmin}, k = {settings.k}, Ts = {settings.Ts * 1000:g} ms "
          f"(move {settings.duration:g} s), Qy = {settings.weights.Qy}, Qu = {settings.weights.Qu}, "
          f"torque limit = {settings.limits.to_dict()['torque']}, solver = {settings.solver}")
    print(limits_line(args, settings.limits, robot.drive_unit))
    comparison = plan_modes(robot, A, B, settings, progress=not args.no_progress)
    results = comparison.results
    for res in results:
        if res.stopped:
            print(f"  mode ({res.mode}): {res.stopped}")
    if comparison.interrupted:
        written = [res.save(out / f"plan_{res.mode}.npz") for res in results]
        print("interrupted: partial results saved: " + ", ".join(str(p) for p in written))
        return 130
    print(plan_table(results, robot.drive_unit))
    print(f"  for comparison, the dead-beat move (same criterion, minimal horizon N = k = {settings.k}) needs a "
          f"peak drive effort of {np.max(np.abs(comparison.deadbeat)):.4g} {robot.drive_unit}")
    written = [res.save(out / f"plan_{res.mode}.npz") for res in results]
    written += [save_figure(plot_fig3(results, robot=robot), out / "plan_fig3.png", dpi=120, bbox_inches="tight"),
                save_figure(plot_fig4(results), out / "plan_fig4.png")]
    print("wrote " + ", ".join(str(p) for p in written))
    print(f"view a plan: parallel-gpc view {out / 'plan_b.npz'}; use it as reference: "
          f"parallel_gpc.SampledTrajectory.load('{out / 'plan_b.npz'}')")
    plan_b = results[MODES.index("b")]
    show_trajectory(args, robot, plan_b.t, plan_b.q, planned=results[0].poses, reference=plan_b.poses,
                    title="A→B plan, mode (b) with stopping (path of mode (a) drawn too)")
    return 0


def register_plan(sub) -> None:
    """Add the ``plan`` sub-command."""
    p = sub.add_parser(
        "plan", parents=[ROBOT],
        help="quadratically-optimal A→B planning without (a) and with (b) stopping information (Fig. 3/4)",
        description="Plan a point-to-point move with the end-point criterion (20): N = Nmax, No = N − k, "
                    "Qu over the whole horizon, re-solved every step on the nonlinear plant. Mode (a) keeps "
                    "N = Nmax (no stopping information: B is approached asymptotically); mode (b) shrinks "
                    "N := Nmax, …, Nmin (21) and stops at B at Nmax·Ts; 'once' applies the first solve open "
                    "loop (valid for linear systems only).")
    p.add_argument("--A", nargs="+", type=float, default=None, metavar="Y",
                   help="start pose, one value per output: m, angles in deg (default: the sidecar's [home] A; "
                        "planar robots: 0.2 0.2 -20)")
    p.add_argument("--B", nargs="+", type=float, default=None, metavar="Y",
                   help="end pose, one value per output: m, angles in deg (default: the sidecar's [home] B; "
                        "planar robots: 0.8 0.8 20)")
    p.add_argument("--Nmax", type=int, default=120,
                   help="first horizon in samples; the move lasts Nmax·Ts (default 120)")
    p.add_argument("--Nmin", type=int, default=10, help="smallest horizon of mode (b), k < Nmin ≤ Nmax (default 10)")
    p.add_argument("--Ts", type=float, default=0.01, help="sample time in s (default 0.01)")
    p.add_argument("--Qy", type=float, default=1.0, help="square-root weight of the end-point outputs (default 1)")
    p.add_argument("--Qu", type=float, default=1e-6,
                   help="square-root input weight over the horizon (default 1e-6; larger values shorten the move)")
    p.add_argument("--torque-limit", type=float, default=None, metavar="NM",
                   help="drive limit |u| ≤ NM in N·m (N for prismatic drives), enforced by the QP back end (default: the "
                        "robot file's; --limits none: none)")
    add_limit_arguments(p)
    p.add_argument("--solver", default=None,
                   help="back end: qr (default without limits), qr-first:daqp-direct (default with limits), "
                        "osqp-direct, proxqp-direct, qpsolvers:<name>, …")
    p.add_argument("--settle", type=int, default=400,
                   help="samples recorded after Nmax in modes (a) and (b) (default 400)")
    p.add_argument("--out", default="out/plan", help="output folder for figures and trajectories (default ./out/plan)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_view_arguments(p)
    p.set_defaults(func=cmd_plan)
