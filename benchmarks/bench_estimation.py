"""Forward kinematics from drive readings and the Kalman update: Python loop vs compiled, µs per call.

Along the S-curve (planar robots; the helix on spatial ones) sampled at Ts = 2 ms, the exact
drive positions quantized to the encoder resolution (2^20 counts per revolution, 10^7 per metre,
or ``--counts``) are solved sample after sample, each call warm-started at the previous
solution's configuration, as the estimator does. Interleaved in blocks of ``--block`` samples
per operation (a shared, loaded machine inflates all alike):

* forward kinematics: ``robot.forward_solution`` (the public call: readings checks, the
  Gauss-Newton loop, the residual test, the result object) with ``PARALLEL_GPC_NATIVE=0`` (the
  Python reference) and with the compiled core, the same readings, each warm-started at its own
  previous solution; and the bare compiled call (``_native.ModelUpdate.solve_forward_into``
  into a new buffer, its own instance, no Python around it);
* Kalman update: ``StateEstimator.update`` (forward kinematics + the filter's correction), with
  ``PARALLEL_GPC_NATIVE=0`` and with the compiled core (two estimators on a second instance of
  the robot, each following its own estimate; the untimed ``predict`` between updates holds u = 0).

Prints the medians and the ratios Python / compiled.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_estimation.py [--robot planar_4rrr] [--duration 2] [--cpu] [--block 50]

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


def measure(spec: str, duration: float, sensors: Sensors, clock, block: int) -> dict:
    """Per-call times (s) of the five timed operations along the trajectory of robot ``spec``, in
    blocks of ``block`` samples per operation (each keeps its own warm start across its blocks)."""
    robot = ParallelRobot.load(spec)
    res = sensors.resolution(robot)
    rng = np.random.default_rng(0)
    qs = trajectory(robot, duration)
    readings = [encoder_readings(sensors, res, q[robot.drive_q_indices], rng) for q in qs]
    compiled = compiled_forward(robot)
    if compiled is None:
        sys.exit(f"the compiled forward kinematics is not available: {forward_status()}")
    X0 = np.concatenate([robot.platform_pose(qs[0]), np.zeros(robot.n_y)])
    # the estimators on their own robot: its compiled forward kinematics keeps its own last solution
    other = ParallelRobot.load(spec)
    estimators = {native: StateEstimator(ReducedModel(other, native=native), TS, sensors, X0)
                  for native in (False, True)}
    u0 = np.zeros(robot.n_u)
    state = {"fk python": qs[0], "fk compiled": qs[0], "fk bare": qs[0]}
    iterations = []

    def fk_python(r):
        state["fk python"] = robot.forward_solution(r, state["fk python"], res).q

    def fk_compiled(r):
        sol = robot.forward_solution(r, state["fk compiled"], res)
        state["fk compiled"] = sol.q
        iterations.append(sol.iterations)

    def fk_bare(r):
        out = np.empty(compiled.size)
        compiled.update.solve_forward_into(r, res, state["fk bare"], 50, 50.0, out)
        state["fk bare"] = out[compiled.q]

    def kalman(native):
        def update(r):
            estimators[native].update(Measurement(drives=r))
        return update

    ops = {"fk python": (fk_python, "0"), "fk compiled": (fk_compiled, "1"), "fk bare": (fk_bare, "1"),
           "kalman python": (kalman(False), "0"), "kalman compiled": (kalman(True), "1")}
    times = {key: [] for key in ops}
    saved = os.environ.get(ENV_SWITCH)
    try:
        for start in range(0, len(readings), block):
            chunk = readings[start:start + block]
            for key, (op, switch) in ops.items():
                os.environ[ENV_SWITCH] = switch
                for r in chunk:
                    t0 = clock()
                    op(r)
                    times[key].append(clock() - t0)
                    if key.startswith("kalman"):
                        estimators[key == "kalman compiled"].predict(u0)
    finally:
        if saved is None:
            os.environ.pop(ENV_SWITCH, None)
        else:
            os.environ[ENV_SWITCH] = saved
    gap = float(np.max(np.abs(state["fk python"] - state["fk compiled"])))
    return {"times": times, "calls": len(readings), "gap": gap, "iterations": float(np.mean(iterations)),
            "robot": robot.name}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="planar_4rrr", help="robot name or path (default planar_4rrr)")
    parser.add_argument("--duration", type=float, default=2.0, help="s of the path, 500 calls per s (default 2)")
    parser.add_argument("--counts", default="encoders", help="sensors spec as track --sensors (default encoders)")
    parser.add_argument("--cpu", action="store_true", help="thread CPU time instead of wall-clock time")
    parser.add_argument("--block", type=int, default=50,
                        help="samples per operation between switches (default 50; 1 = interleaved per sample, "
                             "each call then starts with caches the other operations filled)")
    args = parser.parse_args()
    sensors = Sensors.parse(args.counts)
    out = measure(args.robot, args.duration, sensors, time.thread_time if args.cpu else time.perf_counter,
                  max(1, args.block))
    med = {key: 1e6 * float(np.median(t)) for key, t in out["times"].items()}
    print(f"{out['robot']}: {out['calls']} warm-started calls along the path, Ts = {1e3 * TS:g} ms, {args.counts}, "
          f"{'CPU' if args.cpu else 'wall-clock'} medians (µs), blocks of {max(1, args.block)} samples per operation")
    print(f"{'':<20} {'python':>9} {'compiled':>9} {'ratio':>7}")
    for what, key in (("forward kinematics", "fk"), ("Kalman update", "kalman")):
        py, cc = med[f"{key} python"], med[f"{key} compiled"]
        print(f"{what:<20} {py:9.1f} {cc:9.1f} {py / cc:6.1f}x")
    print(f"bare compiled forward kinematics (ModelUpdate.solve_forward_into): {med['fk bare']:.1f} µs, "
          f"{out['iterations']:.2f} Gauss-Newton iterations per call on average")
    print(f"last configurations of the two loops differ by {out['gap']:.1e} (rad or m); "
          f"Ts = {1e6 * TS:.0f} µs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
