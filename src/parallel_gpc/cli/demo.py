"""``parallel-gpc demo``: the paper's Fig. 2 (absolute vs incremental-nonlinear GPC, Qy = 1,
Qu = 0, default robot), with its animation written to ``demo.html``."""

from __future__ import annotations

from pathlib import Path

from .track import add_tracking_arguments, run_and_report, settings_from_args


def cmd_demo(args) -> int:
    settings = settings_from_args(args)
    if args.html is None:  # the demo writes its animation (if meshcat is installed)
        args.html, args.html_optional = str(Path(args.out) / "demo.html"), True
    return run_and_report(settings, ["absolute", "nonlinear"], Path(args.out), args,
                          "Fig. 2 demo (absolute vs incremental-nonlinear)")


def register_demo(sub) -> None:
    """Add the ``demo`` sub-command."""
    p = sub.add_parser("demo", help="the main job: the paper's Fig. 2 comparison on the default robot")
    p.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    add_tracking_arguments(p)
    p.set_defaults(func=cmd_demo)
