#!/usr/bin/env python3
"""Replay the rollouts a converged NMPC step makes (issue 25), to count instructions per rollout stage.

``python benchmarks/bench_rollout.py record OUT.pkl [--steps 12]``
    Runs bench_nmpc's planar case (planar_4rrr, S-curve, Ts = 2 ms, N = 20, converged GPC nonlinear) for
    ``--steps`` closed-loop samples and records the rollouts the iterations make through the model
    (X0, u (N, m), Ts, offset) in order: the line-search trials (rollouts of the plan moved by a
    Gauss–Newton step), by ``ReducedModel.simulate_linearized`` (the rollout fused with its stage
    Jacobians) or ``simulate_factorized`` (a trial rolled out alone). The paper step's pre-simulation of
    the shifted plan is not among them: the Riccati path makes it inside one compiled call
    (``_native.riccati_presimulated``), which the replay repeats only through its effect on the warm starts.

``python benchmarks/bench_rollout.py replay IN.pkl N``
    Replays the first N recorded calls on a fresh model: the same warm-start history as the closed
    loop. Under callgrind the difference of two replays (N and N + 1 calls) is the instruction count of
    call N alone::

        PARALLEL_GPC_THREADS=1 OPENBLAS_NUM_THREADS=1 valgrind --tool=callgrind \\
            --callgrind-out-file=cg.N.out python benchmarks/bench_rollout.py replay IN.pkl N

``python benchmarks/bench_rollout.py distances IN.pkl``
    For every recorded call after the first: how far (‖Δy‖, m or rad) each rollout stage lies from the
    nearest warm start ``simulate`` may take (the previous call's stage i or i + 1), and how many
    stages are within its 1e-4 radius.

PYTHONPATH=src or the package installed.
"""

from __future__ import annotations

import argparse
import pickle
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
WARM_RADIUS = 1e-4  # ModelUpdate::simulate's (and the Python twin's) warm-start radius in y


def record(out: str, steps: int) -> None:
    """Record the iterations' rollouts of ``steps`` samples of bench_nmpc's planar case."""
    sys.path.insert(0, str(HERE))
    import bench_nmpc as bench
    from parallel_gpc import ParallelRobot, ReducedModel
    from parallel_gpc.gpc.robot_references import reference_for

    robot = ParallelRobot.load("planar_4rrr")
    Ts, N, torque = 0.002, 20, 15.0  # bench_nmpc's planar case
    model = ReducedModel(robot)
    calls, marks = [], []

    def recording(method):
        def recorded(X0, u_seq, Ts_, offset=None, **kwargs):
            calls.append((np.array(X0), np.array(u_seq), Ts_, None if offset is None else np.array(offset)))
            return method(X0, u_seq, Ts_, offset, **kwargs)
        return recorded

    model.simulate_factorized = recording(model.simulate_factorized)
    model.simulate_linearized = recording(model.simulate_linearized)
    step = bench.gpc_method(model, Ts, N, torque, 50)

    def marked(X, w):
        marks.append(len(calls))
        return step(X, w)

    bench.closed_loop(robot, reference_for("s-curve", robot, 1.0), steps * Ts, Ts, N, torque, marked)
    if not calls:
        raise SystemExit(f"no rollout recorded in {steps} steps: the NMPC no longer calls simulate_factorized or "
                         "simulate_linearized on the model")
    with open(out, "wb") as f:
        pickle.dump({"calls": calls, "step_starts": marks}, f)
    print(f"{len(calls)} rollouts in {steps} steps (first call of each step: {marks})")


def load(path: str):
    with open(path, "rb") as f:
        return pickle.load(f)


def replay(path: str, n: int) -> None:
    """The first ``n`` recorded calls on a fresh planar_4rrr model."""
    from parallel_gpc import ParallelRobot, ReducedModel

    model = ReducedModel(ParallelRobot.load("planar_4rrr"))
    for X0, u_seq, Ts, offset in load(path)["calls"][:n]:
        model.simulate_factorized(X0, u_seq, Ts, offset)


def distances(path: str) -> None:
    """Per call: the stages' distances in y to the nearest warm start of the previous call."""
    from parallel_gpc import ParallelRobot, ReducedModel

    rec = load(path)
    starts = set(rec["step_starts"])
    model = ReducedModel(ParallelRobot.load("planar_4rrr"))
    ny, prev = model.n_y, None
    for k, (X0, u_seq, Ts, offset) in enumerate(rec["calls"]):
        Y = model.simulate_factorized(X0, u_seq, Ts, offset)[3][:-1, :ny]
        if prev is not None:
            d = np.array([min(np.linalg.norm(Y[i] - prev[j]) for j in (i, i + 1) if j < len(prev))
                          for i in range(len(Y))])
            kind = "step's 1st trial" if k in starts else "later trial"  # its warm starts: the last step's / trial's
            print(f"call {k:3d} {kind:16s} within {WARM_RADIUS:g}: {int(np.sum(d < WARM_RADIUS)):2d}/{len(d)}  "
                  f"|Δy| median {np.median(d):.2e} max {d.max():.2e}")
        prev = Y


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("out")
    r.add_argument("--steps", type=int, default=12)
    p = sub.add_parser("replay")
    p.add_argument("path")
    p.add_argument("n", type=int)
    d = sub.add_parser("distances")
    d.add_argument("path")
    args = ap.parse_args(argv)
    if args.cmd == "record":
        record(args.out, args.steps)
    elif args.cmd == "replay":
        replay(args.path, args.n)
    else:
        distances(args.path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
