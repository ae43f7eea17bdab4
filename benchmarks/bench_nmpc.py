#!/usr/bin/env python3
"""Converged NMPC (the nonlinear form iterated, ``GPCSettings.iterations``) against the paper's
single step and CasADi (SQP, IPOPT) in one closed-loop run.

Two cases. **planar** (the speed target of issue 25): planar_4rrr on the paper's S-curve, Ts = 2 ms,
N = 20, torque limit 15 N·m, the first ``--steps`` samples; the table gives each method's ratio to
IPOPT's mean step and the target line (converged ≤ 5 ms per step, ≥ 300× IPOPT). **delta** (where
the iterations must pay off): the Delta robot (``delta_3rus``) from home to 85 % of the reach along a horizontal ray
(near the workspace edge, :func:`~parallel_gpc.gpc.robot_references.ray_reach`) in ``--move`` s
(quintic), held for 40 ms; Ts, N as given; Qy = 1, Qu = 1e-3 (square root, on Δu over the
shifted previous plan); a symmetric torque limit. The plant is the full constrained model
(Pinocchio ``constraintDynamics``). Every method plans the same discrete problem
(:mod:`parallel_gpc.gpc.nmpc`); CasADi gets it through tests/nmpc_oracle.py (the ZOH map as an
external callback with its own finite-difference Jacobian, limited-memory Hessian): its times
include the Python callback, unlike a hand-written symbolic model.

Rows: "1 iteration" is the paper's step (``iterations=1``); "2"/"3 iterations" add one/two exact
Gauss–Newton steps with their line search; "converged" iterates to the step tolerance (on the
planar case three solves: the paper's and two exact ones, the last only to verify the stop).

Usage: ``python benchmarks/bench_nmpc.py [--case planar|delta|both] [--quick] [--no-casadi] [--out DIR]``.
Prints a table per case and writes DIR/bench_nmpc.json (default DIR: benchmarks/results).
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
from parallel_gpc.gpc.robot_references import ray_reach, reference_for  # noqa: E402
from parallel_gpc.limits import Limits  # noqa: E402
from parallel_gpc.model import native_update  # noqa: E402

QY, QU = 1.0, 1e-3
HERE = Path(__file__).resolve().parent


def delta_move(robot, move: float, hold: float = 0.04):
    """The fast large move of the Delta robot toward its workspace edge, as a sampled trajectory."""
    direction = np.array([1.0, 0.0, 0.0])
    reach = ray_reach(robot, [0, 1, 2], direction, 0.5, 1e3)
    t = np.linspace(0.0, move + hold, 400)
    s = quintic_array(np.clip(t / move, 0.0, 1.0))
    return SampledTrajectory(t, robot.home_pose + np.outer(s, 0.85 * reach * direction)), reach


def model_with(robot, threads: int, Ts: float = 0.002) -> ReducedModel:
    """A model whose compiled update runs its stage loop on `threads` threads (built now, at one ZOH of Ts s; the
    process's setting, ``PARALLEL_GPC_THREADS`` or its default, is back in force for the next models)."""
    before = os.environ.get(native_update.THREADS_ENV)
    os.environ[native_update.THREADS_ENV] = str(threads)
    native_update.compiled_threads.cache_clear()
    try:
        model = ReducedModel(robot)
        model.discrete(np.r_[robot.home_pose, np.zeros(robot.n_y)], Ts)
    finally:
        if before is None:
            del os.environ[native_update.THREADS_ENV]
        else:
            os.environ[native_update.THREADS_ENV] = before
        native_update.compiled_threads.cache_clear()
    return model


def arithmetic_floor(robot, Ts, N, solves: float, reps: int = 15) -> dict:
    """The least wall time a converged step can take on this machine: the rollouts and stage Jacobians it
    cannot do without, at their one-thread CPU time, shared perfectly by the cores the compiled stage loop may
    use (``PARALLEL_GPC_THREADS``' default, min(2, cores)); the solves, the Python around them and every
    thread's overhead not counted. A step of ``solves`` solves (the paper's, then exact Gauss–Newton steps; the
    last verifies) rolls out ``solves`` plans (the pre-simulation and each accepted trial, N stages) and
    linearizes ``solves`` − 1 of them (N − 1 stages). Rollout and Jacobians timed on a one-thread model,
    medians of ``reps`` interleaved calls (process CPU, s), two plans 0.1 % apart in turn (the same plan again
    would reuse the rollout's factorizations). Returns the times in ms and the floor."""
    model = model_with(robot, 1, Ts)
    threads = native_update.compiled_threads()  # what the converged runs used
    X = np.r_[robot.home_pose, np.zeros(robot.n_y)]
    plans = [np.full((N, model.n_u), 0.1), np.full((N, model.n_u), 0.1001)]
    roll, jac = [], []
    for k in range(reps):
        t = time.process_time()
        Xs = model.simulate_factorized(X, plans[k % 2], Ts)[3]
        roll.append(time.process_time() - t)
        t = time.process_time()
        model.stage_jacobians(Xs, plans[k % 2], Ts, start=1)
        jac.append(time.process_time() - t)
    r, j = 1e3 * float(np.median(roll)), 1e3 * float(np.median(jac))
    return {"rollout_ms": r, "jacobians_ms": j, "solves": solves, "cores": threads,
            "floor_ms": (solves * r + (solves - 1.0) * j) / threads}


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
    ny = robot.n_y
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
        errors.append(float(np.linalg.norm(X[:ny] - ref.pose((k + 1) * Ts))))
        peaks.append(float(np.max(np.abs(u))))
        iters.append(it)
    e = np.array(errors)
    return {"mean_step_ms": 1e3 * float(np.mean(times)), "median_step_ms": 1e3 * float(np.median(times)),
            "rms_error_mm": 1e3 * float(np.sqrt(np.mean(e ** 2))), "max_error_mm": 1e3 * float(e.max()),
            "peak_torque_Nm": float(max(peaks)), "mean_iterations": float(np.mean(iters)), "steps": K}


TARGET_MS, TARGET_RATIO = 5.0, 300.0  # issue 25: converged NMPC on planar_4rrr at N = 20
CONVERGED = "GPC nonlinear, converged (tol 1e-8)"
IPOPT = "CasADi IPOPT"


def run_case(name, robot, ref, duration, Ts, N, torque, casadi: bool, sqp: bool) -> dict:
    """One closed loop per method on one case; prints each row as it ends and the ratio to IPOPT."""
    methods = {f"GPC nonlinear, {n} iteration{'s' if n > 1 else ''}": (gpc_method, n) for n in (1, 2, 3)}
    methods[CONVERGED] = (gpc_method, 50)
    if casadi:
        if sqp:
            methods.update({"CasADi SQP, 1 iteration": (casadi_method, ("sqpmethod", 1)),
                            "CasADi SQP, converged": (casadi_method, ("sqpmethod", None))})
        methods[IPOPT] = (casadi_method, ("ipopt", None))
    rows = {}
    print(f"-- {name}: {robot.name}, Ts = {Ts * 1e3:g} ms, N = {N}, torque limit {torque:.4g} N·m, "
          f"{int(round(duration / Ts))} steps", flush=True)
    for label, (make, arg) in methods.items():
        model = ReducedModel(robot)
        step = make(model, Ts, N, torque, arg) if make is gpc_method else make(model, Ts, N, torque, *arg)
        rows[label] = closed_loop(robot, ref, duration, Ts, N, torque, step)
        print(f"{label:40s} " + "  ".join(f"{k} {v:.4g}" if not isinstance(v, str) else f"{k}: {v}"
                                           for k, v in rows[label].items()), flush=True)
    ipopt_ms = rows.get(IPOPT, {}).get("mean_step_ms")
    if ipopt_ms is not None:
        for label, row in rows.items():
            if "mean_step_ms" in row:
                row["ipopt_ratio"] = ipopt_ms / row["mean_step_ms"]
                print(f"{label:40s} {row['mean_step_ms']:9.3f} ms per step  {row['ipopt_ratio']:9.1f}× faster than "
                      "IPOPT")
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=("planar", "delta", "both"), default="both")
    ap.add_argument("--quick", action="store_true", help="delta: Ts = 5 ms, N = 10 (about a minute with CasADi); "
                                                         "planar: 10 steps")
    ap.add_argument("--no-casadi", action="store_true", help="only the GPC iterations")
    ap.add_argument("--steps", type=int, default=None, help="planar: samples of the S-curve (default 25 with CasADi, "
                                                            "150 without; IPOPT takes seconds per step)")
    ap.add_argument("--move", type=float, default=0.12, help="delta: duration of the move in s (default 0.12)")
    ap.add_argument("--torque", type=float, default=None, help="delta: torque limit in N·m (default: 0.8 × the peak "
                                                                 "of the converged run without limit, so that it binds)")
    ap.add_argument("--out", default=str(HERE / "results"))
    args = ap.parse_args(argv)
    out_json = {}
    if args.case in ("planar", "both"):
        robot = ParallelRobot.load("planar_4rrr")
        Ts, N, torque = 0.002, 20, 15.0
        steps = args.steps or (10 if args.quick else 25 if not args.no_casadi else 150)
        rows = run_case("planar", robot, reference_for("s-curve", robot, 1.0), steps * Ts, Ts, N, torque,
                        not args.no_casadi, sqp=False)
        conv = rows[CONVERGED]
        line = (f"target: converged NMPC on planar_4rrr at N = {N}: {conv['mean_step_ms']:.2f} ms mean, "
                f"{conv['median_step_ms']:.2f} ms median per step (≤ {TARGET_MS:g} ms: "
                f"{'met' if conv['median_step_ms'] <= TARGET_MS else 'missed'})")
        if "ipopt_ratio" in conv:
            line += (f"; {conv['ipopt_ratio']:.0f}× IPOPT (≥ {TARGET_RATIO:g}×: "
                     f"{'met' if conv['ipopt_ratio'] >= TARGET_RATIO else 'missed'})")
        print(line, flush=True)
        if "mean_iterations" in conv and native_update.use_native():  # the compiled core's arithmetic
            floor = conv["floor"] = arithmetic_floor(robot, Ts, N, conv["mean_iterations"])
            text = (f"arithmetic floor of the converged step: {floor['solves']:.2f} rollouts of {N} stages "
                    f"({floor['rollout_ms']:.3f} ms each) and {floor['solves'] - 1:.2f} sets of {N - 1} stage "
                    f"Jacobians ({floor['jacobians_ms']:.3f} ms each), one-thread CPU, over {floor['cores']} "
                    f"core{'s' if floor['cores'] > 1 else ''}: {floor['floor_ms']:.3f} ms")
            if "mean_step_ms" in rows.get(IPOPT, {}):
                floor["ipopt_ratio"] = rows[IPOPT]["mean_step_ms"] / floor["floor_ms"]
                text += f", i.e. at most {floor['ipopt_ratio']:.0f}× IPOPT"
            print(text + " (the solves and the Python around them not counted)", flush=True)
        out_json["planar"] = {"meta": {"robot": "planar_4rrr", "reference": "s-curve", "Ts": Ts, "N": N, "steps": steps,
                                       "torque_limit_Nm": torque, "Qy": QY, "Qu": QU}, "rows": rows, "target": line}
    if args.case in ("delta", "both"):
        Ts, N = (0.005, 10) if args.quick else (0.002, 20)
        robot = ParallelRobot.load("delta_3rus")
        ref, reach = delta_move(robot, args.move)
        duration = args.move + 0.04
        torque = args.torque
        if torque is None:  # a limit that binds: 80 % of the converged run's peak without one
            free = closed_loop(robot, ref, duration, Ts, N, 1e6, gpc_method(ReducedModel(robot), Ts, N, 1e6, 50))
            torque = 0.8 * free["peak_torque_Nm"]
        rows = run_case("delta", robot, ref, duration, Ts, N, torque, not args.no_casadi, sqp=True)
        meta = {"robot": "delta_3rus", "Ts": Ts, "N": N, "move_s": args.move, "distance_m": 0.85 * reach,
                "torque_limit_Nm": torque, "Qy": QY, "Qu": QU}
        out_json["delta"] = {"meta": meta, "rows": rows}
        print(json.dumps(meta))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_nmpc.json").write_text(json.dumps(out_json, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
