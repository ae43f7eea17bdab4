"""``parallel-gpc track``: tracking of a reference (a built-in path in the robot's outputs, a hold
or a CSV file) with each GPC form on the nonlinear plant.

Writes ``track_<form>.npz`` (result files that ``parallel-gpc view`` opens), ``track_path.png``
and ``track_time.png``. A form whose closed loop diverges keeps its samples up to there (its
file's ``meta["stopped"]`` says where and why), the other forms run; the command then prints the
divergence and exits with :data:`~parallel_gpc.cli.defaults.EXIT_DIVERGED` (3). ``demo`` (:mod:`~parallel_gpc.cli.demo`) shares the options, with the
comparison's defaults.
"""

from __future__ import annotations

import cmath
import math
import sys
from pathlib import Path

from .defaults import EXIT_DIVERGED, EXIT_INTERRUPTED, TOLERANCE, TRACKING
from .outputs import check_view_outputs, prepare_out_dir
from .view import add_view_arguments
from .vocabulary import (ROBOT, add_forms_argument, add_limit_arguments, add_reference_argument, limits_line,
                         selected_forms)


def add_tracking_arguments(p, d: dict | None = None, html: bool = True) -> None:
    """Options shared by ``track`` and ``demo`` (beside the :data:`~.vocabulary.ROBOT` parent's); defaults
    from ``d`` (default :data:`defaults.TRACKING`)."""
    d = TRACKING if d is None else d
    p.add_argument("--Ts", type=float, default=d["Ts"], help=f"sample time in s (default {d['Ts']})")
    p.add_argument("--N", type=int, default=d["N"], help=f"prediction horizon (default {d['N']})")
    p.add_argument("--No", type=int, default=d["No"], help=f"insensitivity horizon (default {d['No']})")
    p.add_argument("--Nu", type=int, default=None, help="control horizon (default N)")
    p.add_argument("--Qy", type=float, default=d["Qy"], help=f"square-root output weight (default {d['Qy']:g})")
    p.add_argument("--Qu", type=float, default=d["Qu"],
                   help=f"square-root input / increment weight (default {d['Qu']:g})")
    p.add_argument("--Qf", type=float, default=1.0,
                   help="terminal factor on the last predicted error's weight (default 1: the paper's criterion)")
    p.add_argument("--terminal", choices=["pose", "stop"], default=None,
                   help="terminal equality: the last predicted pose on the reference (pose), and at rest (stop); "
                        "hard rows, solved by a QP back end (default none)")
    p.add_argument("--solver", default=None,
                   help="back end: qr (the paper's square-root reference), riccati (Qu > 0, stage-wise, no "
                   "condensing: the Riccati recursion, with torque/du limits an active set, with output limits an "
                   "interior point), osqp-direct, proxqp-direct, daqp-direct, qpsolvers:NAME, qr-first:... (default: "
                   "riccati where it gives QR's minimizer — Qu ≥ 0.01·Qy·Ts², no terminal equality or weight, no "
                   "limits, or torque/du limits at N ≥ 10 —, otherwise qr (Qu = 0: "
                   "minimum-norm), with limits qr-first:bvls for the absolute form, qr-first:daqp-direct for the "
                   "incremental forms; the table prints the one used)")
    p.add_argument("--iterations", type=int, default=d["iterations"], metavar="K",
                   help="Gauss–Newton iterations per step of the nonlinear form: 1 = the paper's single step, "
                        "more = iterated toward the nonlinear MPC optimum, stopping at --tolerance (the other forms take "
                        f"their single step; the solvers line reports the iterations used) (default {d['iterations']})")
    p.add_argument("--tolerance", type=float, default=None,
                   help=f"the iterations stop when the Gauss–Newton step ‖Δv‖∞ ≤ tolerance·(1 + ‖v‖∞) (default {TOLERANCE:g})")
    p.add_argument("--time-budget", type=float, default=None, metavar="SECONDS",
                   help="real-time mode: no Gauss–Newton iteration that would end past this many s of the control "
                        "step (the solvers line counts the steps it stopped) (default none)")
    p.add_argument("--torque-limit", type=float, default=None,
                   help="drive limit in N·m (N for prismatic drives); default: the robot file's (--limits none: none)")
    p.add_argument("--du-limit", type=float, default=None,
                   help="drive increment limit in N·m (N) per sample (incremental forms only)")
    add_limit_arguments(p)
    p.add_argument("--disturbance-gain", type=float, default=d["disturbance_gain"], metavar="ALPHA",
                   help="gain α ∈ [0, 1] of the state-disturbance estimate, the same for every form; 0 = off "
                        + ("(default: each form's own, 0 absolute, 0.5 incremental)" if d["disturbance_gain"] is None
                           else f"(default {d['disturbance_gain']:g})"))
    p.add_argument("--mass-scale", type=float, default=d["mass_scale"],
                   help=f"plant mass / model mass (default {d['mass_scale']:g})")
    p.add_argument("--noise", type=float, default=0.0, help="measurement noise std on [y, ẏ] (SI)")
    p.add_argument("--force", type=float, nargs="+", default=d["platform_force"], metavar="F",
                   help="constant disturbance on the platform, one value per coordinate (N, N·m), e.g. FX FY MZ "
                        f"(default {' '.join(f'{v:g}' for v in d['platform_force'])})")
    add_reference_argument(p, "a step to a pose near home, held")
    p.add_argument("--duration", type=float, default=d["duration"], help="run length in s (default: "
                   + ("motion + 0.2 s)" if d["duration"] is None else f"{d['duration']:g} s)"))
    p.add_argument("--sensors", default="full", metavar="full|encoders[:COUNTS_PER_REV][,m=COUNTS_PER_M]",
                   help="what the controller sees: the full state, or quantized drive encoders through a Kalman "
                        "filter: counts per revolution of revolute drives, m= counts per metre of prismatic ones (defaults "
                        "2^20 and 1e7; e.g. encoders:2^16, encoders:m=1e5) (default full)")
    p.add_argument("--plant", choices=["own", "mujoco"], default="own",
                   help="the simulated machine: our constrained plant, or the robot exported to MuJoCo "
                        "(pip install 'parallel-gpc[mujoco]') (default own)")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    add_view_arguments(p, html=html)


