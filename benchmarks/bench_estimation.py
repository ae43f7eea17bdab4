"""Forward kinematics from drive readings and the Kalman update: Python loop vs compiled, µs per call.

Along the S-curve (planar robots; the helix on spatial ones) sampled at Ts = 2 ms, the exact
drive positions quantized to the encoder resolution (2^20 counts per revolution, 10^7 per metre,
or ``--counts``) are solved sample after sample, each call warm-started at the previous
solution's configuration, as the estimator does. Per sample, interleaved (a shared, loaded
machine inflates both alike):

* forward kinematics: ``solve_forward`` with the Python Gauss-Newton loop and with the compiled
  one (``_native.ModelUpdate.forward``), the same readings and warm start;
* Kalman update: ``StateEstimator.update`` (forward kinematics + the filter's correction), with
  ``PARALLEL_GPC_NATIVE=0`` and with the compiled core (two estimators, each following its own
  estimate; the untimed ``predict`` between updates holds u = 0).

Prints the medians and the ratios Python / compiled.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_estimation.py [--robot planar_4rrr] [--duration 2] [--cpu]

``--cpu`` times with the thread's CPU clock instead of the wall clock (for a shared machine).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from parallel_gpc import ParallelRobot, ReducedModel, path_for  # noqa: E402
from parallel_gpc.estimation import Measurement, Sensors, StateEstimator  # noqa: E402
from parallel_gpc.estimation.sensors import encoder_readings  # noqa: E402
from parallel_gpc.model.forward import solve_forward  # noqa: E402
from parallel_gpc.model.native import ENV_SWITCH  # noqa: E402
from parallel_gpc.model.native_update import compiled_forward, forward_status  # noqa: E402

TS = 0.002


def trajectory(robot: ParallelRobot, duration: float) -> list[np.ndarray]:
    """(nq,) exact configurations along the robot's reference path, one per sample."""
    kind = "s-curve" if robot.name.startswith("planar") else "helix"
    ref = path_for(kind, robot.home_pose, robot.output_angular, duration)
    qs, q = [], robot.q_home
    for k in range(int(round(duration / TS))):
        q = robot.assemble(ref.pose(k * TS), q)
        qs.append(q)
    return qs


def measure(robot: ParallelRobot, duration: float, sensors: Sensors, clock) -> dict:
    """Per-call times (s) of the four timed operations along the trajectory."""
    res = sensors.resolution(robot)
    rng = np.random.default_rng(0)
    qs = trajectory(robot, duration)
    readings = [encoder_readings(sensors, res, q[robot.drive_q_indices], rng) for q in qs]
    compiled = compiled_forward(robot)
    if compiled is None:
        sys.exit(f"the compiled forward kinematics is not available: {forward_status()}")
    X0 = np.concatenate([robot.platform_pose(qs[0]), np.zeros(robot.n_y)])
    estimators = {native: StateEstimator(ReducedModel(robot, native=native), TS, sensors, X0)
                  for native in (False, True)}
    u0 = np.zeros(robot.n_u)
    times = {key: [] for key in ("fk python", "fk compiled", "kalman python", "kalman compiled")}
    q_py = q_cc = qs[0]
    saved = os.environ.get(ENV_SWITCH)
    try:
        for r in readings:
            t0 = clock()
            q_py = solve_forward(robot, r, res, q_py, compiled=None).q
            t1 = clock()
            q_cc = solve_forward(robot, r, res, q_cc, compiled=compiled).q
            t2 = clock()
            times["fk python"].append(t1 - t0)
            times["fk compiled"].append(t2 - t1)
            for native, est in estimators.items():
                os.environ[ENV_SWITCH] = "1" if native else "0"
                meas = Measurement(drives=r)
                t0 = clock()
                est.update(meas)
                times[f"kalman {'compiled' if native else 'python'}"].append(clock() - t0)
                est.predict(u0)
    finally:
        if saved is None:
            os.environ.pop(ENV_SWITCH, None)
        else:
            os.environ[ENV_SWITCH] = saved
    gap = float(np.max(np.abs(q_py - q_cc)))
    return {"times": times, "calls": len(readings), "gap": gap}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="planar_4rrr", help="robot name or path (default planar_4rrr)")
    parser.add_argument("--duration", type=float, default=2.0, help="s of the path, 500 calls per s (default 2)")
    parser.add_argument("--counts", default="encoders", help="sensors spec as track --sensors (default encoders)")
    parser.add_argument("--cpu", action="store_true", help="thread CPU time instead of wall-clock time")
    args = parser.parse_args()
    robot = ParallelRobot.load(args.robot)
    sensors = Sensors.parse(args.counts)
    out = measure(robot, args.duration, sensors, time.thread_time if args.cpu else time.perf_counter)
    med = {key: 1e6 * float(np.median(t)) for key, t in out["times"].items()}
    print(f"{robot.name}: {out['calls']} warm-started calls along the path, Ts = {1e3 * TS:g} ms, {args.counts}, "
          f"{'CPU' if args.cpu else 'wall-clock'} medians (µs)")
    print(f"{'':<20} {'python':>9} {'compiled':>9} {'ratio':>7}")
    for what, key in (("forward kinematics", "fk"), ("Kalman update", "kalman")):
        py, cc = med[f"{key} python"], med[f"{key} compiled"]
        print(f"{what:<20} {py:9.1f} {cc:9.1f} {py / cc:6.1f}x")
    print(f"last configurations of the two loops differ by {out['gap']:.1e} (rad or m); "
          f"Ts = {1e6 * TS:.0f} µs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
