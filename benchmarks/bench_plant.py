#!/usr/bin/env python3
"""Benchmark the plant step: ConstrainedPlant.step in Python vs with the compiled core, per robot.

Usage: ``OPENBLAS_NUM_THREADS=1 taskset -c 1 python benchmarks/bench_plant.py [--samples 400]
[--repeats 3] [--robots planar_4rrr ...]`` (PYTHONPATH=src with the module built by
``native/build_inplace.py``, or the package installed). Each robot's plants (``native=False`` and
``native=True``) start at home with a small velocity and alternate in blocks of 50 samples of
1 ms under gravity-holding torques (the same conditions for both, interleaved so that machine
load hits both alike). Per path: the median µs of the whole step, of the integration alone
(RK4, 2 sub-steps of ``constraintDynamics``) and of the projection onto the closures. Prints a
Markdown table. ``--closed-loop K`` then runs K samples of the closed loop of
``closed_loop_wall_time`` (planar_4rrr, absolute controller, N = 20, 1 kHz) in which, at every
sample, both plants step from the same state with the same u (in alternating order; the loop goes
on from the compiled one) and prints the median controller step and plant steps in µs.
``--split S`` runs ``closed_loop_wall_time("planar_4rrr", S)`` itself (``simulate``, default plant)
with ``ConstrainedPlant.step`` timed and prints wall, controller (its step times), plant and the
rest (the loop's bookkeeping) in s per simulated s. See benchmarks/README.md.
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import pinocchio as pin  # noqa: E402

from parallel_gpc import ParallelRobot  # noqa: E402
from parallel_gpc.model.plant import ConstrainedPlant  # noqa: E402

ROBOTS = ["planar_4rrr", "planar_3rrr", "delta_3rus", "hexapod_6ups", "hexapod_8ups"]
TS = 1e-3  # s
BLOCK = 50  # samples per block; the plants restart from X0 after each block


def holding_torques(robot: ParallelRobot) -> np.ndarray:
    """(n_u,) least-squares drive torques that hold the platform against gravity at home."""
    q = robot.q_home
    T, _ = robot.velocity_map(q)
    g_r = T.T @ pin.computeGeneralizedGravity(robot.model, robot.model.createData(), q)
    return np.linalg.lstsq(T.T @ robot.drive_selection, g_r, rcond=None)[0]


def time_block(plant: ConstrainedPlant, u: np.ndarray, times: dict) -> None:
    """BLOCK samples of ``plant``: whole step, then the same sample split into its parts."""
    for _ in range(BLOCK):
        q0, v0 = plant.q, plant.v
        t0 = time.perf_counter()
        plant.step(u)
        t1 = time.perf_counter()
        times["step"].append(t1 - t0)
        q1, v1 = plant.q, plant.v
        plant.q, plant.v = q0, v0  # the same sample again, integration and projection apart
        plant.robot._ck_cache = plant.robot._vm_cache = None  # as cold as in the step
        t0 = time.perf_counter()
        if plant.compiled is None:
            q, v = q0, v0
            for _ in range(plant.substeps):
                q, v = plant._rk4(q, v, u, TS / plant.substeps)
        else:
            q, v = plant._compiled_sample(u, TS)
        t1 = time.perf_counter()
        plant._project(q, v)
        t2 = time.perf_counter()
        times["integrate"].append(t1 - t0)
        times["project"].append(t2 - t1)
        plant.q, plant.v = q1, v1


def bench_robot(name: str, samples: int, repeats: int) -> dict:
    robot = ParallelRobot.load(name)
    X0 = np.concatenate([robot.home_pose, np.full(robot.n_y, 0.02)])
    u = holding_torques(robot)
    out = {}
    for native in (False, True):
        out[native] = {k: [] for k in ("step", "integrate", "project")}
    for _ in range(repeats * max(1, samples // BLOCK)):
        for native in (False, True):
            time_block(ConstrainedPlant(robot, X0, Ts=TS, native=native), u, out[native])
    return {native: {k: 1e6 * float(np.median(v)) for k, v in d.items()} for native, d in out.items()}


def closed_loop(K: int) -> None:
    """Paired plant steps inside the closed loop (see the module docstring)."""
    from parallel_gpc import ReducedModel
    from parallel_gpc.gpc.controller import GPCController
    from parallel_gpc.gpc.criterion import Weights
    from parallel_gpc.gpc.prediction import Horizons
    from parallel_gpc.gpc.references import SCurve, path_for

    robot = ParallelRobot.load("planar_4rrr")
    ref = path_for("auto", robot.home_pose, robot.output_angular, SCurve().duration)
    ctl = GPCController.build(ReducedModel(robot), TS, Horizons(20), Weights(1.0, 1e-5))
    fast, slow = (ConstrainedPlant(robot, ref.initial_state(), Ts=TS, native=native) for native in (True, False))
    times = {k: [] for k in ("controller", "python", "compiled")}
    deviation = 0.0
    for k in range(K):
        X, w = fast.X, ref.window(k * TS, TS, 20)
        t1 = time.perf_counter()
        info = ctl.step(X, w)
        times["controller"].append(time.perf_counter() - t1)
        slow.q, slow.v, slow._T, slow._pinv = fast.q, fast.v, fast._T, fast._pinv
        for plant in ((fast, slow) if k % 2 else (slow, fast)):
            t0 = time.perf_counter()
            plant.step(info.u)
            times["compiled" if plant is fast else "python"].append(time.perf_counter() - t0)
        deviation = max(deviation, float(np.max(np.abs(fast.X - slow.X))))
    print(f"closed loop, {K} samples, median µs: " + ", ".join(f"{k} {1e6 * np.median(v):.0f}" for k, v in times.items())
          + f"; max |X_python − X_compiled| after a sample: {deviation:.1e}")


def loop_split(seconds: float) -> None:
    """``closed_loop_wall_time`` with the plant's steps timed: s per simulated s of each part."""
    from parallel_gpc.bench import closed_loop_wall_time

    spent = []
    step = ConstrainedPlant.step

    def timed_step(self, u, Ts):
        t0 = time.perf_counter()
        out = step(self, u, Ts)
        spent.append(time.perf_counter() - t0)
        return out

    ConstrainedPlant.step = timed_step
    try:
        r = closed_loop_wall_time("planar_4rrr", seconds)
    finally:
        ConstrainedPlant.step = step
    wall, ctl, plant = r["wall_s"], r["controller_s"], float(np.sum(spent))
    print(f"simulate {seconds:g} s at 1 kHz: wall {wall / seconds:.3f} s/s = controller {ctl / seconds:.3f} + plant "
          f"{plant / seconds:.3f} + loop {(wall - ctl - plant) / seconds:.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=400, help="samples per path and repetition")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--robots", nargs="*", default=ROBOTS, help="robots of the plant-step table (none: skip it)")
    parser.add_argument("--closed-loop", type=int, default=0, metavar="K", help="samples of the paired closed loop")
    parser.add_argument("--split", type=float, default=0.0, metavar="S", help="s of simulate with the split timed")
    args = parser.parse_args()
    print("| robot | nv | Python step µs (integrate + project) | compiled step µs (integrate + project) | speed-up |")
    print("|---|---|---|---|---|")
    for name in args.robots:
        r = bench_robot(name, args.samples, args.repeats)
        py, c = r[False], r[True]
        nv = ParallelRobot.load(name).model.nv
        print(f"| {name} | {nv} | {py['step']:.0f} ({py['integrate']:.0f} + {py['project']:.0f}) | "
              f"{c['step']:.0f} ({c['integrate']:.0f} + {c['project']:.0f}) | {py['step'] / c['step']:.2f}× |",
              flush=True)
    if args.closed_loop > 0:
        closed_loop(args.closed_loop)
    if args.split > 0:
        loop_split(args.split)


if __name__ == "__main__":
    main()