def settings_from_args(args):
    """The :class:`~parallel_gpc.TrackingSettings` of the parsed arguments, with the state limits
    of ``--limits`` and the explicit ones."""
    from ..errors import InvalidParameterError
    from ..model import ParallelRobot
    from ..studies import TrackingSettings

    if args.iterations == 1 and (args.tolerance is not None or args.time_budget is not None):
        given = "--tolerance" if args.tolerance is not None else "--time-budget"
        raise InvalidParameterError(f"{given} stops the nonlinear form's Gauss–Newton iterations; with --iterations 1 "
                                    "(the default: the paper's single step) there are none: give --iterations K > 1")
    settings = TrackingSettings.from_flat(
        robot=args.robot, Ts=args.Ts, N=args.N, No=args.No, Nu=args.Nu, Qy=args.Qy, Qu=args.Qu, Qf=args.Qf,
        terminal=args.terminal, solver=args.solver, torque_limit=args.torque_limit, du_limit=args.du_limit,
        disturbance_gain=args.disturbance_gain,
        mass_scale=args.mass_scale, noise_std=args.noise, platform_force=tuple(args.force),
        reference=args.reference, duration=args.duration, sensors=args.sensors, plant=args.plant,
        iterations=args.iterations, tolerance=args.tolerance, time_budget=args.time_budget,
    )
    velocity = None if args.velocity_limit is None else (
        args.velocity_limit[0] if len(args.velocity_limit) == 1 else args.velocity_limit)
    return settings.with_run_limits(ParallelRobot.load(settings.robot), args.limits, args.output_box, velocity,
                                    args.hard_limits)


def run_and_report(settings, forms, out: Path, args, title: str) -> int:
    """Run, print the metrics table, write plots and result files; returns the exit code."""
    from ..model import ParallelRobot
    from ..results import saturation_flags
    from ..plots import save_figure, plot_paths, plot_time_histories
    from ..studies import metrics_table, run_tracking
    from .view import show_trajectory

    out = prepare_out_dir(out)
    check_view_outputs(args)
    robot = ParallelRobot.load(settings.robot)
    results = run_tracking(settings, forms, progress=not args.no_progress, robot=robot, poles=True)
    H, W = settings.horizons, settings.weights
    print(f"{title}: robot {robot.name}, Ts = {1e3 * settings.Ts:g} ms, N = {H.N}, No = {H.No}, "
          f"Nu = {H.Nu}, Qy = {W.Qy:g}, Qu = {W.Qu:g}, "
          f"sensors {settings.sensors}, plant {settings.plant}, mass scale {settings.mass_scale:g}, load {list(settings.platform_force) if any(settings.platform_force) else 'none'}, "
          "disturbance estimate α = " + ("each form's default (est. α column)" if settings.disturbance_gain is None
                                         else f"{settings.disturbance_gain:g} (every form)"))
    print(limits_line(args, settings.limits, robot.drive_unit))
    print(metrics_table(results, robot.drive_unit))
    for form, res in results.items():
        print(f"solvers, {form}: {res.solver_summary()}")
        res.save(out / f"track_{form}.npz")
    note = undamped_note({form: res.meta.get("closed_loop_pole") for form, res in results.items()}, settings.Ts,
                         settings.horizons.N)
    if note:
        print(note)
    paths = [save_figure(plot_paths(results, f"{title}: path"), out / "track_path.png"),
             save_figure(plot_time_histories(results, f"{title}: error, velocity, drive effort"),
                         out / "track_time.png")]
    print("wrote " + ", ".join(str(p) for p in paths) + f" and track_<form>.npz in {out}")
    last = results[list(results)[-1]]
    flags = saturation_flags(last.u, settings.limits, rtol=1e-5)
    show_trajectory(args, robot, last.t, last.q, reference=last.reference, saturated=flags)
    return outcome_code(results.values())


