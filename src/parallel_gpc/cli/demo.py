"""``parallel-gpc demo``: the paper's Fig. 2 comparison where the forms differ.

Three parts (library: :mod:`parallel_gpc.studies`):

1. Qu = 0, the paper's setting: all forms in lockstep on one closed loop, compared with the
   one-step dead-beat law: they give the same u(k) (dead-beat, form-independent).
2. Qu > 0 (default Ts = 10 ms, N = 30, Qu = 1e-3) on a plant 20 % heavier than the model with a
   steady load: every form, with the state-disturbance estimate off and on (one table column),
   so that the effects of the form and of the estimator are never confounded.
3. The same forms (but incremental-delayed, unless it is the only one) on the same plant seeing
   only their drive encoders (``--encoders``, default 2^20 counts per revolution): quantized
   readings → forward kinematics → Kalman filter of [y, ẏ, d], beside the full-state runs of
   part 2 (estimate on), with the step times and the steps longer than Ts — what a controller
   for a real machine does.

Writes ``demo_compare.png`` (shared axes, limit lines if ``--torque-limit``), ``demo_path.png``,
``demo_<form>_a<α>.npz`` and ``demo_<form>_encoders.npz`` result files and one labelled
``demo_<form>.html`` animation per form.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from .defaults import DEMO
from .track import EXIT_CODES, add_tracking_arguments, outcome_code, settings_from_args
from .vocabulary import ROBOT, add_forms_argument, limits_line, selected_forms


def cmd_demo(args) -> int:
    from ..errors import InvalidParameterError
    from ..model import forward_status, ParallelRobot
    from ..studies import comparison_table, deadbeat_check, run_comparison, run_tracking, sensors_table
    from ..plots import save_figure, plot_comparison, plot_paths

    settings = settings_from_args(args)
    if args.encoders != "none":  # refused before parts 1 and 2 run
        if not str(args.encoders).startswith("encoders"):
            raise InvalidParameterError(f"--encoders {args.encoders!r} must be an encoder spec (encoders, "
                                        "encoders:2^16, encoders:m=1e5, ...) or none")
        replace(settings, sensors=args.encoders)
    robot = ParallelRobot.load(settings.robot)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(limits_line(args, settings.limits, robot.drive_unit))
    check = deadbeat_check(settings, duration=args.deadbeat_duration, robot=robot)
    diffs = ", ".join(f"{f} {d:.1e}" for f, d in check.max_difference().items())
    print(f"1) Qu = 0 (the paper's Fig. 2 setting), exact plant, Ts = {1e3 * settings.Ts:g} ms, N = {settings.horizons.N}: "
          f"the stacked G has full row rank, so every form is the one-step dead-beat law "
          f"u(k) = (C B_d)⁺ (w(k+1) − C(A_d X + c_d)).\n   max |u_form − u_dead-beat| over "
          f"{len(check.t)} samples [N·m]: {diffs} — the forms are indistinguishable at Qu = 0.")
    forms = selected_forms(args.forms)
    runs = run_comparison(settings, forms, gains=(0.0, settings.disturbance_gain), progress=not args.no_progress,
                          robot=robot)
    print(f"2) Qu = {settings.weights.Qu:g} (the horizon matters), Ts = {1e3 * settings.Ts:g} ms, "
          f"N = {settings.horizons.N}, "
          f"plant mass × {settings.mass_scale:g}, steady load {list(settings.platform_force)} (N, N, N·m), "
          f"torque limit {settings.limits.to_dict()['torque']}; each form with the disturbance estimate off and on (est. α):")
    print(comparison_table(runs))
    print("   steady = mean position error over the last 0.3 s (S-curve ends at 2 s); int. f = largest "
          "drive-torque component in null(B_r) (drive fighting)"
          + ("; with an active torque limit it may be used to respect the limit" if settings.limits.torque is not None else ""))
    _iterations_lines({f"{form}, est. α {gain:g}": res for (form, gain), res in runs.items()})
    for (form, gain), res in runs.items():
        res.save(out / f"demo_{form}_a{gain:g}.npz")
    on = {form: res for (form, gain), res in runs.items() if gain == settings.disturbance_gain}
    encoders = {}
    if args.encoders != "none":
        # incremental-delayed only when asked alone: the demo's runtime grows by ~30 %, not ~40 %
        enc_forms = [f for f in forms if f != "incremental-delayed"] or forms
        encoders = run_tracking(replace(settings, sensors=args.encoders), enc_forms, progress=not args.no_progress,
                                robot=robot)
        print(f"3) drive encoders only ({args.encoders}: quantized readings → forward kinematics → Kalman filter of "
              f"[y, ẏ, d]; the controller's own estimate off) beside the full-state runs of 2), same plant and load:")
        print(sensors_table(on, encoders, settings.Ts))
        print(f"   step = estimation + control time per sample, > Ts = steps longer than Ts = {1e3 * settings.Ts:g} ms "
              f"(forward kinematics: {forward_status()})")
        _iterations_lines({f"{form}, encoders": res for form, res in encoders.items()})
        for form, res in encoders.items():
            res.save(out / f"demo_{form}_encoders.npz")
    title = f"Qu = {settings.weights.Qu:g}, mass × {settings.mass_scale:g}, load {list(settings.platform_force)}"
    written = [save_figure(plot_comparison(runs, settings.limits, f"GPC forms compared ({title})"),
                           out / "demo_compare.png"),
               save_figure(plot_paths(on, f"platform path, estimator on ({title})"), out / "demo_path.png")]
    _animations(args, robot, on, settings, out)
    print("wrote " + ", ".join(str(p) for p in written) + " and demo_<form>_a<α>.npz"
          + (" and demo_<form>_encoders.npz" if encoders else "") + f" in {out}")
    return outcome_code([*runs.values(), *encoders.values()])


def _iterations_lines(results: dict) -> None:
    """One line per labelled result whose nonlinear form iterated (``--iterations``): its Gauss–Newton summary."""
    for label, res in results.items():
        summary = res.iterations_summary()
        if summary:
            print(f"   {label}: {summary}")


def _animations(args, robot, results, settings, out: Path) -> None:
    """One labelled HTML animation per form, demo_<form>.html (``--serve`` shows the last form live)."""
    from argparse import Namespace

    from ..results import saturation_flags
    from .view import show_trajectory

    for i, (form, res) in enumerate(results.items()):
        html = str(out / f"demo_{form}.html")
        flags = saturation_flags(res.u, settings.limits, rtol=1e-5)
        view = Namespace(html=html, html_optional=True, serve=bool(args.serve) and i == len(results) - 1)
        show_trajectory(view, robot, res.t, res.q,
                        reference=res.reference, saturated=flags,
                        title=f"{form} GPC, disturbance estimate α = {settings.disturbance_gain:g}, Qu = {settings.weights.Qu:g}")


def register_demo(sub) -> None:
    """Add the ``demo`` sub-command."""
    p = sub.add_parser("demo", parents=[ROBOT],
                       help="the main job: the paper's Fig. 2 comparison of the GPC forms on the default robot",
                       description=__doc__.split("\n\n")[0] + " Qu = 0 (dead-beat, form-independent) and Qu > 0 "
                       "on a mismatched, loaded plant with the disturbance estimate off and on.", epilog=EXIT_CODES)
    p.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    add_forms_argument(p)
    p.add_argument("--deadbeat-duration", type=float, default=1.0, help="s of the Qu = 0 lockstep check (default 1)")
    p.add_argument("--encoders", default="encoders", metavar="encoders[:COUNTS_PER_REV][,m=COUNTS_PER_M]|none",
                   help="sensors of part 3, the encoder-only loop (as track's --sensors); none skips it "
                        "(default encoders: 2^20 counts per revolution, 1e7 per metre)")
    add_tracking_arguments(p, DEMO, html=False)  # it writes demo_<form>.html itself
    p.set_defaults(func=cmd_demo)
