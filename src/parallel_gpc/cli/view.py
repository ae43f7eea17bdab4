"""``parallel-gpc view``: show a saved trajectory in meshcat (offline HTML and/or a live viewer).

Other commands (demo, track, plan) reuse :func:`add_view_arguments` and
:func:`show_trajectory` so every run can be exported or watched the same way. meshcat is
imported only when a view is requested, so the other commands start fast.
"""

from __future__ import annotations

from pathlib import Path

from ..model.robot import ParallelRobot


def add_view_arguments(parser) -> None:
    """Add ``--html PATH`` and ``--serve`` to an argparse (sub-)parser."""
    group = parser.add_argument_group("view")
    group.add_argument("--html", metavar="PATH",
                       help="write a self-contained HTML animation (opens offline in any browser)")
    group.add_argument("--serve", action="store_true",
                       help="show the animation in a live meshcat viewer on 127.0.0.1 until Ctrl-C")


def show_trajectory(args, robot: ParallelRobot, t, qs, reference=None, planned=None, saturated=None,
                    title: str | None = None) -> None:
    """Export and/or serve a trajectory as the ``--html`` / ``--serve`` arguments ask.

    Args:
        args: parsed arguments with ``html`` (path or None) and ``serve`` (bool) attributes.
        robot: the robot of the trajectory.
        t: (K,) times, s. qs: (K, nq) assembled configurations.
        reference, planned: optional (K', 2 or 3) platform poses drawn as lines (x, y in m).
        saturated: optional (K, n_u) flags, True while a drive is at its torque limit.
        title: page title of the HTML file (default: the robot name).
    """
    html, serve = getattr(args, "html", None), bool(getattr(args, "serve", False))
    if not html and not serve:
        return
    from .. import viz

    if html:
        path = viz.export_html(html, robot, t, qs, reference=reference, planned=planned,
                               saturated=saturated, title=title)
        print(f"wrote {path} (self-contained HTML, open it in a browser)")
    if serve:
        viz.serve_until_interrupt(robot, t, qs, reference=reference, planned=planned, saturated=saturated)


def cmd_view(args) -> int:
    """Load a trajectory file and show it; without --html/--serve write RESULT.html next to it."""
    from .. import viz

    trajectory = viz.load_trajectory(args.result)
    robot = ParallelRobot.load(trajectory.robot)
    if not args.html and not args.serve:
        args.html = str(Path(args.result).with_suffix(".html"))
    show_trajectory(args, robot, trajectory.t, trajectory.q, reference=trajectory.reference,
                    planned=trajectory.planned, saturated=trajectory.saturated,
                    title=f"parallel-gpc: {robot.name}, {Path(args.result).stem}")
    return 0


def register_view(sub) -> None:
    """Add the ``view`` sub-command."""
    p = sub.add_parser(
        "view", help="show a saved trajectory (.npz: t, q, robot[, reference, planned, saturated]) in meshcat",
        description="Animate a saved trajectory: write a self-contained HTML file (--html, the default "
                    "RESULT.html) and/or serve it live on 127.0.0.1 (--serve, until Ctrl-C).",
    )
    p.add_argument("result", metavar="RESULT.npz", help="trajectory file with keys t (K,), q (K, nq), robot")
    add_view_arguments(p)
    p.set_defaults(func=cmd_view)