def undamped_note(poles: dict, Ts: float, N: int) -> str:
    """One line naming the forms whose unconstrained loop's dominant pole ([Re, Im], or None) is not
    inside the unit circle (:mod:`~parallel_gpc.gpc.stability`), else "". Its reading follows the largest
    pole: on the negative real side, the dead-beat law's z = −1 (Qu = 0), which a small Qu > 0 damps; else
    a slow mode the horizon N·Ts does not stabilize (a larger Qu does not help there: the Gepetto 5-bar, joint
    outputs, N = 20 at 2 ms, |z| = 1.008 at Qu = 1e-3, 1.012 at 1e-2, inside at N = 40)."""
    from ..gpc.stability import STABLE_MARGIN

    flagged = {form: complex(*pole) for form, pole in poles.items()
               if pole is not None and abs(complex(*pole)) >= 1.0 - STABLE_MARGIN}
    if not flagged:
        return ""
    z = max(flagged.values(), key=abs)
    where = f"{z.real:+.5f}" if abs(z.imag) <= 1e-9 * abs(z) else f"{z.real:+.5f} {'+-'[z.imag < 0]} {abs(z.imag):.5f}j"
    hz = abs(cmath.phase(z)) / (2.0 * math.pi * Ts)
    head = f"note ({', '.join(flagged)}): the unconstrained loop at the start has a pole at z = {where} (|z| = {abs(z):.6f}): "
    if z.real < 0.0:
        return (head + f"an undamped {hz:.4g} Hz oscillation of inputs and velocities that the sampled "
                f"error hides (at Qu = 0 the dead-beat law cancels the sampled plant's zero at z = −1); a small Qu > 0 "
                f"damps it (docs/controller.md, 'Qu = 0 and the zero at z = −1')")
    return (head + f"a growing {hz:.4g} Hz mode that the prediction horizon N·Ts = {1e3 * N * Ts:g} ms does not "
            f"stabilize here (not the dead-beat law's z = −1, which a small Qu > 0 damps); a longer N may "
            f"(closed_loop_poles in parallel_gpc.gpc.stability tells before a run; docs/controller.md, "
            f"'Qu = 0 and the zero at z = −1')")


def outcome_code(results) -> int:
    """Print why runs stopped early; the exit code: 130 if Ctrl-C stopped one, else 3 if a closed
    loop diverged, else 0. ``results``: SimulationResults, already saved."""
    for res in results:
        if res.diverged:
            print(f"parallel-gpc: {res.meta.get('form', '')} GPC: {res.stopped}; its samples up to there are saved",
                  file=sys.stderr)
    if any(r.interrupted for r in results):
        print("interrupted: partial results saved")
        return EXIT_INTERRUPTED
    return EXIT_DIVERGED if any(r.diverged for r in results) else 0


def cmd_track(args) -> int:
    forms = selected_forms(args.forms)
    title = f"Tracking ({Path(args.reference).name} reference)"
    return run_and_report(settings_from_args(args), forms, Path(args.out), args, title)


#: The exit codes, in ``track --help`` and ``demo --help``.
EXIT_CODES = (f"exit codes: 0 done; 2 bad input (one-line error, nothing run); {EXIT_DIVERGED} a closed loop "
              f"diverged (its samples up to there and the other forms are saved; the message gives t, the "
              f"position error and the cause); {EXIT_INTERRUPTED} Ctrl-C (partial results saved)")


def register_track(sub) -> None:
    """Add the ``track`` sub-command."""
    p = sub.add_parser("track", parents=[ROBOT],
                       help="track a reference (a built-in path in the robot's outputs, a hold or a CSV file) with "
                            "each GPC form on the full constrained plant", epilog=EXIT_CODES)
    add_forms_argument(p, None, "--form")  # --form: the earlier spelling, still accepted
    p.add_argument("--out", default="out/track", help="output folder (default out/track)")
    add_tracking_arguments(p)
    p.set_defaults(func=cmd_track)
