#!/usr/bin/env python3
"""Time the absolute and incremental steps with ``solver="riccati"`` against ``"qr"``.

``python benchmarks/bench_riccati.py [--reps 7] [--samples 60] [--cases planar_4rrr:10,planar_4rrr:20,...]``
``python benchmarks/bench_riccati.py --limited [--horizons 20,40,80,160] [--robot planar_4rrr] [--forms absolute,nonlinear] [--cpu] [--closed-loop]``
``python benchmarks/bench_riccati.py --trace incremental:160 [--samples 12] [--reps 1] [--closed-loop] [--robot planar_4rrr]``
``valgrind --tool=callgrind python benchmarks/bench_riccati.py --count incremental:80 --steps K [--samples 12] [--free]``

For every case (robot, N) the states of a 0.5 s closed loop along the robot's default path (qr,
absolute form, on the full plant) are recorded; then every configuration steps through the same
states and reference windows, interleaved (one pass of each configuration per repetition, the
controller reset before each pass): the reference-Python step (``ReducedModel(robot,
native=False)`` + qr, today's pure-Python path), and {absolute, incremental} × {qr, riccati} with
the compiled model update. Ts = 2 ms, No = 0, Nu = N, Qy = 1, Qu = 1e-5. Prints the median step
(µs, the whole ``GPCController.step``) and its ratio to the same form's reference-Python step.

Run with ``OPENBLAS_NUM_THREADS=1 taskset -c 1`` and PYTHONPATH=src (the compiled core built).
``--cpu`` times ``--limited`` steps by this process's CPU time (``time.process_time``) instead of the
wall clock: on a machine shared with other work, the time the step itself used. ``--closed-loop``
steps every ``--limited`` configuration through its own closed loop on the full plant (from the
reference's initial state; the plant is not timed) instead of the recorded states: the delayed form
applies the u(k) it decided at k − 1, and on states that do not follow its inputs its plan swings from
step to step (planar_4rrr, N = 160: every other step's active set far from the one before).
``--count form:N --steps K``: for instruction counts (the machine's load does not change them): the
states recorded as for ``--limited`` (``--samples`` of them), τ as there, then only the limited step
(``--free``: the unconstrained one) on the first K states, the active set's sweeps per step printed.
The instructions of a warm step: (Ir at K = samples − Ir at K = 3) / (samples − 3), with
``PYTHONHASHSEED=0 PARALLEL_GPC_THREADS=1 OPENBLAS_NUM_THREADS=1`` (both runs do the same work but those steps).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from parallel_gpc.gpc.controller import GPCController
from parallel_gpc.gpc.criterion import Weights
from parallel_gpc.gpc.prediction import Horizons
from parallel_gpc.gpc.references import SCurve, path_for
from parallel_gpc.gpc.settings import condensed_default
from parallel_gpc.limits import Limits
from parallel_gpc.model.dynamics import ReducedModel
from parallel_gpc.model.plant import ConstrainedPlant
from parallel_gpc.model.robot import ParallelRobot

from closed_loop import closed_loop_steps, interleaved_loops

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


def run_limited(name: str, horizons: list[int], reps: int, samples: int, forms: list[str],
                clock=time.perf_counter, closed_loop: bool = False) -> None:
    """``--limited``: the torque-limited step (τ = half the unconstrained run's largest |u|) with
    ``solver="riccati"`` (the stage-wise active set; the interior point when its set does not
    settle) against the condensed default of the form (:func:`condensed_default`: what ``solver=None``
    resolves to without the stage-wise path), and against the unconstrained Riccati step
    of the same form; per N, then the fitted exponent of the step time in N. Also the active
    set's sweeps per step (the first step of a pass cold, the others warm) and how many steps
    went to the interior point. ``clock``: what times a step (s; the wall clock, or ``time.process_time``).
    The limited and unconstrained stage-wise steps take turns, one state (one sample) at a time, each with its own
    history: a burst of machine noise falls on both, not on one configuration's whole pass (round 18; before, one
    pass per configuration: a burst of a few tens of ms could double one median of their ratio).
    ``closed_loop``: every configuration in its own closed loop on the plant (τ from the unconstrained
    one's), not on the recorded states. The printed max|Δu|/τ compares the applied inputs of the limited stage-wise
    and condensed runs, each with its own history (u(k−1), warm starts; in closed loop its own states): the
    incremental forms' histories part ways on ill-conditioned steps (incremental-delayed N = 160, Qu = 1e-5: 0.12 on
    the recorded states, 2.0 in closed loop while the inputs ring between the limits), while from the same controller
    state both solve each step alike (0 at every one of 60 recorded steps: restore one from the other's state, round 11)."""
    robot = ParallelRobot.load(name)
    ref = path_for("auto", robot.home_pose, robot.output_angular, SCurve().duration)
    model = ReducedModel(robot)
    rows = {}
    for N in horizons:
        Xs, ws = (None, None) if closed_loop else _states(robot, ref, N, samples)
        for form in forms:
            free = GPCController.build(model, TS, Horizons(N), WEIGHTS, form=form, solver="riccati")
            if closed_loop:
                tau = 0.5 * np.abs(closed_loop_steps(robot, ref, free, N, samples, clock, TS)[1]).max()
            else:
                tau = 0.5 * max(np.abs(free.step(X, w).u).max() for X, w in zip(Xs, ws))
            configs = {"unconstrained riccati": free}
            limits = Limits(torque=tau)
            for key, solver in (("riccati", "riccati"), ("condensed", condensed_default(form, limits))):
                configs[f"limited {key}"] = GPCController.build(model, TS, Horizons(N), WEIGHTS, form=form,
                                                                solver=solver, limits=limits)
            times = {key: [] for key in configs}
            us = {key: [] for key in configs}
            sweeps, ipm = {"cold": [], "warm": []}, 0
            def count(k, ctl):
                nonlocal ipm
                stagewise = ctl._riccati.constrained
                sweeps["warm" if k else "cold"].append(stagewise.iterations[0])
                ipm += stagewise.method != "active-set"

            # the two stage-wise configurations interleaved step by step (their ratio is the target), the condensed
            # one on its own (its N = 160 steps of ~0.1 s would leave both of theirs to a cold cache)
            groups = [{key: configs[key] for key in ("limited riccati", "unconstrained riccati")},
                      {"limited condensed": configs["limited condensed"]}]
            for _ in range(reps):
                for group in groups:
                    if closed_loop:
                        runs = interleaved_loops(robot, ref, group, N, samples, clock, TS,
                                                 lambda key, k, ctl: count(k, ctl) if key == "limited riccati" else None)
                        for key, (t, u) in runs.items():
                            times[key] += t
                            us[key] = u
                        continue
                    for key, ctl in group.items():
                        ctl.reset()
                        us[key] = []
                    for k, (X, w) in enumerate(zip(Xs, ws)):
                        for key, ctl in group.items():
                            t0 = clock()
                            info = ctl.step(X, w)
                            times[key].append(clock() - t0)
                            us[key].append(info.u)
                            if key == "limited riccati":
                                count(k, ctl)
            med = {key: 1e6 * float(np.median(t)) for key, t in times.items()}
            lim, dflt = np.array(us["limited riccati"]), np.array(us["limited condensed"])
            rows[(form, N)] = med
            how = f"{'CPU' if clock is time.process_time else 'wall'}{', closed loop' if closed_loop else ''}"
            print(f"{name} {form:11s} N = {N:3d} ({how}): limited riccati {med['limited riccati']:9.1f} µs, limited condensed "
                  f"({configs['limited condensed'].solver}) {med['limited condensed']:8.1f} µs, unconstrained riccati "
                  f"{med['unconstrained riccati']:7.1f} µs; limited/unconstrained "
                  f"{med['limited riccati'] / med['unconstrained riccati']:5.2f}, condensed/riccati "
                  f"{med['limited condensed'] / med['limited riccati']:5.2f}; max|Δu|/τ {np.abs(lim - dflt).max() / tau:.1e}; "
                  f"sweeps cold {np.mean(sweeps['cold']):.1f} warm {np.mean(sweeps['warm']):.2f}, "
                  f"{ipm}/{len(sweeps['cold']) + len(sweeps['warm'])} steps by the interior point")
    for form in forms:
        for key in ("limited riccati", "limited condensed", "unconstrained riccati"):
            t = [rows[(form, N)][key] for N in horizons]
            slope = np.polyfit(np.log(horizons), np.log(t), 1)[0]
            print(f"{form:11s} {key:22s} time ∝ N^{slope:.2f} over N = {horizons}")


def _limited_pair(name: str, form: str, N: int, samples: int):
    """(recorded states, reference rows, the unconstrained and the torque-limited controllers, τ (N·m)) of one form
    and N on the S-curve: τ is half the unconstrained step's peak over the recorded states (the limit binds)."""
    robot = ParallelRobot.load(name)
    ref = path_for("auto", robot.home_pose, robot.output_angular, SCurve().duration)
    model = ReducedModel(robot)
    Xs, ws = _states(robot, ref, N, samples)
    free = GPCController.build(model, TS, Horizons(N), WEIGHTS, form=form, solver="riccati")
    tau = 0.5 * max(np.abs(free.step(X, w).u).max() for X, w in zip(Xs, ws))
    free.reset()
    limited = GPCController.build(model, TS, Horizons(N), WEIGHTS, form=form, solver="riccati",
                                  limits=Limits(torque=tau))
    return Xs, ws, free, limited, tau


def run_trace(name: str, form: str, N: int, samples: int, reps: int = 1, closed_loop: bool = False) -> None:
    """``--trace form:N``: the limited step of :func:`run_limited` step by step (a warm-up pass, then
    ``reps`` passes; the unconstrained step timed on the same state right after, or with ``closed_loop`` in
    its own loop, the two loops interleaved): the last pass's µs of each, what solved it (active set, or the
    interior point after it), the active set's sweeps and the interior point's iterations, how many
    components the solution's set holds on a limit; then, over the ``reps`` passes, the median µs of the
    limited steps by their number of sweeps against the unconstrained steps of the same samples. τ: that of
    the recorded states (:func:`_limited_pair`), in closed loop too."""
    robot = ParallelRobot.load(name)
    Xs, ws, free, limited, tau = _limited_pair(name, form, N, samples)
    ref = path_for("auto", robot.home_pose, robot.output_angular, SCurve().duration)
    print(f"{name} {form} N = {N}, τ = {tau:.3g} N·m{' (closed loop)' if closed_loop else ''}: step, limited µs, "
          "unconstrained µs, method, (sweeps, interior-point iterations), components on a limit")
    stagewise = limited._riccati.constrained
    rows = []  # (pass, sample, limited s, unconstrained s, sweeps)
    for rep in range(reps + 1):
        passed = []

        def note(k):
            held = "–" if stagewise._fixed is None else f"{int((stagewise._fixed >= 0).sum())}/{stagewise._fixed.size}"
            passed.append((stagewise.method, stagewise.iterations, held))

        if closed_loop:
            runs = interleaved_loops(robot, ref, {"limited": limited, "free": free}, N, samples, time.perf_counter, TS,
                                     lambda key, k, ctl: note(k) if key == "limited" else None)
            t_lim, t_free = runs["limited"][0], runs["free"][0]
        else:
            limited.reset()
            free.reset()
            t_lim, t_free = [], []
            for X, w in zip(Xs, ws):
                t0 = time.perf_counter()
                limited.step(X, w)
                t1 = time.perf_counter()
                free.step(X, w)
                t_lim.append(t1 - t0)
                t_free.append(time.perf_counter() - t1)
                note(len(t_lim) - 1)
        if rep:
            rows += [(rep, k, a, b, it[0]) for k, (a, b, (_, it, _)) in enumerate(zip(t_lim, t_free, passed))]
        if rep == reps:
            for k, (a, b, (method, it, held)) in enumerate(zip(t_lim, t_free, passed)):
                print(f"  {k:3d} {1e6 * a:9.1f} {1e6 * b:8.1f}  {method:32s} {it}  {held}")
    print("by sweeps (median µs over the passes): sweeps, steps, limited, unconstrained on the same samples")
    for n in sorted({r[4] for r in rows}):
        sel = [r for r in rows if r[4] == n]
        print(f"  {n:3d} {len(sel):5d} {1e6 * np.median([r[2] for r in sel]):9.1f} "
              f"{1e6 * np.median([r[3] for r in sel]):9.1f}")


def run_count(name: str, form: str, N: int, samples: int, steps: int, free_only: bool) -> None:
    """``--count form:N --steps K``: the limited (or, ``free_only``, the unconstrained) step on the first
    ``steps`` recorded states and nothing else after the recording, for callgrind's instruction counts."""
    Xs, ws, free, limited, tau = _limited_pair(name, form, N, samples)
    ctl = free if free_only else limited
    sweeps = []
    for X, w in list(zip(Xs, ws))[:steps]:
        ctl.step(X, w)
        if not free_only:
            sweeps.append(limited._riccati.constrained.iterations[0])
    print(f"{name} {form} N = {N}: {'unconstrained' if free_only else 'limited'} steps on {steps} of {samples} "
          f"recorded states, τ = {tau:.4g}; sweeps per step {sweeps}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=None, help="repetitions (default 7; --trace: 1 pass after the warm-up)")
    parser.add_argument("--samples", type=int, default=60)
    parser.add_argument("--cases", default="planar_4rrr:10,planar_4rrr:20,planar_4rrr:40,hexapod_8ups:20")
    parser.add_argument("--limited", action="store_true", help="the torque-limited step (stage-wise active set)")
    parser.add_argument("--horizons", default="20,40,80,160", help="N values of --limited")
    parser.add_argument("--robot", default="planar_4rrr", help="robot of --limited")
    parser.add_argument("--forms", default="absolute,incremental", help="forms of --limited")
    parser.add_argument("--trace", metavar="FORM:N", help="the limited step of one form and N, step by step")
    parser.add_argument("--cpu", action="store_true", help="--limited: time the steps by CPU time, not wall time")
    parser.add_argument("--closed-loop", action="store_true",
                        help="--limited: each configuration in its own closed loop on the plant, not the recorded states")
    parser.add_argument("--count", metavar="FORM:N", help="only the limited steps of one form and N (callgrind)")
    parser.add_argument("--steps", type=int, default=12, help="--count: the steps on the first recorded states")
    parser.add_argument("--free", action="store_true", help="--count: the unconstrained step instead")
    args = parser.parse_args()
    reps = 7 if args.reps is None else args.reps
    if args.count:
        form, N = args.count.split(":")
        run_count(args.robot, form, int(N), args.samples, args.steps, args.free)
        return
    if args.trace:
        form, N = args.trace.split(":")
        run_trace(args.robot, form, int(N), args.samples, 1 if args.reps is None else args.reps, args.closed_loop)
        return
    if args.limited:
        run_limited(args.robot, [int(n) for n in args.horizons.split(",")], reps, args.samples,
                    args.forms.split(","), time.process_time if args.cpu else time.perf_counter, args.closed_loop)
        return
    for case in args.cases.split(","):
        name, N = case.split(":")
        run_case(name, int(N), reps, args.samples)


if __name__ == "__main__":
    main()
