"""Benchmark of the GPC control step on the real problems along the S-curve.

``run_benchmark(quick, out_dir)`` times, for each robot and horizon N, on the problems the
controller solves while tracking the paper's S-curve (Fig. 2):

* ``unconstrained`` — the square-root solve by QR (LAPACK path, numpy path, the pivoted
  rank-revealing path), Cholesky of the normal equations (guarded), every QP back end without
  limits, and one bare LAPACK QR (``dgeqrf``) of the stacked matrix: the machine-independent unit;
* ``limited`` — the same problems with drive torque limits that bind at about half of the
  inputs: ``qpsolvers`` + OSQP / ProxQP / DAQP (rebuilt every call), the persistent direct back
  ends (warm-started along the curve), bounded-variable least squares and the controller's
  defaults ``qr-first:bvls`` (absolute form) and ``qr-first:daqp-direct`` (incremental forms);
* ``step`` — the full control step (model update + prediction + solve, ``GPCController.step``)
  of the absolute, incremental and incremental-nonlinear forms, unconstrained and limited, each
  controller replaying its own stretch of samples consecutively (as in a control loop);
* ``qpmpc`` — the linear time-varying MPC problem along the nonlinear pre-simulation (absolute
  inputs, torque limits) solved by our condenser + QP back end and by the ``qpmpc`` package.

Each entry reports the median and 99th percentile of the wall time, its ratio to the QR (LAPACK)
solve measured in the same run, and the solution's error against a tight reference (QR without
limits; a fresh DAQP active-set solve with limits). Repetitions are interleaved in one process:
every repetition walks the problems in order and runs every solver on each problem, then every
controller over each stretch. A closed loop of ``closed_loop_s`` at 1 kHz (absolute form, N = 20,
full constrained plant) gives the wall time per simulated second. Set
``OPENBLAS_NUM_THREADS=1`` before numpy is imported (the script does).
"""

from __future__ import annotations

import json
import math
import os
import time
import warnings
from dataclasses import asdict
from pathlib import Path

import numpy as np
from scipy.linalg import lapack

from ..gpc import GPCController, Horizons, Prediction, condense, SCurve, path_for, Weights, build_problem
from ..gpc.stagewise import StagewiseSolver
from ..model import cached_identity, ReducedModel, ConstrainedPlant, ParallelRobot
from ..limits import Limits
from .report import evaluate_targets, machine_info, markdown_report, ratios
from ..plots import plot_results, save_figure
from .qpmpc import QPMPC_VELOCITY_SCALE, QpmpcPeer, qpmpc_problem
from ..studies import simulate
from ..results import json_default
from ..solvers import DAQPBackend, QRSolver, make_solver
from .problems import BenchConfig, closed_loop_states, replay_controllers, replay, robot_C
from .store import log_solve, relative_error, BenchRun

__all__ = ["BenchConfig", "run_benchmark", "closed_loop_wall_time", "lapack_qr_unit", "robot_C"]


# ------------------------------------------------------------------------------- methods
def lapack_qr_unit(A: np.ndarray) -> None:
    """One bare LAPACK Householder QR (``dgeqrf``) of a matrix the size of the stacked problem:
    the unit the benchmark's ratios are measured in (machine-independent, unlike µs)."""
    lapack.dgeqrf(A)


