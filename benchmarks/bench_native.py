"""Compiled vs pure-Python model update: median µs per call, and the controller step with each.

Per robot: ``ReducedModel.discrete(X, Ts)`` over 20 states along a path with nonzero velocities
(consecutive calls, as the controller makes them) and one ``simulate_factorized`` of N = 20 states
(the nonlinear form's pre-simulation with inputs near those holding the home pose,
receding: each call starts at the previous call's second state). Then the
full ``GPCController.step`` of the absolute and nonlinear forms on planar_4rrr (N = 20,
Ts = 2 ms, S-curve, closed loop on the constrained plant; only the step is timed) with the
compiled update on and off.

    OPENBLAS_NUM_THREADS=1 taskset -c 1 python benchmarks/bench_native.py [--reps 5] [--cpu]

``--cpu`` times with the thread's CPU clock instead of the wall clock (for a shared machine).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from parallel_gpc import (  # noqa: E402
    GPCController, Horizons, ParallelRobot, ReducedModel, SCurve, Weights,
)

from closed_loop import closed_loop_steps  # noqa: E402

TS = 0.002
N = 20
clock = time.perf_counter  # --cpu: time.thread_time
ROBOTS = ["planar_4rrr", "planar_3rrr", "delta_3rus", "hexapod_6ups", "hexapod_8ups"]


def _path(robot: ParallelRobot, n: int = N) -> list[np.ndarray]:
    rng = np.random.default_rng(3)
    direction = rng.uniform(-1, 1, robot.n_y)
    return [np.concatenate([robot.home_pose + 0.02 * t * direction, 0.5 * direction]) for t in np.linspace(0, 1, n)]


def _median_us(times) -> float:
    return float(np.median(times)) * 1e6


def model_update_times(name: str, reps: int) -> dict:
    """Median µs of discrete and simulate_factorized, Python and compiled interleaved per repetition
    (a shared, loaded machine inflates both alike)."""
    robot = ParallelRobot.load(name)
    states = _path(robot)
    hold = ReducedModel(robot, native=False).terms(np.concatenate([robot.home_pose, np.zeros(robot.n_y)]))
    u_hold = np.linalg.lstsq(hold.B_r, hold.h_r, rcond=None)[0]  # drive efforts that hold the home pose
    u = u_hold + np.random.default_rng(1).uniform(-0.5, 0.5, (N, robot.n_u))
    models = {False: ReducedModel(robot, native=False), True: ReducedModel(robot, native=True)}
    times = {(native, what): [] for native in models for what in ("discrete", "simulate")}
    for _ in range(reps):
        for native, model in models.items():
            for X in states:
                t0 = clock()
                model.discrete(X, TS)
                times[native, "discrete"].append(clock() - t0)
            X = states[0]
            for k in range(N):  # receding horizon: the next call starts at the next simulated state
                t0 = clock()
                X_seq = model.simulate_factorized(X, np.roll(u, -k, axis=0), TS)[3]
                times[native, "simulate"].append(clock() - t0)
                X = X_seq[1]
    return {key: _median_us(t) for key, t in times.items()}


def controller_step_times(form: str, native: bool, steps: int = 300, warmup: int = 20) -> float:
    robot = ParallelRobot.load("planar_4rrr")
    ref = SCurve()
    ctl = GPCController.build(ReducedModel(robot, native=native), TS, Horizons(N), Weights(1.0, 1e-5), form=form)
    times, _ = closed_loop_steps(robot, ref, ctl, N, steps, clock, TS)
    return _median_us(times[warmup:])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=5)
    parser.add_argument("--cpu", action="store_true", help="the thread's CPU clock instead of the wall clock")
    args = parser.parse_args()
    global clock
    clock = time.thread_time if args.cpu else time.perf_counter
    print(f"{'robot':<14}{'discrete py':>13}{'compiled':>10}{'ratio':>7}{'simulate20 py':>15}{'compiled':>10}{'ratio':>7}")
    for name in ROBOTS:
        t = model_update_times(name, args.reps)
        dp, sp, dc, sc = (t[False, "discrete"], t[False, "simulate"], t[True, "discrete"], t[True, "simulate"])
        print(f"{name:<14}{dp:>11.1f}µs{dc:>8.1f}µs{dp / dc:>6.1f}×{sp:>13.0f}µs{sc:>8.0f}µs{sp / sc:>6.1f}×")
    print("\nGPCController.step, planar_4rrr, N = 20, Ts = 2 ms (median µs, closed loop)")
    for form in ("absolute", "nonlinear"):
        runs = {native: [] for native in (False, True)}
        for _ in range(args.reps):  # interleaved
            for native in runs:
                runs[native].append(controller_step_times(form, native))
        py, cc = np.median(runs[False]), np.median(runs[True])
        print(f"  {form:<10} python {py:8.0f} µs   compiled {cc:8.0f} µs   ratio {cc / py:.2f}")

if __name__ == "__main__":
    main()
