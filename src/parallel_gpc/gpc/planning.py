"""Quadratically-optimal point-to-point trajectory planning, eq. (20)–(21).

The platform moves from pose A to pose B with no prescribed path. The criterion (5) is used
with N = Nmax and No = N − k (k = order of the system in samples; k = 2 for X = [y, ẏ]): only
the last k predicted outputs are compared with B — the positions at N − 1 and N, which also
means zero velocity at the end — while Qu penalizes every input over the whole horizon. The
square-root system is the paper's eq. (20),

.. math::

    \\begin{bmatrix} Q_y \\bar G \\\\ Q_u \\end{bmatrix} u \\approx
    \\begin{bmatrix} Q_y (w - f)_{N-k+1..N} \\\\ 0 \\end{bmatrix},

whose solution spreads the drive effort quadratically over the horizon ("dead-beat spread in
time"). The paper's two modes (Fig. 3) are both receding-horizon: re-solved every step from the
current state of the nonlinear plant with the model at that state, only the first input applied:

* ``"a"`` — *without stopping information*: N = Nmax and No = N − k held fixed ("difference of
  horizons N and No is still the same"): the end point moves with the window, so the platform
  approaches B asymptotically, with no definite stopping instant.
* ``"b"`` — *with stopping*: the horizon shrinks, eq. (21), N := Nmax, Nmax − 1, …, Nmin, then
  is held at Nmin: the platform stops at B at t ≈ Nmax·Ts.

A third variant, ``"once"``, is the paper's remark that for a linear system the sequence can be
computed once (at N = Nmax from the model at A) and applied open loop; on the robot the frozen
model misses B by the effect of the nonlinearity.

The recorded plant outputs are the planned trajectory: :meth:`PlanResult.trajectory` gives a
:class:`~parallel_gpc.references.SampledTrajectory` that the tracking controller takes as its
reference w, and :meth:`PlanResult.save` writes a file that
:meth:`SampledTrajectory.load <parallel_gpc.references.SampledTrajectory.load>` reads.

Defaults: Ts = 10 ms (the move lasts Nmax·Ts, so a coarser sample keeps the problem small:
Nmax = 120 gives a 1.2 s move with 480 unknowns on the 4-drive robot), Qy = 1, Qu = 1e-6.
Qu must be small against the end-point rows of G: their smallest singular value is about
7e-5 m/(N·m) on the default robot at these settings, so Qu = 1e-6 leaves an end-point shortfall
below 1e-6 m in the linear model while still selecting the minimum-energy solution (a larger
Qu shortens the move: it trades end-point error for energy).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
from tqdm import tqdm

from ..model import discretize_zoh, ReducedModel
from ..errors import InvalidParameterError, SolverError
from ..results import robot_reference
from .prediction import Horizons, Prediction, absolute_prediction
from ..solvers import LeastSquaresProblem, SolveResult, make_solver
from .constraints import DriveKinematics, constrain, split, stage_constraints
from .criterion import build_problem, check_problem_size
from ..validation import check_allocation, check_sample_time, finite_vector
from .plan_result import PlanRecorder, PlanResult
from .plan_settings import (  # noqa: F401  (re-exported: the planning API in one place)
    DEFAULT_LIMITED_SOLVER,
    INTERRUPTED,
    MODE_LABELS,
    MODES,
    PlanSettings,
)


# ---------------------------------------------------------------------------- one solve
def end_point_problem(model, X, target, N: int, settings: PlanSettings,
                      u_hold: np.ndarray | None = None,
                      warm_start: np.ndarray | None = None) -> tuple[LeastSquaresProblem, Prediction]:
    """The least squares (20) at state X: horizon N, No = N − k, Nu = N.

    The model is the state-dependent factorization (3) at X, ZOH-discretized at Ts (4); only
    the last k predicted outputs are compared with ``target``. With ``u_hold`` (the static
    torque that holds the platform at the target against gravity, :func:`hold_torque`) the
    unknowns are the deviations v = u − u_hold, so Qu penalizes ‖u − u_hold‖: without it, the
    receding-horizon plan of a robot under gravity settles short of B (on our Delta robot by
    0.7 mm, whatever Qu), because the minimum-‖u‖ plan from rest at B is not u_hold.

    Args:
        model: a :class:`~parallel_gpc.dynamics.ReducedModel` (or any object with
            ``factorize(X) -> (A, B, c)``, ``C``, ``n_y``, ``n_u``).
        X: (2·n_y,) state [y, ẏ] (m, rad, m/s, rad/s).
        target: (n_y,) end pose B (m, rad).
        N: horizon, N ≥ k.
        settings: weights, k, Ts, torque limit.
        u_hold: (n_u,) N·m, or None (zero).
        warm_start: (N·n_u,) the previous plan as v (shifted), or None: the poses the drive
            limits are linearized at (:mod:`parallel_gpc.gpc.constraints`).

    The state limits of ``settings.limits`` (drive strokes, workspace box, velocities) hold over
    the whole move, every predicted step 1..N, not only the compared end: a move that would
    leave them bends or slows instead.

    Returns:
        (problem, prediction): ``min ‖A v − b‖²`` over v = [u(0) … u(N−1)] − u_hold (N·n_u, N·m),
        followed by the slack variables of soft state limits (``problem.n_slack``).
    """
    A, B, c = model.factorize(X)
    Ad, Bd, cd = discretize_zoh(A, B, c, settings.Ts)
    N = int(N)
    whole = absolute_prediction(Ad, Bd, cd, model.C, X, Horizons(N, 0, N))  # every step: the state limits'
    hold = None if u_hold is None else np.tile(u_hold, N)
    if hold is not None:  # ŷ = f + G (v + hold)
        whole = replace(whole, f=whole.f + whole.G @ hold, u_base=whole.u_base + hold)
    rows_end = settings.k * model.n_y  # the compared end: the last k steps
    pred = replace(whole, f=whole.f[-rows_end:], G=whole.G[-rows_end:], horizons=Horizons(N, N - settings.k, N))
    w = np.tile(target, (settings.k, 1))
    problem = build_problem(pred, w, settings.weights, model.n_y, model.n_u, settings.limits)
    if hold is not None and problem.lb is not None:
        problem.lb, problem.ub = problem.lb - hold, problem.ub - hold
    limits = settings.limits
    if limits.has_state_limits:
        limits = limits.for_drives(model.n_u, model.n_y)
        y_lin = whole.f if warm_start is None or warm_start.shape != (whole.G.shape[1],) else whole.outputs(warm_start)
        rows = stage_constraints(whole, limits, settings.Ts, model.C @ X, y_lin, DriveKinematics.needed(model, limits))
        problem = constrain(problem, rows, limits)
    return problem, pred


def hold_torque(model, target) -> np.ndarray | None:
    """(n_u,) minimum-norm drive torques (N·m) that hold the platform at rest at ``target``
    (ÿ = f + g u = 0, eq. (1)); None when it is zero (a horizontal robot) or the model is not a
    :class:`~parallel_gpc.model.dynamics.ReducedModel`."""
    if not isinstance(model, ReducedModel):
        return None
    terms = model.terms(np.concatenate([target, np.zeros(model.n_y)]))
    u = -np.linalg.pinv(terms.g) @ terms.f
    return u if np.any(u != 0.0) else None


def solve_end_point(model, X, target, N: int, settings: PlanSettings, backend=None,
                    warm_start: np.ndarray | None = None, u_hold: np.ndarray | None = None
                    ) -> tuple[np.ndarray, SolveResult]:
    """Solve (20) at state X with horizon N.

    Returns:
        (u, result): u is the (N, n_u) input sequence in N·m (NaN if the solve failed; check
        ``result.ok``).
    """
    problem, _ = end_point_problem(model, X, target, N, settings, u_hold, warm_start)
    backend = make_solver(settings.solver) if backend is None else backend
    if warm_start is not None and problem.n_slack:
        warm_start = np.concatenate([warm_start, np.zeros(problem.n_slack)])
    result, _ = split(problem, backend.solve(problem, warm_start))
    u = np.asarray(result.v, dtype=float).reshape(int(N), model.n_u)
    return (u if u_hold is None else u + u_hold), result


def deadbeat_inputs(model, X, target, settings: PlanSettings) -> np.ndarray:
    """The dead-beat move: the same end-point criterion with the minimal horizon N = k.

    The comparison case of the paper's "dead-beat spread in time": the end point is reached
    in k samples (unconstrained; Qu as in ``settings``, for the minimum-norm choice).

    Returns:
        (k, n_u) drive torques in N·m.
    """
    free = replace(settings, limits=None, solver="qr")
    u, result = solve_end_point(model, X, target, settings.k, free)
    if not result.ok:  # pragma: no cover - QR does not fail on finite data
        raise SolverError(f"dead-beat solve failed: {result.status} {result.message}")
    return u


# ---------------------------------------------------------------------------- planner
def _default_plant(robot, X0, settings: PlanSettings):
    from ..model import ConstrainedPlant

    return ConstrainedPlant(robot, X0, Ts=settings.Ts, substeps=settings.plant_substeps, torque_limit=robot.limits)


def plan_point_to_point(robot, A, B, settings: PlanSettings | None = None, mode: str = "b", plant=None,
                        model=None, progress: bool = False) -> PlanResult:
    """Plan a quadratically-optimal move from pose A to pose B, eq. (20)–(21).

    Args:
        robot: the :class:`~parallel_gpc.robot.ParallelRobot` (may be None when both ``plant``
            and ``model`` are given, e.g. a linear test system).
        A, B: (n_y,) start and end poses (m, rad); the move starts at rest.
        settings: :class:`PlanSettings` (default ``PlanSettings()``).
        mode: ``"a"`` (re-solved every step with N = Nmax fixed: asymptotic approach),
            ``"b"`` (re-solved every step, N := Nmax, …, Nmin, then held at Nmin: stops at B) or
            ``"once"`` (one solve at Nmax applied open loop: linear systems only).
        plant: the system the plan is recorded on (``Ts`` equal to the settings', ``step(u)``,
            ``X``, optionally ``q`` and ``saturated``); default a fresh
            :class:`~parallel_gpc.plant.ConstrainedPlant` at A, at rest, with the robot's own
            drive limits. If given, its pose must be A.
        model: the planner's model (default ``ReducedModel(robot)``).
        progress: show a progress bar over the steps of modes (a) and (b).

    Returns:
        The :class:`PlanResult`: Nmax + settle_steps steps for modes (a) and (b), Nmax for
        once (fewer, with ``stopped`` set, if the plant leaves the workspace).

    Raises:
        InvalidParameterError: unknown mode, bad poses or settings, or a plant not at A or with
            another sample time.
        UnreachablePoseError, SingularPoseError: A or B is outside the workspace or singular.
        SolverError: a solve failed with no earlier plan to fall back on.
    """
    settings = PlanSettings() if settings is None else settings
    if not isinstance(settings, PlanSettings):
        raise InvalidParameterError(f"settings must be a PlanSettings, got {type(settings).__name__}")
    if mode not in MODES:
        raise InvalidParameterError(f"planning mode {mode!r} is not one of {MODES} (a: receding without stopping "
                                    f"information, b: shrinking horizon with stopping, once: one open-loop solve)")
    if robot is None and (plant is None or model is None):
        raise InvalidParameterError("plan_point_to_point needs a robot, or both a plant and a model")
    model = ReducedModel(robot) if model is None else model
    n_y, n_u = model.n_y, model.n_u
    A = finite_vector("start pose A", A, n_y)
    B = finite_vector("end pose B", B, n_y)
    settings.weights.blocks(n_y, n_u)  # validate the weights against the sizes, once
    check_problem_size(Horizons(settings.Nmax, settings.Nmax - settings.k, settings.Nmax), n_y, n_u)
    settings.limits.for_drives(n_u)  # per-drive limits: one per drive
    if robot is not None:
        robot.check_pose(A)
        robot.check_pose(B)
    if plant is None:
        plant = _default_plant(robot, np.concatenate([A, np.zeros(n_y)]), settings)
    elif np.max(np.abs(np.asarray(plant.X, dtype=float)[:n_y] - A)) > 1e-6:
        raise InvalidParameterError(f"the plant is at pose {np.round(np.asarray(plant.X)[:n_y], 6).tolist()}, "
                                    f"not at the start pose A = {np.round(A, 6).tolist()}")
    check_sample_time(plant, settings.Ts, "plant", "the plan's")
    backend = make_solver(settings.solver)
    sat0 = getattr(plant, "saturated", 0)
    K = settings.Nmax if mode == "once" else settings.Nmax + settings.settle_steps
    q0 = getattr(plant, "q", None)
    check_allocation(f"the record of {K} samples (Nmax = {settings.Nmax}"
                     + ("" if mode == "once" else f" + settle_steps = {settings.settle_steps}") + ")",
                     (K + 1) * (2 * n_y + n_u + 3 + (0 if q0 is None else len(q0))),
                     "reduce settle_steps (plan --settle) or Nmax")
    rec = PlanRecorder(K, n_y, n_u, plant)
    try:
        if mode == "once":
            _run_open_loop(model, plant, B, settings, backend, rec)
        else:
            _run_receding(model, plant, B, settings, backend, rec, mode, progress)
    except KeyboardInterrupt:  # Ctrl-C: keep the samples applied so far
        if rec.steps == 0:
            raise
        rec.stopped = f"{INTERRUPTED} after {rec.steps} of {K} samples"
    n = rec.steps
    return PlanResult(mode, A, B, settings.Ts * np.arange(n + 1), rec.X[: n + 1, :n_y].copy(),
                      rec.X[: n + 1, n_y:].copy(), rec.u[:n].copy(), rec.horizon[:n].copy(),
                      rec.status[:n].astype(str), rec.solve_time[:n].copy(),
                      None if rec.q is None else rec.q[: n + 1].copy(), settings,
                      int(getattr(plant, "saturated", 0) - sat0), rec.stopped, robot_reference(robot),
                      None if robot is None else robot.output_space)



def _run_open_loop(model, plant, B, settings: PlanSettings, backend, rec: PlanRecorder) -> None:
    """Mode once: one solve at N = Nmax from the model at A, the whole sequence applied."""
    Nmax, Ts = settings.Nmax, settings.Ts
    t0 = time.perf_counter()
    u_seq, result = solve_end_point(model, np.asarray(plant.X, dtype=float), B, Nmax, settings, backend,
                                    u_hold=hold_torque(model, B))
    rec.solve_time[0] = time.perf_counter() - t0
    if not result.ok:
        raise SolverError(f"planning solve (mode once, N = {Nmax}) failed with {result.solver}: {result.status} "
                          f"{result.message}")
    for i in range(Nmax):
        if not rec.apply(i, u_seq[i], Nmax - i, result.status if i == 0 else "open-loop", Ts):
            break


def horizon_at(mode: str, i: int, settings: PlanSettings) -> int:
    """Horizon N of step i: mode (a) Nmax always; mode (b) max(Nmax − i, Nmin), eq. (21)."""
    return settings.Nmax if mode == "a" else max(settings.Nmax - i, settings.Nmin)


def _run_receding(model, plant, B, settings: PlanSettings, backend, rec: PlanRecorder, mode: str,
                  progress: bool) -> None:
    """Modes (a) and (b): re-solve every step from the plant's state, only the first input applied;
    the horizon of step i is :func:`horizon_at`."""
    Ts, m = settings.Ts, model.n_u
    remaining = None  # the last successful plan's inputs not yet applied, (n, m)
    v_prev = None
    u_hold = hold_torque(model, B)
    steps = tqdm(range(len(rec.u)), disable=not progress, desc=f"plan {MODE_LABELS[mode]}", unit="step", leave=False)
    for i in steps:
        N = horizon_at(mode, i, settings)
        warm = None
        if v_prev is not None:  # the previous solution shifted by one sample (last input repeated)
            warm = v_prev[m:]
            if len(warm) < N * m:
                warm = np.concatenate([warm, np.tile(v_prev[-m:], N - len(warm) // m)])
            warm = warm[: N * m]
        t0 = time.perf_counter()
        u_seq, result = solve_end_point(model, np.asarray(plant.X, dtype=float), B, N, settings, backend, warm,
                                        u_hold)
        rec.solve_time[i] = time.perf_counter() - t0
        if result.ok:
            plan, v_prev, status = u_seq, result.v, result.status
        elif remaining is not None and len(remaining):  # visible fallback: follow the last plan
            plan, v_prev, status = remaining, None, "fallback"
        else:
            raise SolverError(f"planning solve (mode {mode}, step {i}, N = {N}) failed with {result.solver}: "
                              f"{result.status} {result.message}")
        remaining = plan[1:]
        if not rec.apply(i, plan[0], N, status, Ts):
            break


@dataclass
class PlanComparison:
    """The modes of :func:`plan_modes` planned for one move.

    Attributes:
        results: the :class:`PlanResult` of each mode that ran, in order (the last one may be
            interrupted: see :attr:`interrupted`).
        interrupted: True when Ctrl-C stopped the run before every mode finished.
        deadbeat: (k, n_u) the dead-beat inputs of the same criterion at the minimal horizon
            N = k (N·m or N), or None when interrupted.
    """

    results: list
    interrupted: bool = False
    deadbeat: np.ndarray | None = None


def plan_modes(robot, A, B, settings: PlanSettings, modes=MODES, progress: bool = False) -> PlanComparison:
    """Plan the move A → B in each of ``modes`` (the paper's Fig. 3/4 comparison) on fresh plants.

    Ctrl-C keeps the modes finished so far (and the samples of the interrupted one): the
    comparison is returned with ``interrupted`` True; before the first sample of the first mode
    it propagates.

    Args:
        robot: the :class:`~parallel_gpc.model.ParallelRobot`.
        A, B: (n_y,) start and end poses (m, rad).
        settings: the :class:`PlanSettings`.
        modes: the modes to plan, a subset of :data:`MODES` in any order.
        progress: progress bar over the steps of each receding mode.
    """
    results = []
    try:
        for mode in modes:
            res = plan_point_to_point(robot, A, B, settings, mode=mode, progress=progress)
            results.append(res)
            if res.interrupted:
                break
    except KeyboardInterrupt:  # before the mode's first sample: keep the finished modes
        if not results:
            raise
    if len(results) < len(modes) or results[-1].interrupted:
        return PlanComparison(results, interrupted=True)
    X0 = np.concatenate([np.asarray(A, dtype=float), np.zeros(robot.n_y)])
    return PlanComparison(results, deadbeat=deadbeat_inputs(ReducedModel(robot), X0, np.asarray(B, dtype=float),
                                                            settings))