# ------------------------------------------------------------------------------- the run
def _bench_robot_N(run: BenchRun, robot: ParallelRobot, N: int, stretches, ref: SCurve, bar) -> None:
    cfg = run.cfg
    Ts, name = cfg.Ts, robot.name
    m = robot.n_u
    W = Weights(1.0, cfg.qu)
    H = Horizons(N)
    stretches = list(stretches.values())
    # ---- the absolute controller's own closed loop: its problems, and the torque limit τ
    seq_abs = replay(GPCController.build(ReducedModel(robot), Ts, H, W, form="absolute"), robot, stretches, ref, N)
    abs_ctl = GPCController.build(ReducedModel(robot), Ts, H, W, form="absolute")
    problems = [[(pred := abs_ctl.predict(X), build_problem(pred, w, W, robot.n_y, m)) for X, w, _ in rows]
                for rows in seq_abs]
    qr = QRSolver()
    u_all = np.concatenate([np.abs(qr.solve(p).v) for rows in problems for _, p in rows])
    tau = float(np.quantile(u_all, cfg.limit_quantile))
    run.limits[(name, N)] = tau
    limits = Limits(torque=tau)
    limited = [[build_problem(pred, w, W, robot.n_y, m, limits) for (pred, _), (_, w, _) in zip(rows, seq)]
               for rows, seq in zip(problems, seq_abs)]
    # references: QR (unconstrained), a fresh DAQP active-set solve (limited)
    ref_free = [[qr.solve(p).v for _, p in rows] for rows in problems]
    ref_lim = [[DAQPBackend().solve(p).v for p in rows] for rows in limited]

    free_methods = [("qr (LAPACK)", QRSolver()), ("one LAPACK QR (dgeqrf, same size)", None),
                    ("qr (numpy)", QRSolver("numpy")), ("qr (pivoted, scipy)", QRSolver("pivoted")),
                    ("cholesky (normal eq.)", make_solver("cholesky"))]
    free_methods += [(f"qpsolvers:{s}", make_solver(f"qpsolvers:{s}")) for s in cfg.qp_solvers]
    free_methods += [(d, make_solver(d)) for d in cfg.direct]
    lim_methods = [(f"qpsolvers:{s}", make_solver(f"qpsolvers:{s}")) for s in cfg.qp_solvers]
    lim_methods += [(d, make_solver(d)) for d in cfg.direct]
    lim_methods += [(name, make_solver(name)) for name in ("bvls", "qr-first:bvls", "qr-first:daqp-direct")]

    # ---- full steps: each controller's own closed loop (untimed recording pass)
    steps = replay_controllers(lambda native: ReducedModel(robot, native=native), cfg, N, tau)
    seqs = {cname: replay(ctl, robot, stretches, ref, N, run.entry("loop", name, N, cname), cfg.warmup)
            for cname, ctl in steps}
    # ---- qpmpc: the LTV models of the nonlinear pre-simulation at each sample
    nl = dict(steps)["nonlinear"]
    ltv = []
    for stretch, rows in zip(stretches, seqs["nonlinear"]):
        out = []
        for smp, (X, w, snap) in zip(stretch, rows):
            nl.restore(snap)
            u_sim = np.vstack([nl.plan[1:], nl.plan[-1:]])
            A_seq, B_seq, c_seq, _ = nl.model.simulate_factorized(X, u_sim, Ts, nl.disturbance)
            c_seq = c_seq + nl.disturbance
            wdot = np.array([(ref.pose(smp.t + (j + 1) * Ts + 1e-6) - ref.pose(smp.t + (j + 1) * Ts - 1e-6)) / 2e-6
                             for j in range(N)])
            f, G = condense(A_seq, B_seq, c_seq, robot_C(robot), X, H, hold_inputs=True)
            pred = Prediction(f, G, np.zeros(N * m), np.eye(N * m), H, "absolute")
            v_ref = DAQPBackend().solve(build_problem(pred, w, W, robot.n_y, m, limits)).v
            out.append((A_seq, B_seq, c_seq, X, w, wdot, v_ref))
            if not ltv and not out[1:]:  # the cost scale a qpmpc user would pick, once
                kappa = 1.0 / float(np.max(np.einsum("ij,ij->j", G, G)))
        ltv.append(out)
    ours_ltv = [(f"ours: condense + {name}", make_solver(name))
                for name in ("qr-first:daqp-direct", "proxqp-direct", "daqp-direct", "bvls")]
    # the same problem stage by stage, no condensing: the controller's limited `riccati` path (the
    # active set of Riccati sweeps on the torque rows), warm-started from its last set like a controller
    Wy, Wu = W.blocks(robot.n_y, m)
    C = robot_C(robot)  # built once: not part of any timed solve
    stagewise_ltv = StagewiseSolver(Wy, Wu, C, H, "absolute", limits.for_drives(m, robot.n_y), Ts)
    peers = []
    for s in cfg.qpmpc_solvers:
        try:
            peers.append(QpmpcPeer(s))
        except ImportError:  # qpmpc not installed: the section reports nothing
            break

    # ---- interleaved repetitions
    warm = {}
    for rep in range(cfg.reps):
        for si, stretch in enumerate(stretches):
            for k in range(len(stretch)):
                timed = k >= cfg.warmup
                prob, prob_l = problems[si][k][1], limited[si][k]
                v_ref, v_ref_l = ref_free[si][k], ref_lim[si][k]
                # unconstrained solves
                for mname, solver in free_methods:
                    if solver is None:  # the unit: a bare dgeqrf of the stacked matrix
                        t0 = time.perf_counter()
                        lapack_qr_unit(prob.A)
                        dt = time.perf_counter() - t0
                        if timed:
                            run.entry("unconstrained", name, N, mname).times.append(dt)
                        continue
                    t0 = time.perf_counter()
                    v = solver.solve(prob, warm.get(("free", mname))).v
                    dt = time.perf_counter() - t0
                    warm[("free", mname)] = _shift(v, m)
                    if timed:
                        e = run.entry("unconstrained", name, N, mname)
                        log_solve(e, dt, np.all(np.isfinite(v)), v, v_ref, prob)
                # limited solves
                for mname, solver in lim_methods:
                    t0 = time.perf_counter()
                    res = solver.solve(prob_l, warm.get(("lim", mname)))
                    dt = time.perf_counter() - t0
                    warm[("lim", mname)] = _shift(res.v, m) if res.ok else None
                    if timed:
                        e = log_solve(run.entry("limited", name, N, mname), dt, res.ok, res.v, v_ref_l, prob_l)
                        e.violations.append(prob_l.violation(res.v) if res.ok else math.inf)
                # the LTV problem: our condenser + QP vs qpmpc
                A_seq, B_seq, c_seq, X, w, wdot, v_ref_ltv = ltv[si][k]
                for mname, solver in ours_ltv:
                    t0 = time.perf_counter()
                    f, G = condense(A_seq, B_seq, c_seq, C, X, H, hold_inputs=True)
                    pred = Prediction(f, G, np.zeros(N * m), cached_identity(N * m), H, "absolute")
                    p = build_problem(pred, w, W, robot.n_y, m, limits)
                    res = solver.solve(p, warm.get(("ltv", mname)))
                    dt = time.perf_counter() - t0
                    warm[("ltv", mname)] = _shift(res.v, m) if res.ok else None
                    if timed:
                        log_solve(run.entry("qpmpc", name, N, mname), dt, res.ok, res.v, v_ref_ltv)
                t0 = time.perf_counter()
                res, _ = stagewise_ltv.solve((A_seq, B_seq, c_seq, X, None), w.reshape(H.n_rows, robot.n_y), C @ X,
                                             warm=k > 0)
                dt = time.perf_counter() - t0
                if timed:
                    log_solve(run.entry("qpmpc", name, N, "ours: stage-wise (riccati: active set)"), dt, res.ok,
                              res.v, v_ref_ltv)
                for peer in peers:
                    t0 = time.perf_counter()
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        mp = qpmpc_problem(A_seq, B_seq, c_seq, X, w, wdot, X[:robot.n_y], np.full(m, tau), cfg.qu,
                                           kappa)
                        v = peer.solve(mp)
                    dt = time.perf_counter() - t0
                    if timed:
                        e = run.entry("qpmpc", name, N, peer.name,
                                      note=f"velocities scaled by {QPMPC_VELOCITY_SCALE:g} (weight ε²), "
                                           f"cost scaled by κ = {kappa:.3g}")
                        e.times.append(dt)
                        e.failures += int(v is None)
                        e.errors.append(relative_error(v, v_ref_ltv))
                if bar is not None:
                    bar.update(1)
        _time_steps(run, name, N, steps, seqs, len(stretches), cfg.warmup)


