#!/usr/bin/env python3
"""Converged NMPC (the nonlinear form iterated, ``GPCSettings.iterations``) against the paper's
single step and CasADi (SQP, IPOPT) in one closed-loop run.

The move: the Delta robot (``delta_3rus``) from home to 85 % of the reach along a horizontal ray
(near the workspace edge, :func:`~parallel_gpc.gpc.robot_references.ray_reach`) in ``--move`` s
(quintic), held for 40 ms; Ts, N as given; Qy = 1, Qu = 1e-3 (square root, on Δu over the
shifted previous plan); a symmetric torque limit. The plant is the full constrained model
(Pinocchio ``constraintDynamics``). Every method plans the same discrete problem
(:mod:`parallel_gpc.gpc.nmpc`); CasADi gets it through tests/nmpc_oracle.py (the ZOH map as an
external callback with its own finite-difference Jacobian, limited-memory Hessian): its times
include the Python callback, unlike a hand-written symbolic model.

Usage: ``python benchmarks/bench_nmpc.py [--quick] [--no-casadi] [--out DIR]``. Prints a table
and writes DIR/bench_nmpc.json (default DIR: benchmarks/results).
"""

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"  # before numpy loads

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from parallel_gpc import ConstrainedPlant, GPCController, Horizons, ParallelRobot, ReducedModel, Weights  # noqa: E402
from parallel_gpc.gpc.controller import LIMIT_MARGIN  # noqa: E402
from parallel_gpc.gpc.references import SampledTrajectory, quintic_array  # noqa: E402
from parallel_gpc.gpc.robot_references import ray_reach  # noqa: E402
from parallel_gpc.limits import Limits  # noqa: E402

QY, QU = 1.0, 1e-3
HERE = Path(__file__).resolve().parent


def delta_move(robot, move: float, hold: float = 0.04):
    """The fast large move of the Delta robot toward its workspace edge, as a sampled trajectory."""
    direction = np.array([1.0, 0.0, 0.0])
    reach = ray_reach(robot, [0, 1, 2], direction, 0.5, 1e3)
    t = np.linspace(0.0, move + hold, 400)
    s = quintic_array(np.clip(t / move, 0.0, 1.0))
    return SampledTrajectory(t, robot.home_pose + np.outer(s, 0.85 * reach * direction)), reach


def gpc_method(model, Ts, N, torque, iterations, tolerance=1e-8):
    ctrl = GPCController.build(model, Ts, Horizons(N), Weights(QY, QU), form="nonlinear", iterations=iterations,
                               tolerance=tolerance, limits=Limits(torque=torque), disturbance_gain=0.0)  # as CasADi

    def step(X, w):
        info = ctrl.step(X, w)
        return info.u, info.iterations
    return step


def casadi_method(model, Ts, N, torque, method, max_iter):
    sys.path.insert(0, str(HERE.parent / "tests"))
    from nmpc_oracle import ipopt_plan
    m = model.n_u
    state = {"plan": np.zeros((N, m))}

    def step(X, w):
        plan = state["plan"]
        u0 = np.vstack([plan[1:], plan[-1:]])
        v, _, _, iters = ipopt_plan(model, Ts, X, u0, w, QY, QU, N, torque=torque * (1 - LIMIT_MARGIN),
                                    method=method, max_iter=max_iter, tol=1e-8)
        state["plan"] = u0 + np.cumsum(v.reshape(N, m), axis=0)
        return state["plan"][0].copy(), iters
    return step


def closed_loop(robot, ref, duration, Ts, N, torque, step):
    X = np.concatenate([ref.pose(0.0), np.zeros(robot.n_y)])
    plant = ConstrainedPlant(robot, X, Ts=Ts, torque_limit=Limits(torque=torque))
    K = int(round(duration / Ts))
    times, errors, peaks, iters = [], [], [], []
    for k in range(K):
        w = ref.sample(k * Ts + Ts * np.arange(1, N + 1))
        t0 = time.perf_counter()
        try:
            u, it = step(plant.X, w)
        except Exception as exc:  # a method that fails (e.g. a trial step outside the workspace) is reported
            return {"failed": f"step {k}: {type(exc).__name__}: {' '.join(str(exc).split())[:160]}", "steps": k}
        times.append(time.perf_counter() - t0)
        X = plant.step(u)
        errors.append(float(np.linalg.norm(X[:3] - ref.pose((k + 1) * Ts))))
        peaks.append(float(np.max(np.abs(u))))
        iters.append(it)
    e = np.array(errors)
    return {"mean_step_ms": 1e3 * float(np.mean(times)), "median_step_ms": 1e3 * float(np.median(times)),
            "rms_error_mm": 1e3 * float(np.sqrt(np.mean(e ** 2))), "max_error_mm": 1e3 * float(e.max()),
            "peak_torque_Nm": float(max(peaks)), "mean_iterations": float(np.mean(iters)), "steps": K}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="Ts = 5 ms, N = 10 (about a minute with CasADi)")
    ap.add_argument("--no-casadi", action="store_true", help="only the GPC iterations")
    ap.add_argument("--move", type=float, default=0.12, help="duration of the move in s (default 0.12)")
    ap.add_argument("--torque", type=float, default=None, help="torque limit in N·m (default: 1.2 × the peak of "
                                                                 "the converged run without limit, so that it binds)")
    ap.add_argument("--out", default=str(HERE / "results"))
    args = ap.parse_args(argv)
    Ts, N = (0.005, 10) if args.quick else (0.002, 20)
    robot = ParallelRobot.load("delta_3rus")
    ref, reach = delta_move(robot, args.move)
    duration = args.move + 0.04
    torque = args.torque
    if torque is None:  # a limit that binds: 80 % of the converged run's peak without one
        free = closed_loop(robot, ref, duration, Ts, N, 1e6, gpc_method(ReducedModel(robot), Ts, N, 1e6, 50))
        torque = 0.8 * free["peak_torque_Nm"]
    methods = {f"GPC nonlinear, {n} iteration{'s' if n > 1 else ''}": (gpc_method, n) for n in (1, 2, 3)}
    methods["GPC nonlinear, converged (tol 1e-8)"] = (gpc_method, 50)
    if not args.no_casadi:
        methods.update({"CasADi SQP, 1 iteration": (casadi_method, ("sqpmethod", 1)),
                        "CasADi SQP, converged": (casadi_method, ("sqpmethod", None)),
                        "CasADi IPOPT": (casadi_method, ("ipopt", None))})
    rows = {}
    for name, (make, arg) in methods.items():
        model = ReducedModel(robot)
        step = make(model, Ts, N, torque, arg) if make is gpc_method else make(model, Ts, N, torque, *arg)
        rows[name] = closed_loop(robot, ref, duration, Ts, N, torque, step)
        print(f"{name:40s} " + "  ".join(f"{k} {v:.4g}" if not isinstance(v, str) else f"{k}: {v}"
                                          for k, v in rows[name].items()), flush=True)
    meta = {"robot": "delta_3rus", "Ts": Ts, "N": N, "move_s": args.move, "distance_m": 0.85 * reach,
            "torque_limit_Nm": torque, "Qy": QY, "Qu": QU}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_nmpc.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    print(json.dumps(meta))
    return 0


if __name__ == "__main__":
    sys.exit(main())
