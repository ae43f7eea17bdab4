"""``parallel-gpc view``: show a result file in meshcat (offline HTML and/or a live viewer).

Opens every file ``track``, ``demo`` and ``plan`` write (:mod:`parallel_gpc.results`). Other
commands reuse :func:`add_view_arguments` and :func:`show_trajectory` so every run can be
exported or watched the same way. meshcat is imported only when a view is requested.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

from .vocabulary import PACKAGE_PATH

#: How to get the view when meshcat is not installed.
INSTALL_HINT = 'the meshcat view needs the meshcat package (a dependency of parallel-gpc): pip install "meshcat>=0.3.2"'


def add_view_arguments(parser, html: bool = True) -> None:
    """Add ``--html PATH`` (unless ``html`` is False: a command that names its own HTML files)
    and ``--serve`` to an argparse (sub-)parser."""
    group = parser.add_argument_group("view")
    if html:
        group.add_argument("--html", metavar="PATH",
                           help="write a self-contained HTML animation (opens offline in any browser)")
    group.add_argument("--serve", action="store_true",
                       help="show the animation in a live meshcat viewer on 127.0.0.1 until Ctrl-C")


def _viz():
    """The view modules, or None when meshcat is not installed."""
    if importlib.util.find_spec("meshcat") is None:
        return None
    from ..viz import html_export, live

    return html_export, live


def show_trajectory(args, robot, t, qs, reference=None, planned=None, saturated=None,
                    title: str | None = None) -> None:
    """Export and/or serve a trajectory as the ``--html`` / ``--serve`` arguments ask.

    Args:
        args: parsed arguments with ``html`` (path or None) and ``serve`` (bool) attributes;
            ``html_optional`` True turns a missing meshcat into a printed hint.
        robot: the :class:`~parallel_gpc.ParallelRobot` of the trajectory.
        t: (K,) times, s. qs: (K, nq) assembled configurations.
        reference, planned: optional (K', 2 or 3) platform poses drawn as lines (x, y in m).
        saturated: optional (K, n_u) flags, True while a drive is at its torque limit.
        title: page title of the HTML file (default: the robot name).

    Raises:
        ViewerError: a view was asked for explicitly and meshcat is not installed.
    """
    html, serve = getattr(args, "html", None), bool(getattr(args, "serve", False))
    if not html and not serve:
        return
    modules = _viz()
    if modules is None:
        if getattr(args, "html_optional", False) and not serve:
            print(f"no {html} written: {INSTALL_HINT}")
            return
        from ..errors import ViewerError

        raise ViewerError(f"--html/--serve need meshcat; {INSTALL_HINT}")
    html_export, live = modules
    if html:
        path = html_export.export_html(html, robot, t, qs, reference=reference, planned=planned,
                                       saturated=saturated, title=title)
        print(f"wrote {path} (self-contained HTML, open it in a browser)")
    if serve:
        live.serve_until_interrupt(robot, t, qs, reference=reference, planned=planned, saturated=saturated)


def cmd_view(args) -> int:
    """Load a result file and show it; without --html/--serve write RESULT.html next to it."""
    from ..errors import ResultFormatError
    from ..model import ParallelRobot
    from ..results import load_result

    result = load_result(args.result)
    name = args.robot or result.robot
    if not name:
        raise ResultFormatError(f"{args.result!r} names no robot (kind {result.kind!r}); give it with --robot NAME")
    if result.q is None:
        raise ResultFormatError(f"{args.result!r} (kind {result.kind!r}) has no configurations q to animate; "
                                "view shows the files of track, demo and plan")
    robot = ParallelRobot.load(name)
    if result.q.shape[1] != robot.model.nq:
        raise ResultFormatError(f"{args.result!r} holds configurations of {result.q.shape[1]} coordinates "
                                f"(robot {result.robot or 'unnamed'!r}); robot {robot.name!r} has nq = {robot.model.nq}")
    if not args.html and not args.serve:
        args.html = str(Path(args.result).with_suffix(".html"))
    show_trajectory(args, robot, result.t, result.q, reference=result.reference, planned=result.planned,
                    saturated=result.saturated, title=f"parallel-gpc: {robot.name}, {Path(args.result).stem}")
    return 0


def register_view(sub) -> None:
    """Add the ``view`` sub-command."""
    p = sub.add_parser(
        "view", parents=[PACKAGE_PATH], help="show a result file (.npz written by track, demo, plan) in meshcat",
        description="Animate a result file: write a self-contained HTML file (--html, the default "
                    "RESULT.html) and/or serve it live on 127.0.0.1 (--serve, until Ctrl-C).",
    )
    p.add_argument("result", metavar="RESULT.npz", help="result file (t, q, robot; the format: docs/validation.md)")
    p.add_argument("--robot", default=None,
                   help="robot name or path, overriding the file's (for files that name none)")
    add_view_arguments(p)
    p.set_defaults(func=cmd_view)