def _time_steps(run: BenchRun, robot: str, N: int, steps, seqs, n_stretches: int, warmup: int) -> None:
    """Full control steps: each controller replays its own closed-loop samples of a stretch one
    after the other (state restored before every step), as a control loop would call it —
    interleaving the steps with the other solvers, as the benchmark did before, inflated the step
    (absolute, planar_4rrr, N = 20: 862 µs with five QP solves between steps vs 630 µs
    consecutive, the same with the garbage collector off: cold caches, not allocation)."""
    for si in range(n_stretches):
        for cname, ctl in steps:
            for k, (X, w, snap) in enumerate(seqs[cname][si]):
                ctl.restore(snap)
                t0 = time.perf_counter()
                info = ctl.step(X, w)
                dt = time.perf_counter() - t0
                if k >= warmup:
                    e = run.entry("step", robot, N, cname)
                    e.times.append(dt)
                    e.failures += int(info.fallback)


def _shift(v, m: int):
    """The absolute controller's warm start: the previous solution shifted by one sample."""
    if v is None or not np.all(np.isfinite(v)):
        return None
    return np.concatenate([v[m:], v[-m:]])


def closed_loop_wall_time(robot_name: str, seconds: float, N: int = 20, Ts: float = 1e-3, solver: str | None = None,
                          native: bool | None = None) -> dict:
    """Wall time of a closed-loop simulation: the absolute controller (N, Qu = 1e-5, ``solver``)
    at 1/Ts on the full constrained plant tracking the robot's default path for ``seconds``.

    Args:
        solver: the controller's back end (None: the default, here ``"riccati"``; ``"qr"``: the
            square-root reference). The result names the back end used.
        native: None = the compiled core where built (model update and plant), False = the
            pure-Python reference.

    Returns:
        {"robot", "N", "Ts_s", "solver", "native", "simulated_s", "wall_s", "wall_per_simulated_s",
        "controller_s"} (controller_s: the sum of the controller's step times).
    """
    robot = ParallelRobot.load(robot_name)
    ref = path_for("auto", robot.home_pose, robot.output_angular, SCurve().duration)
    model = ReducedModel(robot, native=native)
    ctl = GPCController.build(model, Ts, Horizons(N), Weights(1.0, 1e-5), solver=solver)
    plant = ConstrainedPlant(robot, ref.initial_state(), Ts=Ts, native=native)
    t0 = time.perf_counter()
    res = simulate(ctl, plant, ref, seconds, progress=False)
    wall = time.perf_counter() - t0
    return {"robot": robot_name, "N": N, "Ts_s": Ts, "solver": ctl.solver, "native": bool(model.native),
            "simulated_s": seconds, "wall_s": wall, "wall_per_simulated_s": wall / seconds,
            "controller_s": float(np.sum(res.step_time))}


