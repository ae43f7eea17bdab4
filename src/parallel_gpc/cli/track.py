"""``parallel-gpc track`` and ``parallel-gpc demo``: S-curve tracking (paper Fig. 2)."""

from __future__ import annotations

from pathlib import Path

from ..gpc.controller import FORMS
from ..studies.plots_tracking import plot_paths, plot_time_histories
from ..model.robot import DEFAULT_ROBOT, ParallelRobot
from ..studies.tracking import TrackingSettings, metrics_table, run_tracking


def add_tracking_arguments(p) -> None:
    """Options shared by ``track`` and ``demo``."""
    d = TrackingSettings()
    p.add_argument("--robot", default=DEFAULT_ROBOT, help=f"robot name or path (default {DEFAULT_ROBOT})")
    p.add_argument("--Ts", type=float, default=d.Ts, help=f"sample time in s (default {d.Ts})")
    p.add_argument("--N", type=int, default=d.N, help=f"prediction horizon (default {d.N})")
    p.add_argument("--No", type=int, default=d.No, help="insensitivity horizon (default 0)")
    p.add_argument("--Nu", type=int, default=None, help="control horizon (default N)")
    p.add_argument("--Qy", type=float, default=d.Qy, help="square-root output weight (default 1)")
    p.add_argument("--Qu", type=float, default=d.Qu, help="square-root input / increment weight (default 0)")
    p.add_argument("--solver", default=None, help="back end: qr, osqp-direct, proxqp-direct, daqp-direct, "
                   "qpsolvers:NAME, qr-first:... (default: qr, or qr-first:daqp-direct with limits)")
    p.add_argument("--torque-limit", type=float, default=None, help="drive torque limit in N·m")
    p.add_argument("--du-limit", type=float, default=None, help="torque increment limit in N·m per sample")
    p.add_argument("--mass-scale", type=float, default=1.0, help="plant mass / model mass (default 1)")
    p.add_argument("--noise", type=float, default=0.0, help="measurement noise std on [y, ẏ] (SI)")
    p.add_argument("--force", type=float, nargs=3, default=(0.0, 0.0, 0.0), metavar=("FX", "FY", "MZ"),
                   help="constant disturbance on the platform (N, N, N·m)")
    p.add_argument("--reference", choices=["s-curve", "hold"], default="s-curve")
    p.add_argument("--duration", type=float, default=None, help="run length in s (default: motion + 0.2 s)")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    try:
        from .view import add_view_arguments

        add_view_arguments(p)
    except ImportError:  # the view is optional (meshcat)
        pass


def settings_from_args(args) -> TrackingSettings:
    return TrackingSettings(
        robot=args.robot, Ts=args.Ts, N=args.N, No=args.No, Nu=args.Nu, Qy=args.Qy, Qu=args.Qu,
        solver=args.solver, torque_limit=args.torque_limit, du_limit=args.du_limit,
        mass_scale=args.mass_scale, noise_std=args.noise, platform_force=tuple(args.force),
        reference=args.reference, duration=args.duration,
    )


def run_and_report(settings: TrackingSettings, forms, out: Path, args, title: str) -> int:
    """Run, print the metrics table, write plots and results; returns the exit code."""
    robot = ParallelRobot.load(settings.robot)
    results = run_tracking(settings, forms, progress=not args.no_progress, robot=robot)
    print(f"{title}: robot {robot.name}, Ts = {1e3 * settings.Ts:g} ms, N = {settings.N}, No = {settings.No}, "
          f"Nu = {settings.Nu or settings.N}, Qy = {settings.Qy:g}, Qu = {settings.Qu:g}, "
          f"mass scale {settings.mass_scale:g}")
    print(metrics_table(results))
    out.mkdir(parents=True, exist_ok=True)
    for form, res in results.items():
        res.save(out / f"track_{form}.npz")
    paths = [plot_paths(results, out / "track_path.png", f"{title}: platform path"),
             plot_time_histories(results, out / "track_time.png", f"{title}: error, velocity, torque")]
    print("wrote " + ", ".join(str(p) for p in paths) + f" and track_<form>.npz in {out}")
    if hasattr(args, "html") or hasattr(args, "serve"):
        from .view import show_trajectory
        from ..viz import saturation_flags

        last = results[list(results)[-1]]
        flags = (None if settings.torque_limit is None
                 else saturation_flags(last.u, settings.torque_limit, rtol=1e-5))
        show_trajectory(args, robot, last.t, last.q, reference=last.reference, saturated=flags)
    interrupted = any(r.interrupted for r in results.values())
    if interrupted:
        print("interrupted: partial results saved")
        return 130
    return 0


def cmd_track(args) -> int:
    forms = list(FORMS) if args.form == "all" else [args.form]
    return run_and_report(settings_from_args(args), forms, Path(args.out), args, "S-curve tracking")


def cmd_demo(args) -> int:
    """The paper's Fig. 2: absolute vs incremental-nonlinear GPC, Qy = 1, Qu = 0, default robot."""
    settings = settings_from_args(args)
    if getattr(args, "html", "unset") is None:
        args.html = str(Path(args.out) / "demo.html")  # the demo always writes its animation
    return run_and_report(settings, ["absolute", "nonlinear"], Path(args.out), args,
                          "Fig. 2 demo (absolute vs incremental-nonlinear)")


def register_track(sub) -> None:
    p = sub.add_parser("track", help="track the S-curve (or a hold pose) with GPC on the nonlinear plant")
    p.add_argument("--form", choices=[*FORMS, "all"], default="all", help="GPC form (default all)")
    p.add_argument("--out", default="out/track", help="output folder (default out/track)")
    add_tracking_arguments(p)
    p.set_defaults(func=cmd_track)


def register_demo(sub) -> None:
    p = sub.add_parser("demo", help="the main job: the paper's Fig. 2 comparison on the default robot")
    p.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    add_tracking_arguments(p)
    p.set_defaults(func=cmd_demo)

