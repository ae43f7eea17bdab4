#!/usr/bin/env python3
"""The compiled stage Jacobians on 1 and 2 threads (``PARALLEL_GPC_THREADS``, docs/performance.md#threads),
interleaved in one process so that both see the same machine: ``ReducedModel.stage_jacobians`` of 19 stages
(planar_4rrr, delta_3rus; blocks of 20 calls), the rollout of 20 stages and its Jacobians as two calls and as one
(``simulate_linearized``: the Jacobians on the second thread during the rollout), then the converged NMPC step of
bench_nmpc's planar case
(planar_4rrr, N = 20, Ts = 2 ms, S-curve, torque limit 15 N·m), two closed loops in lockstep, one per thread
count. Medians of wall (perf_counter) and CPU time (process_time: every thread of the process).

    python benchmarks/bench_threads.py [--rounds 10] [--steps 25] [--no-adapt]

``--no-adapt``: the helper runs even where the machine has no free core for it (by default a call runs on
one thread then).
"""

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"  # before numpy loads

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from bench_nmpc import gpc_method, model_with  # noqa: E402
from parallel_gpc import ConstrainedPlant, ParallelRobot  # noqa: E402
from parallel_gpc.gpc.robot_references import reference_for  # noqa: E402
from parallel_gpc.limits import Limits  # noqa: E402
from parallel_gpc.model import native_update  # noqa: E402
from parallel_gpc.model.native import native_module  # noqa: E402

TS, N, TORQUE = 0.002, 20, 15.0


def timed(f) -> tuple[float, float]:
    t, c = time.perf_counter(), time.process_time()
    f()
    return time.perf_counter() - t, time.process_time() - c


def line(label: str, samples) -> str:
    a = 1e3 * np.asarray(samples)
    return f"{label}: wall median {np.median(a[:, 0]):.3f} ms, CPU median {np.median(a[:, 1]):.3f} ms"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=10)
    ap.add_argument("--steps", type=int, default=25)
    ap.add_argument("--no-adapt", action="store_true")
    args = ap.parse_args(argv)
    module = native_module()
    if not hasattr(module, "adapt_threads"):
        print("the compiled core has no threaded stage loop (not built, PARALLEL_GPC_NATIVE=0 or an older build)")
        return 1
    module.adapt_threads(not args.no_adapt)
    print(f"load {os.getloadavg()[0]:.1f}, {native_update.available_cores()} cores", flush=True)
    for name in ("planar_4rrr", "delta_3rus"):
        robot = ParallelRobot.load(name)
        if name == "planar_4rrr":
            X, u = np.array([0.5, 0.4, 0.1, 0.8, -0.5, 1.0]), np.tile([1.0, -1.0, 0.5, 0.2], (20, 1))
        else:
            X = np.concatenate([robot.home_pose + [0.02, -0.01, 0.03], [0.4, -0.3, 0.5]])
            u = np.tile([0.5, -0.3, 0.2], (20, 1))
        models = {n: model_with(robot, n) for n in (1, 2)}
        trajs = {n: m.simulate_factorized(X, u, TS)[3] for n, m in models.items()}
        res = {1: [], 2: []}
        for _ in range(args.rounds):
            for n, m in models.items():
                w, c = timed(lambda: [m.stage_jacobians(trajs[n], u, TS, start=1) for _ in range(20)])
                res[n].append((w / 20, c / 20))
        for n in (1, 2):
            print(line(f"{name} stage_jacobians, 19 stages, {n} thread{'s' if n > 1 else ''}", res[n]), flush=True)
        # the rollout and its Jacobians: two calls vs the fused one (Jacobians during the rollout), interleaved;
        # two plans 0.1 % apart in turn, as a line search's trials (the same plan again would reuse every
        # factorization of the rollout before)
        plans = [u, u * 1.001]
        fused = {(n, f): [] for n in (1, 2) for f in (False, True)}
        for _ in range(args.rounds):
            for (n, f), samples in fused.items():
                m = models[n]
                call = (lambda p: m.simulate_linearized(X, p, TS, None, start=1)) if f else \
                    (lambda p: m.stage_jacobians(m.simulate_factorized(X, p, TS)[3], p, TS, start=1))
                w, c = timed(lambda: [call(plans[j % 2]) for j in range(20)])
                samples.append((w / 20, c / 20))
        for (n, f), samples in fused.items():
            what = "simulate_linearized" if f else "simulate_factorized + stage_jacobians"
            print(line(f"{name} {what}, 20 stages, {n} thread{'s' if n > 1 else ''}", samples), flush=True)
    robot = ParallelRobot.load("planar_4rrr")
    ref = reference_for("s-curve", robot, 1.0)
    loops = {n: (gpc_method(model_with(robot, n), TS, N, TORQUE, 50),
                 ConstrainedPlant(robot, np.concatenate([ref.pose(0.0), np.zeros(robot.n_y)]), Ts=TS,
                                  torque_limit=Limits(torque=TORQUE))) for n in (1, 2)}
    res = {1: [], 2: []}
    for k in range(args.steps):
        w = ref.sample(k * TS + TS * np.arange(1, N + 1))
        for n, (step, plant) in loops.items():
            out = {}
            res[n].append(timed(lambda: out.update(r=step(plant.X, w))))
            plant.step(out["r"][0])
    for n in (1, 2):
        print(line(f"converged NMPC planar N = {N}, {args.steps} steps, {n} thread{'s' if n > 1 else ''}", res[n]))
    print(f"load {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
