#!/usr/bin/env python3
"""The default solver against the QR reference: control step in QR units and the 1 kHz closed loop.

Usage: ``OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/bench_default.py [--reps 15] [--loop-s 10]
[--rounds 2]`` (~1–2 min). planar_4rrr, N = 20, Ts = 2 ms, Qu = 1e-5 (the benchmark's weights):
each form's controller with ``solver=None`` (the default of ``gpc.settings.default_solver``) and
with ``solver="qr"``, replayed on 40 states of its own default closed loop along the S-curve; the
blocks (40 consecutive ``dgeqrf`` of the 140 × 80 stacked matrix — the unit —, then each
controller's 40 steps) interleaved over ``--reps`` passes in one process; medians. Then the 10 s
closed loop at 1 kHz (``closed_loop_wall_time``), default and QR alternating for ``--rounds``.
See benchmarks/README.md, "The stage-wise path as the default".
"""

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"  # before numpy loads

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from parallel_gpc import ConstrainedPlant, GPCController, Horizons, ParallelRobot, ReducedModel, SCurve  # noqa: E402
from parallel_gpc import Weights  # noqa: E402
from parallel_gpc.bench.harness import closed_loop_wall_time, lapack_qr_unit  # noqa: E402

FORMS = ("absolute", "incremental", "nonlinear")


def replayed_states(model, robot, form, Ts, N, W, ref, start=150, count=40):
    """(X, w, controller state) of ``count`` samples of the form's default closed loop from sample ``start``."""
    ctl = GPCController.build(model, Ts, Horizons(N), W, form=form)
    plant = ConstrainedPlant(robot, ref.initial_state(), Ts=Ts)
    rows = []
    for k in range(start + count):
        X, w = plant.X, ref.window(k * Ts, Ts, N)
        if k >= start:
            rows.append((X.copy(), w.copy(), ctl.state))
        plant.step(ctl.step(X, w).u)
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--reps", type=int, default=15)
    p.add_argument("--loop-s", type=float, default=10.0, help="closed-loop duration in s (0: skip)")
    p.add_argument("--rounds", type=int, default=2)
    args = p.parse_args()
    robot, Ts, N, W = ParallelRobot.load("planar_4rrr"), 0.002, 20, Weights(1.0, 1e-5)
    model, ref = ReducedModel(robot), SCurve()
    configs = {(form, solver): GPCController.build(model, Ts, Horizons(N), W, form=form, solver=solver)
               for form in FORMS for solver in (None, "qr")}
    samples = {form: replayed_states(model, robot, form, Ts, N, W, ref) for form in FORMS}
    A = np.random.default_rng(0).standard_normal((N * robot.n_y + N * robot.n_u, N * robot.n_u))
    times = {key: [] for key in [*configs, "unit"]}
    for _ in range(args.reps):
        for _ in range(40):
            t0 = time.perf_counter()
            lapack_qr_unit(A)
            times["unit"].append(time.perf_counter() - t0)
        for (form, solver), ctl in configs.items():
            for X, w, state in samples[form]:
                ctl.restore(state)
                t0 = time.perf_counter()
                info = ctl.step(X, w)
                times[(form, solver)].append(time.perf_counter() - t0)
                assert not info.fallback
    unit = np.median(times["unit"])
    print(f"unit: dgeqrf {A.shape} median {1e6 * unit:.1f} µs; load average {os.getloadavg()[0]:.2f}")
    for (form, solver), ctl in configs.items():
        med = np.median(times[(form, solver)])
        label = "default" if solver is None else solver
        print(f"{form:12s} {label:8s} ({ctl.solver:8s}) median {1e6 * med:7.1f} µs = {med / unit:5.2f} QR units")
    for rnd in range(args.rounds if args.loop_s > 0 else 0):
        for solver in (None, "qr"):
            c0 = time.process_time()
            r = closed_loop_wall_time("planar_4rrr", args.loop_s, solver=solver)
            print(f"closed loop {args.loop_s:g} s at 1 kHz, round {rnd}, {r['solver']:8s}: wall {r['wall_s']:.2f} s, "
                  f"CPU {time.process_time() - c0:.2f} s, controller {r['controller_s']:.2f} s, "
                  f"load average {os.getloadavg()[0]:.2f}", flush=True)


if __name__ == "__main__":
    main()