# ------------------------------------------------------------------------------- entry points
def run_benchmark(quick: bool = False, config: BenchConfig | None = None) -> dict:
    """Run the benchmark and return its rows (nothing is printed or written: see
    :func:`write_benchmark` and :func:`~parallel_gpc.bench.report.format_table`).

    Args:
        quick: a short run (fewer stretches, samples and repetitions).
        config: full control over what runs (overrides ``quick``).

    Returns:
        {"machine", "config", "limits_Nm", "results" (one dict per entry), "targets", "wall_time_s",
        "interrupted"}. Ctrl-C stops the run: the rows of the (robot, N) pairs measured to the
        end are kept, written and returned, with ``interrupted`` True.
    """
    cfg = config or (BenchConfig.quick() if quick else BenchConfig())
    if os.environ.get("OPENBLAS_NUM_THREADS") != "1":
        warnings.warn("OPENBLAS_NUM_THREADS is not 1: BLAS threads distort small-matrix timings", stacklevel=2)
    run = BenchRun(cfg)
    plan = [(r, cfg.Ns) for r in cfg.robots] + [(r, cfg.spatial_Ns) for r in cfg.spatial]
    total = sum(len(Ns) for _, Ns in plan) * cfg.reps * len(cfg.segments) * cfg.segment_length
    bar = None
    if cfg.progress:
        from tqdm import tqdm

        bar = tqdm(total=total, desc="benchmark", unit="problem", leave=False)
    t_start = time.perf_counter()
    finished: set[tuple] = set()  # entries of the (robot, N) pairs measured to the end
    interrupted = False
    try:
        for rname, Ns in plan:
            robot = ParallelRobot.load(rname)
            ref = path_for("auto", robot.home_pose, robot.output_angular, SCurve().duration)
            stretches = closed_loop_states(robot, cfg, ref)
            for N in Ns:
                if bar is not None:
                    bar.set_description(f"{rname} N={N}")
                _bench_robot_N(run, robot, N, stretches, ref, bar)
                finished = set(run.entries)
    except KeyboardInterrupt:  # Ctrl-C: report and save the rows of the finished (robot, N) pairs
        interrupted = True
        run.entries = {k: e for k, e in run.entries.items() if k in finished}
    finally:
        if bar is not None:
            bar.close()
    order = {k: i for i, k in enumerate(("unconstrained", "limited", "step", "loop", "qpmpc"))}
    closed_loop = None
    if cfg.closed_loop_s > 0 and not interrupted:
        try:
            closed_loop = [closed_loop_wall_time(cfg.robots[0], cfg.closed_loop_s),  # the default solver
                           closed_loop_wall_time(cfg.robots[0], cfg.closed_loop_s, solver="qr"),
                           {**closed_loop_wall_time(cfg.robots[0], cfg.closed_loop_s, solver="qr", native=False),
                            "reference": True}]  # the pure-Python reference (with QR): timed, no target
        except KeyboardInterrupt:  # Ctrl-C during the closed loop: the table rows are kept
            interrupted = True
    robots = {r: i for i, (r, _) in enumerate(plan)}
    entries = sorted(enumerate(run.entries.values()),
                     key=lambda ie: (robots.get(ie[1].robot, 99), ie[1].N, order[ie[1].section], ie[0]))
    rows = [e.summary() for _, e in entries]
    ratios(rows)
    targets = evaluate_targets(rows, closed_loop) if rows else []
    result = {
        "machine": machine_info(),
        "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(cfg).items()},
        "limits_Nm": {f"{r}/N={n}": tau for (r, n), tau in run.limits.items()},
        "results": rows,
        "targets": targets,
        "closed_loop": closed_loop,
        "wall_time_s": time.perf_counter() - t_start,
        "interrupted": interrupted,
    }
    return result


def write_benchmark(result: dict, out_dir) -> list[Path]:
    """Write ``bench_gpc.json`` (always), ``bench_gpc.md`` and ``bench_gpc.png`` (when there are
    rows) of a :func:`run_benchmark` result into ``out_dir`` (created).

    Returns:
        The paths written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = [out / "bench_gpc.json"]
    written[0].write_text(json.dumps(result, indent=1, default=json_default))
    if result["results"]:
        (out / "bench_gpc.md").write_text(markdown_report(result))
        written += [out / "bench_gpc.md", save_figure(plot_results(result["results"]), out / "bench_gpc.png")]
    return written

