"""``parallel-gpc robustness``: tracking error of each GPC form under mismatch, noise and a load.

A thin layer over :func:`parallel_gpc.robustness_study`: prints the table and writes
``robustness.csv``, ``robustness.json`` and ``robustness.png`` into ``--out``. Ctrl-C stops the
study, saves the rows computed so far (marked interrupted) and exits with code 130.
"""

from __future__ import annotations

import sys

from .defaults import EXIT_INTERRUPTED, PAPER_FORMS
from .vocabulary import ROBOT, add_forms_argument, add_reference_argument, selected_forms

#: ``--quick``: fewer cases (nominal, ±30 % mass, one noise level, one force), same runs.
QUICK = dict(mass_scales=(0.7, 1.3), noise_levels=(1e-4,), disturbances=(20.0,))


def cmd_robustness(args) -> int:
    from ..plots import plot_robustness, save_figure
    from ..sweeps import (DEFAULT_DISTURBANCES, DEFAULT_MASS_SCALES, DEFAULT_NOISE_LEVELS, DEFAULT_WEIGHTS,
                          robustness_study)
    from ..gpc import Weights
    from .outputs import prepare_out_dir

    forms = selected_forms(args.forms)
    settings = dict(mass_scales=DEFAULT_MASS_SCALES, noise_levels=DEFAULT_NOISE_LEVELS,
                    disturbances=DEFAULT_DISTURBANCES, duration=2.5)
    if args.quick:
        settings.update(QUICK)
    if args.mass_scales is not None:
        settings["mass_scales"] = tuple(args.mass_scales)
    if args.noise is not None:
        settings["noise_levels"] = tuple(args.noise)
    if args.disturbances is not None:
        settings["disturbances"] = tuple(args.disturbances)
    if args.duration is not None:
        settings["duration"] = args.duration
    weights = Weights(DEFAULT_WEIGHTS.Qy if args.Qy is None else args.Qy,
                      DEFAULT_WEIGHTS.Qu if args.Qu is None else args.Qu)
    out = prepare_out_dir(args.out)

    def echo(row) -> None:
        print(f"  {row['form']:<11} {row['study']:<11} {row['value']:>8g} {row['unit']:<2} "
              f"RMS {row['rms_position_error_mm']:.4f} mm  steady {row['steady_state_error_mm']:.4f} mm  "
              f"{row['status']}", file=sys.stderr)

    result = robustness_study(args.robot, forms=forms, Ts=args.Ts, N=args.N, weights=weights,
                              reference=args.reference, progress=False, on_row=echo, workers=args.workers,
                              scheduler=args.scheduler, **settings)
    print(result.format_table())
    paths = [result.save_csv(out / "robustness.csv"), result.save_json(out / "robustness.json")]
    if result.rows:
        paths.append(save_figure(plot_robustness(result), out / "robustness.png"))
    print("wrote " + ", ".join(str(p) for p in paths))
    if result.interrupted:
        print(f"parallel-gpc: interrupted after {len(result.rows)} runs; the partial table is saved",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    return 0


def register_robustness(sub) -> None:
    """Add the ``robustness`` sub-command."""
    p = sub.add_parser(
        "robustness", parents=[ROBOT],
        help="tracking error of each GPC form under mass mismatch, noise and a constant force",
        description="For each prediction form, run the closed loop on the full constrained plant with the "
                    "plant's masses/inertias scaled (-30 … +30 %), with measurement noise, and with a "
                    "constant force on the platform, along the robot's path (the S-curve on planar robots, the "
                    "helix on spatial ones); print a table and write CSV, JSON and a plot.",
    )
    add_forms_argument(p, PAPER_FORMS)
    p.add_argument("--duration", type=float, default=None, help="length of each run in s (default 2.5; the path takes 80 %% of it, then a hold)")
    p.add_argument("--Ts", type=float, default=0.005, help="sample time in s (default 0.005)")
    p.add_argument("--N", type=int, default=10, help="prediction horizon in samples (default 10)")
    p.add_argument("--Qy", type=float, default=None, help="output weight (square root, default 1)")
    p.add_argument("--Qu", type=float, default=None, help="input/increment weight (square root, default 1e-4)")
    p.add_argument("--mass-scales", type=float, nargs="*", default=None, metavar="S",
                   help="plant mass scales, space-separated (default 0.7 0.85 1.15 1.3; none: no mass cases)")
    p.add_argument("--noise", type=float, nargs="*", default=None, metavar="STD",
                   help="pose noise σ in m, space-separated (default 1e-5 1e-4; none: no noise cases)")
    p.add_argument("--disturbances", type=float, nargs="*", default=None, metavar="F",
                   help="platform forces along x in N, space-separated (default 10 20; none: no force cases)")
    add_reference_argument(p, "the home pose", "; built-in paths take 80 %% of the run, then a hold")
    p.add_argument("--out", default="out/robustness", help="output folder (default out/robustness)")
    p.add_argument("--quick", action="store_true", help="fewer cases: ±30 %% mass, noise 1e-4 m, 20 N (about half the time)")
    p.add_argument("--workers", type=int, default=0,
                   help="0 = serial in this process (default); n = a local Dask cluster of n processes")
    p.add_argument("--scheduler", default=None, help="address tcp://HOST:PORT of a running Dask scheduler")
    p.set_defaults(func=cmd_robustness)
