#!/usr/bin/env python3
"""Time the control step without the model update, and record u(k) to compare two source trees.

``python benchmarks/step_replay.py time [--robot planar_4rrr] [--reps 5] [--configs a,b] [--cpu]``
    Each configuration (form, limits, back end) runs 60 closed-loop samples on the full plant from a
    state 0.5 s along the robot's default path (N = 20, Ts = 2 ms, Qy = 1, Qu = 1e-5, torque limit
    τ = half the peak |u| of the unconstrained run before it); the samples are then replayed
    ``--reps`` times with the model update served from a cache of the recorded
    ``discrete`` / ``simulate_factorized`` results. Prints the median step time without the model
    update, and the median of the model update alone (measured apart), so that the two can be
    combined with another model update (a compiled one). ``--cpu`` times with the thread's CPU
    clock instead of the wall clock: on a shared machine it leaves out the time the process waits
    for a core (not the cache misses the other processes cause).

``python benchmarks/step_replay.py record OUT.npz [--limits-from REF.npz] [--solver NAME]``
    u(k) of 60 closed-loop steps from rest for every form × {no limit, torque limit, Δu limit
    (incremental forms)} × {planar_4rrr, hexapod_8ups, delta_3rus}; the limits (half the peak |u|
    and |Δu| of the unconstrained absolute / incremental runs) are taken from REF.npz when given, so
    two source trees meet the same problems; ``--solver`` names the back end of the limited runs.

``python benchmarks/step_replay.py compare A.npz B.npz``
    The largest relative difference max|u_A − u_B| / max|u_A| of every run, and over all runs.

Run with ``OPENBLAS_NUM_THREADS=1`` (and ``taskset -c 1`` on a shared machine); PYTHONPATH=src or the
package installed. See benchmarks/README.md ("The lean step").
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from parallel_gpc.limits import Limits
from parallel_gpc.gpc.controller import FORMS, GPCController
from parallel_gpc.gpc.criterion import Weights
from parallel_gpc.gpc.prediction import Horizons
from parallel_gpc.gpc.references import SCurve, path_for
from parallel_gpc.model.dynamics import ReducedModel
from parallel_gpc.model.plant import ConstrainedPlant
from parallel_gpc.model.robot import ParallelRobot

TS, N, SAMPLES = 0.002, 20, 60
WEIGHTS = Weights(1.0, 1e-5)
RECORD_ROBOTS = ("planar_4rrr", "hexapod_8ups", "delta_3rus")
#: name → (form, limit kinds, solver); "torque" stands for τ, "du" for 0.2 τ.
CONFIGS = {
    "absolute": ("absolute", (), None), "incremental": ("incremental", (), None),
    "nonlinear": ("nonlinear", (), None),
    "absolute +tau": ("absolute", ("torque",), None),
    "incremental +tau": ("incremental", ("torque",), None),
    "nonlinear +tau": ("nonlinear", ("torque",), None),
    "incremental +du": ("incremental", ("du",), None),
    "absolute +tau daqp-direct": ("absolute", ("torque",), "daqp-direct"),
    "absolute +tau bvls": ("absolute", ("torque",), "bvls"),
}


class ReplayModel:
    """A model whose ``discrete`` and ``simulate_factorized`` answers are recorded once from the
    wrapped model, then served from the record (a state not recorded is an error)."""

    def __init__(self, model):
        self.model, self.record, self._cache = model, True, {}
        self.n_x, self.n_y, self.n_u, self.C = model.n_x, model.n_y, model.n_u, model.C

    def _get(self, key, compute):
        if key not in self._cache:
            if not self.record:
                raise KeyError("state not recorded")
            self._cache[key] = compute()
        return self._cache[key]

    def discrete(self, X, Ts):
        return self._get(("d", X.tobytes()), lambda: self.model.discrete(X, Ts))

    def simulate_factorized(self, X0, u_seq, Ts, offset=None):
        key = ("s", X0.tobytes(), np.asarray(u_seq).tobytes(), None if offset is None else offset.tobytes())
        return self._get(key, lambda: self.model.simulate_factorized(X0, u_seq, Ts, offset))


def _robot_and_path(name: str):
    robot = ParallelRobot.load(name)
    return robot, path_for("auto", robot.home_pose, robot.output_angular, SCurve().duration)


def time_steps(robot_name: str, reps: int, names, clock=time.perf_counter) -> None:
    """Print, per configuration, the median step time without the model update (µs)."""
    robot, ref = _robot_and_path(robot_name)
    start = round(0.5 / TS)
    ctl = GPCController.build(ReducedModel(robot), TS, Horizons(N), WEIGHTS)
    plant = ConstrainedPlant(robot, ref.initial_state(), Ts=TS)
    us = []
    for k in range(start):
        us.append(ctl.step(plant.X, ref.window(k * TS, TS, N)).u)
        plant.step(us[-1])
    tau = 0.5 * np.max(np.abs(us), axis=0)
    X0 = plant.X.copy()
    for name in names:
        form, kinds, solver = CONFIGS[name]
        limits = Limits(**{kind: tau if kind == "torque" else 0.2 * tau for kind in kinds})
        model = ReplayModel(ReducedModel(robot))
        ctl = GPCController.build(model, TS, Horizons(N), WEIGHTS, form=form, solver=solver, limits=limits, u0=us[-1])
        plant = ConstrainedPlant(robot, X0, Ts=TS)
        rows = []
        for k in range(SAMPLES):
            X, w = plant.X, ref.window((start + k) * TS, TS, N)
            rows.append((X, w, ctl.state))
            plant.step(ctl.step(X, w).u)
        model.record = False
        times = []
        for _ in range(reps):
            for X, w, snap in rows:
                ctl.restore(snap)
                t0 = clock()
                ctl.step(X, w)
                times.append(clock() - t0)
        update = []
        for X, _, _ in rows[:20]:
            t0 = clock()
            if form == "nonlinear":
                model.model.simulate_factorized(X, np.tile(us[-1], (N, 1)), TS)
            else:
                model.model.discrete(X, TS)
            update.append(clock() - t0)
        print(f"{robot_name:12s} {name:28s} step without model update {np.median(times) * 1e6:7.1f} µs   "
              f"model update alone {np.median(update) * 1e6:7.1f} µs", flush=True)


def _closed_loop_inputs(robot, ref, form: str, solver: str | None, tau=None, delta=None) -> np.ndarray:
    """(SAMPLES, m) u(k) of a closed loop from the path's initial state (N·m)."""
    limited = tau is not None or delta is not None
    ctl = GPCController.build(ReducedModel(robot), TS, Horizons(N), WEIGHTS, form=form,
                              solver=solver if limited else None, limits=Limits(torque=tau, du=delta))
    plant = ConstrainedPlant(robot, ref.initial_state(), Ts=TS)
    u = []
    for k in range(SAMPLES):
        u.append(ctl.step(plant.X, ref.window(k * TS, TS, N)).u)
        plant.step(u[-1])
    return np.array(u)


