#!/usr/bin/env python3
"""Time the absolute and incremental steps with ``solver="riccati"`` against ``"qr"``.

``python benchmarks/bench_riccati.py [--reps 7] [--samples 60] [--cases planar_4rrr:10,planar_4rrr:20,...]``

For every case (robot, N) the states of a 0.5 s closed loop along the robot's default path (qr,
absolute form, on the full plant) are recorded; then every configuration steps through the same
states and reference windows, interleaved (one pass of each configuration per repetition, the
controller reset before each pass): the reference-Python step (``ReducedModel(robot,
native=False)`` + qr, today's pure-Python path), and {absolute, incremental} × {qr, riccati} with
the compiled model update. Ts = 2 ms, No = 0, Nu = N, Qy = 1, Qu = 1e-5. Prints the median step
(µs, the whole ``GPCController.step``) and its ratio to the same form's reference-Python step.

Run with ``OPENBLAS_NUM_THREADS=1 taskset -c 1`` and PYTHONPATH=src (the compiled core built).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from parallel_gpc.gpc.controller import GPCController
from parallel_gpc.gpc.criterion import Weights
from parallel_gpc.gpc.prediction import Horizons
from parallel_gpc.gpc.references import SCurve, path_for
from parallel_gpc.model.dynamics import ReducedModel
from parallel_gpc.model.plant import ConstrainedPlant
from parallel_gpc.model.robot import ParallelRobot

TS = 0.002
WEIGHTS = Weights(1.0, 1e-5)


def _states(robot, ref, N: int, samples: int):
    """States and reference windows of a closed loop (absolute, qr) on the full plant."""
    ctl = GPCController.build(ReducedModel(robot), TS, Horizons(N), WEIGHTS)
    plant = ConstrainedPlant(robot, ref.initial_state(), Ts=TS)
    Xs, ws = [], []
    for k in range(samples):
        w = ref.window(k * TS, TS, N)
        Xs.append(plant.X.copy())
        ws.append(w)
        plant.step(ctl.step(plant.X, w).u)
    return Xs, ws


def run_case(name: str, N: int, reps: int, samples: int) -> None:
    robot = ParallelRobot.load(name)
    ref = path_for("auto", robot.home_pose, robot.output_angular, SCurve().duration)
    Xs, ws = _states(robot, ref, N, samples)
    compiled, python = ReducedModel(robot), ReducedModel(robot, native=False)
    if not compiled.native:
        raise SystemExit(f"the compiled model update is not in use: {compiled.native_reason}")
    configs = {}
    for form in ("absolute", "incremental"):
        configs[f"{form} reference-python qr"] = GPCController.build(python, TS, Horizons(N), WEIGHTS, form=form)
        for solver in ("qr", "riccati"):
            configs[f"{form} compiled {solver}"] = GPCController.build(compiled, TS, Horizons(N), WEIGHTS, form=form,
                                                                 solver=solver)
    times = {key: [] for key in configs}
    us = {key: [] for key in configs}
    for _ in range(reps):
        for key, ctl in configs.items():
            ctl.reset()
            u = []
            for X, w in zip(Xs, ws):
                t0 = time.perf_counter()
                info = ctl.step(X, w)
                times[key].append(time.perf_counter() - t0)
                u.append(info.u)
            us[key] = np.array(u)
    print(f"\n{name}, N = {N} ({samples} states × {reps} passes, interleaved), median µs of GPCController.step")
    for key in configs:
        form = key.split()[0]
        med = 1e6 * float(np.median(times[key]))
        ref_med = 1e6 * float(np.median(times[f"{form} reference-python qr"]))
        qr = us[f"{form} compiled qr"]
        diff = float(np.max(np.abs(us[key] - qr)) / np.max(np.abs(qr)))
        print(f"  {key:34s} {med:8.1f} µs   {ref_med / med:5.2f}× faster than reference   "
              f"max|u − u_qr|/max|u_qr| = {diff:.1e}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=7)
    parser.add_argument("--samples", type=int, default=60)
    parser.add_argument("--cases", default="planar_4rrr:10,planar_4rrr:20,planar_4rrr:40,hexapod_8ups:20")
    args = parser.parse_args()
    for case in args.cases.split(","):
        name, N = case.split(":")
        run_case(name, int(N), args.reps, args.samples)


if __name__ == "__main__":
    main()