def record_inputs(out: str, limits_from: str | None, solver: str | None) -> None:
    """Write u(k) of every run (and the limits used) to ``out`` (.npz)."""
    given = dict(np.load(limits_from)) if limits_from else None
    runs = {}
    for name in RECORD_ROBOTS:
        robot, ref = _robot_and_path(name)
        if given:
            tau, delta = given[f"limits/{name}/tau"], given[f"limits/{name}/delta"]
        else:
            tau = 0.5 * np.max(np.abs(_closed_loop_inputs(robot, ref, "absolute", solver)), axis=0)
            delta = 0.5 * np.max(np.abs(np.diff(_closed_loop_inputs(robot, ref, "incremental", solver), axis=0)), axis=0)
        runs[f"limits/{name}/tau"], runs[f"limits/{name}/delta"] = tau, delta
        for form in FORMS:
            cases = {"none": (None, None), "torque": (tau, None)}
            if form != "absolute":
                cases["du"] = (None, delta)
            for case, (t, d) in cases.items():
                runs[f"{name}/{form}/{case}"] = _closed_loop_inputs(robot, ref, form, solver, t, d)
    np.savez(out, **runs)


def compare(a: str, b: str) -> float:
    """Print max|u_a − u_b| / max|u_a| per run; return the largest."""
    A, B = np.load(a), np.load(b)
    worst = 0.0
    for key in A.files:
        if key.startswith("limits/"):
            continue
        rel = float(np.max(np.abs(A[key] - B[key])) / max(float(np.max(np.abs(A[key]))), 1e-300))
        worst = max(worst, rel)
        print(f"{key:45s} {rel:.2e}")
    print(f"largest relative difference {worst:.2e}")
    return worst


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    t = sub.add_parser("time")
    t.add_argument("--robot", default="planar_4rrr")
    t.add_argument("--reps", type=int, default=5)
    t.add_argument("--configs", default=",".join(CONFIGS), help=f"comma-separated, of {list(CONFIGS)}")
    t.add_argument("--cpu", action="store_true", help="the thread's CPU clock instead of the wall clock")
    r = sub.add_parser("record")
    r.add_argument("out")
    r.add_argument("--limits-from", default=None)
    r.add_argument("--solver", default=None)
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    args = p.parse_args()
    if args.command == "time":
        time_steps(args.robot, args.reps, [s.strip() for s in args.configs.split(",")],
                   time.thread_time if args.cpu else time.perf_counter)
    elif args.command == "record":
        record_inputs(args.out, args.limits_from, args.solver)
    else:
        compare(args.a, args.b)


if __name__ == "__main__":
    main()
