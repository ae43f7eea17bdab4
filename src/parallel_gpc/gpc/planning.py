"""Quadratically-optimal point-to-point trajectory planning, eq. (20)–(21).

The platform moves from pose A to pose B with no prescribed path. The criterion (5) is used
with N = Nmax and No = N − k (k = order of the system in samples; k = 2 for X = [y, ẏ]): only
the last k predicted outputs are compared with B — the positions at N − 1 and N, which also
means zero velocity at the end — while Qu penalizes every input over the whole horizon. The
square-root system is the paper's eq. (20),

.. math::

    \\begin{bmatrix} Q_y \\bar G \\\\ Q_u \\end{bmatrix} u \\approx
    \\begin{bmatrix} Q_y (w - f)_{N-k+1..N} \\\\ 0 \\end{bmatrix},

whose solution spreads the drive energy quadratically over the horizon ("dead-beat spread in
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

import json
import math
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..model.dynamics import ReducedModel, discretize_zoh
from ..errors import AssemblyError, InvalidParameterError, SingularPoseError, SolverError
from ..results import robot_reference, save_result
from .prediction import Horizons, Prediction, absolute_prediction
from .references import SampledTrajectory, pose_error_norms
from ..solvers import LeastSquaresProblem, SolveResult, make_solver
from .criterion import Weights, build_problem, check_problem_size
from ..validation import finite_vector, positive

MODES = ("a", "b", "once")
#: Back end used when torque limits are given and no solver is named: the paper's QR while the
#: limits are inactive, the exact active-set QP (DAQP) when they bind.
DEFAULT_LIMITED_SOLVER = "qr-first:daqp-direct"
#: How :attr:`PlanResult.stopped` starts when Ctrl-C stopped the plan.
INTERRUPTED = "interrupted (Ctrl-C)"
#: What each mode is called in tables and plots.
MODE_LABELS = {"a": "(a) receding, no stopping information", "b": "(b) shrinking horizon, stops",
               "once": "once: open loop (linear systems only)"}


def _integer(name: str, value, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise InvalidParameterError(f"{name} = {value!r} must be an integer ≥ {low}")
    return int(value)


@dataclass(frozen=True)
class PlanSettings:
    """What to plan with (validated at construction).

    Attributes:
        Nmax: horizon of the first solve, samples; the move lasts Nmax·Ts.
        Nmin: smallest horizon of mode (b), k < Nmin ≤ Nmax (the paper: ≤ about 20, larger
            values do not improve the result).
        k: order of the system in samples: the last k outputs are penalized (2 for X = [y, ẏ]).
        Ts: sample time in s (default 10 ms).
        Qy: square-root output weight (scalar, (n_y,) or (n_y, n_y)).
        Qu: square-root input weight over the whole horizon (scalar, (n_u,) or (n_u, n_u)).
        torque_limit: symmetric drive torque limit |u| ≤ τ in N·m (scalar or (n_u,)), or None.
        solver: back-end name (:func:`parallel_gpc.solvers.make_solver`); default ``"qr"``
            without limits and ``"qr-first:daqp-direct"`` with limits.
        settle_steps: samples recorded after Nmax in modes (a) and (b) (default 400: mode (a)
            comes within 1 mm of B about 3.4·Nmax·Ts after the start on the default robot).
        reach_tolerance: (position m, orientation rad) band around B for the time to reach.
        plant_substeps: RK4 steps per sample of the default plant.
    """

    Nmax: int = 120
    Nmin: int = 10
    k: int = 2
    Ts: float = 0.01
    Qy: object = 1.0
    Qu: object = 1e-6
    torque_limit: object = None
    solver: str | None = None
    settle_steps: int = 400
    reach_tolerance: tuple[float, float] = (1e-4, 1e-3)
    plant_substeps: int = 5

    def __post_init__(self):
        k = _integer("order k", self.k, 1)
        Nmin = _integer("Nmin", self.Nmin, 1)
        Nmax = _integer("Nmax", self.Nmax, 1)
        if not k < Nmin <= Nmax:
            raise InvalidParameterError(f"horizons must satisfy k < Nmin ≤ Nmax; got k = {k}, Nmin = {Nmin}, "
                                        f"Nmax = {Nmax}")
        _integer("settle_steps", self.settle_steps, 0)
        _integer("plant_substeps", self.plant_substeps, 1)
        object.__setattr__(self, "Ts", positive("Ts", self.Ts, " s"))
        tol = tuple(self.reach_tolerance)
        if len(tol) != 2:
            raise InvalidParameterError(
                f"reach_tolerance = {self.reach_tolerance!r} must be (position m, orientation rad)")
        object.__setattr__(self, "reach_tolerance", (positive("reach tolerance (position)", tol[0], " m"),
                                                     positive("reach tolerance (orientation)", tol[1], " rad")))
        if self.torque_limit is not None:
            lim = np.asarray(self.torque_limit, dtype=float)
            if not np.all(np.isfinite(lim)) or np.any(lim <= 0):
                raise InvalidParameterError(f"torque_limit = {self.torque_limit!r} must be finite and > 0 (N·m)")
            if self.solver == "qr":
                raise InvalidParameterError(
                    "solver 'qr' cannot enforce torque limits; use a QP back end such as "
                    f"{DEFAULT_LIMITED_SOLVER!r}, 'osqp-direct' or 'qpsolvers:osqp'")

    @property
    def weights(self) -> Weights:
        return Weights(self.Qy, self.Qu)

    @property
    def solver_name(self) -> str:
        """The back end actually used."""
        if self.solver is not None:
            return self.solver
        return DEFAULT_LIMITED_SOLVER if self.torque_limit is not None else "qr"

    @property
    def duration(self) -> float:
        """Planned move time Nmax·Ts in s."""
        return self.Nmax * self.Ts

    def to_json(self) -> str:
        """The settings as JSON (arrays as lists)."""
        return json.dumps({k: (np.asarray(v).tolist() if isinstance(v, np.ndarray) else v)
                           for k, v in asdict(self).items()})


# ---------------------------------------------------------------------------- one solve
def end_point_problem(model, X, target, N: int, settings: PlanSettings,
                      u_hold: np.ndarray | None = None) -> tuple[LeastSquaresProblem, Prediction]:
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

    Returns:
        (problem, prediction): ``min ‖A v − b‖²`` over v = [u(0) … u(N−1)] − u_hold (N·n_u, N·m).
    """
    A, B, c = model.factorize(X)
    Ad, Bd, cd = discretize_zoh(A, B, c, settings.Ts)
    pred = absolute_prediction(Ad, Bd, cd, model.C, X, Horizons(int(N), int(N) - settings.k, int(N)))
    w = np.tile(target, (settings.k, 1))
    hold = None if u_hold is None else np.tile(u_hold, int(N))
    if hold is not None:  # ŷ = f + G (v + hold)
        pred = replace(pred, f=pred.f + pred.G @ hold, u_base=pred.u_base + hold)
    problem = build_problem(pred, w, settings.weights, model.n_y, model.n_u, settings.torque_limit)
    if hold is not None and problem.lb is not None:
        problem.lb, problem.ub = problem.lb - hold, problem.ub - hold
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
    problem, _ = end_point_problem(model, X, target, N, settings, u_hold)
    backend = make_solver(settings.solver_name) if backend is None else backend
    result = backend.solve(problem, warm_start)
    u = np.asarray(result.v, dtype=float).reshape(int(N), model.n_u)
    return (u if u_hold is None else u + u_hold), result


def deadbeat_inputs(model, X, target, settings: PlanSettings) -> np.ndarray:
    """The dead-beat move: the same end-point criterion with the minimal horizon N = k.

    The comparison case of the paper's "dead-beat spread in time": the end point is reached
    in k samples (unconstrained; Qu as in ``settings``, for the minimum-norm choice).

    Returns:
        (k, n_u) drive torques in N·m.
    """
    free = replace(settings, torque_limit=None, solver="qr")
    u, result = solve_end_point(model, X, target, settings.k, free)
    if not result.ok:  # pragma: no cover - QR does not fail on finite data
        raise SolverError(f"dead-beat solve failed: {result.status} {result.message}")
    return u


# ---------------------------------------------------------------------------- result
@dataclass
class PlanResult:
    """A planned move, as recorded on the plant (row i is sample time t_i = i·Ts).

    Attributes:
        mode: ``"a"``, ``"b"`` or ``"once"``.
        start, target: (n_y,) poses A and B (m, rad).
        t: (K+1,) s. poses, velocities: (K+1, n_y) m, rad and m/s, rad/s.
        u: (K, n_u) drive torques applied over [t_i, t_i+1) in N·m.
        horizon: (K,) horizon N of the plan the input came from (modes a and b: the horizon of
            that step's solve; once: the one plan, so Nmax − i samples remain).
        status: (K,) solve status of each step (``"open-loop"`` for the steps of mode once after
            the single solve, ``"fallback"`` when a receding mode applied the previous plan).
        solve_time: (K,) wall time of each step's model + prediction + solve in s.
        q: (K+1, nq) full configurations for the views, or None (plant without ``q``).
        settings: the settings used.
        saturated: number of samples at which the plant saturated its drives.
        stopped: empty if the plan ran to its end; otherwise why the recording stopped early
            (e.g. the open-loop plant of mode once left the workspace, or :data:`INTERRUPTED`: Ctrl-C),
            the arrays then end there.
        robot: how the result file names the robot (embedded name or absolute URDF path; "" for none).
        angular: (n_y,) bool, the angular output coordinates (rad), or None for the planar
            convention [x, y, ψ].
    """

    mode: str
    start: np.ndarray
    target: np.ndarray
    t: np.ndarray
    poses: np.ndarray
    velocities: np.ndarray
    u: np.ndarray
    horizon: np.ndarray
    status: np.ndarray
    solve_time: np.ndarray
    q: np.ndarray | None
    settings: PlanSettings
    saturated: int = 0
    stopped: str = ""
    robot: str = ""
    angular: np.ndarray | None = None

    @property
    def interrupted(self) -> bool:
        """True if Ctrl-C stopped the plan (the arrays hold the samples applied before)."""
        return self.stopped.startswith(INTERRUPTED)

    @property
    def label(self) -> str:
        return MODE_LABELS.get(self.mode, self.mode)

    def __repr__(self) -> str:
        pos, ang = self.end_error if len(self.t) else (math.nan, math.nan)
        return (f"PlanResult(mode={self.mode!r}, steps={len(self.u)}, end_error=({pos:.3g} m, {ang:.3g} rad), "
                f"peak_torque={self.peak_torque:.4g} N·m, energy={self.energy:.4g} N²·m²·s"
                + (f", stopped={self.stopped!r}" if self.stopped else "") + ")")

    # ------------------------------------------------------------ errors
    def error_norms(self) -> tuple[np.ndarray, np.ndarray]:
        """(K+1,) position error ‖p − p_B‖ in m and orientation error ‖ψ − ψ_B‖ in rad
        (translational and angular output coordinates, see :attr:`angular`)."""
        return pose_error_norms(self.poses - self.target, self.angular)

    @property
    def end_error(self) -> tuple[float, float]:
        """(position m, orientation rad) error to B at the last sample."""
        pos, ang = self.error_norms()
        return float(pos[-1]), float(ang[-1])

    @property
    def arrival_error(self) -> tuple[float, float]:
        """(position m, orientation rad) error to B at the planned arrival t = Nmax·Ts."""
        pos, ang = self.error_norms()
        i = min(self.settings.Nmax, len(pos) - 1)
        return float(pos[i]), float(ang[i])

    @property
    def end_speed(self) -> tuple[float, float]:
        """(m/s, rad/s) platform speed at the last sample."""
        lin, ang = pose_error_norms(self.velocities[-1:], self.angular)
        return float(lin[0]), float(ang[0])

    @property
    def time_to_reach(self) -> float:
        """First time (s) after which the pose stays within ``reach_tolerance`` of B; NaN if
        it is not within the band at the last sample."""
        return self.time_within(*self.settings.reach_tolerance)

    def time_within(self, position_tol: float, orientation_tol: float = math.inf) -> float:
        """First time (s) after which the position error stays ≤ ``position_tol`` (m) and the
        orientation error ≤ ``orientation_tol`` (rad); NaN if not within at the last sample."""
        pos, ang = self.error_norms()
        inside = (pos <= position_tol) & (ang <= orientation_tol)
        if not inside[-1]:
            return math.nan
        outside = np.flatnonzero(~inside)
        return float(self.t[0 if outside.size == 0 else outside[-1] + 1])

    @property
    def overshoot(self) -> float:
        """Largest distance (m) the platform went past B along the direction A → B (0 if never)."""
        d = (self.target - self.start)[:2]
        norm = float(np.linalg.norm(d))
        if norm == 0.0:
            return 0.0
        return float(max(0.0, np.max((self.poses[:, :2] - self.target[:2]) @ (d / norm))))

    @property
    def orientation_excursion(self) -> float:
        """Largest orientation (rad) outside the interval between ψ_A and ψ_B: 0 for a move that
        turns the platform only as far as it must; about 2π for a full spin."""
        if self.poses.shape[1] < 3:
            return 0.0
        lo, hi = sorted((float(self.start[2]), float(self.target[2])))
        psi = self.poses[:, 2]
        return float(max(0.0, np.max(psi - hi), np.max(lo - psi)))

    # ------------------------------------------------------------ effort
    @property
    def energy(self) -> float:
        """Drive energy measure Σ‖u‖²·Ts in N²·m²·s."""
        return float(np.sum(self.u**2) * self.settings.Ts)

    @property
    def peak_torque(self) -> float:
        """max |u| over drives and samples in N·m."""
        return float(np.max(np.abs(self.u))) if self.u.size else 0.0

    def metrics(self) -> dict:
        """Summary numbers (SI units in the key names)."""
        pos, ang = self.end_error
        apos, aang = self.arrival_error
        vlin, vang = self.end_speed
        ok = np.isin(self.status, ("optimal", "unconstrained", "open-loop"))
        solved = self.status != "open-loop"
        return {
            "end_position_error_m": pos,
            "end_orientation_error_rad": ang,
            "arrival_position_error_m": apos,
            "arrival_orientation_error_rad": aang,
            "end_speed_m_s": vlin,
            "end_angular_speed_rad_s": vang,
            "time_to_reach_s": self.time_to_reach,
            "overshoot_m": self.overshoot,
            "orientation_excursion_rad": self.orientation_excursion,
            "energy_N2m2s": self.energy,
            "peak_torque_Nm": self.peak_torque,
            "solves": int(np.sum(solved)),
            "failed_solves": int(np.sum(~ok)),
            "mean_solve_time_s": float(np.mean(self.solve_time[solved])) if solved.any() else math.nan,
            "saturated_steps": int(self.saturated),
            "steps": int(len(self.u)),
        }

    # ------------------------------------------------------------ trajectory
    def trajectory(self) -> SampledTrajectory:
        """The planned trajectory (poses and velocities at t_0 … t_K), usable as reference w."""
        return SampledTrajectory(self.t, self.poses, self.velocities)

    def save(self, path) -> Path:
        """Write a result file (:mod:`parallel_gpc.results`, kind ``"plan"``) that ``parallel-gpc
        view`` and :meth:`SampledTrajectory.load` open: ``t``, ``q`` (if recorded), ``planned``
        (the poses), plus ``velocities``, ``u``, ``horizon``, ``status``, ``solve_time``,
        ``mode``, ``start``, ``target``; the settings in ``meta``."""
        arrays = dict(velocities=self.velocities, u=self.u, horizon=self.horizon, status=self.status.astype(str),
                      solve_time=self.solve_time, mode=np.array(self.mode), start=self.start, target=self.target)
        return save_result(path, self.robot or None, self.t, self.q, planned=self.poses, kind="plan",
                           meta={"settings": json.loads(self.settings.to_json()), "stopped": self.stopped},
                           arrays=arrays)


# ---------------------------------------------------------------------------- planner
def _default_plant(robot, X0, settings: PlanSettings):
    from ..model.plant import ConstrainedPlant

    return ConstrainedPlant(robot, X0, substeps=settings.plant_substeps, torque_limit=robot.torque_limit)


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
        plant: the system the plan is recorded on (``step(u, Ts)``, ``X``, optionally ``q``
            and ``saturated``); default a fresh
            :class:`~parallel_gpc.plant.ConstrainedPlant` at A, at rest, with the robot's own
            drive limits. If given, its pose must be A.
        model: the planner's model (default ``ReducedModel(robot)``).
        progress: show a progress bar over the steps of modes (a) and (b).

    Returns:
        The :class:`PlanResult`: Nmax + settle_steps steps for modes (a) and (b), Nmax for
        once (fewer, with ``stopped`` set, if the plant leaves the workspace).

    Raises:
        InvalidParameterError: unknown mode, bad poses or settings, or a plant not at A.
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
    if settings.torque_limit is not None and np.size(settings.torque_limit) not in (1, n_u):
        raise InvalidParameterError(f"torque_limit has {np.size(settings.torque_limit)} entries; expected a "
                                    f"scalar or ({n_u},) for the {n_u} drives")
    if robot is not None:
        robot.check_pose(A)
        robot.check_pose(B)
    if plant is None:
        plant = _default_plant(robot, np.concatenate([A, np.zeros(n_y)]), settings)
    elif np.max(np.abs(np.asarray(plant.X, dtype=float)[:n_y] - A)) > 1e-6:
        raise InvalidParameterError(f"the plant is at pose {np.round(np.asarray(plant.X)[:n_y], 6).tolist()}, "
                                    f"not at the start pose A = {np.round(A, 6).tolist()}")
    backend = make_solver(settings.solver_name)
    sat0 = getattr(plant, "saturated", 0)
    K = settings.Nmax if mode == "once" else settings.Nmax + settings.settle_steps
    rec = _Recorder(K, n_y, n_u, plant)
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
                      None if robot is None else robot.output_angular)


class _Recorder:
    """Preallocated time histories of one plan; ``steps`` counts the samples applied."""

    def __init__(self, K: int, n_y: int, n_u: int, plant):
        self.plant = plant
        self.X = np.empty((K + 1, 2 * n_y))
        self.u = np.empty((K, n_u))
        self.horizon = np.zeros(K, dtype=int)
        self.status = np.full(K, "", dtype=object)
        self.solve_time = np.zeros(K)
        q0 = getattr(plant, "q", None)
        self.q = None if q0 is None else np.empty((K + 1, len(q0)))
        self.steps = 0
        self.stopped = ""
        self._sample(0)

    def _sample(self, i: int) -> None:
        self.X[i] = self.plant.X
        if self.q is not None:
            self.q[i] = self.plant.q

    def apply(self, i: int, u, N: int, status: str, Ts: float) -> bool:
        """Apply u over one sample; False (and ``stopped`` set) if the plant cannot continue."""
        self.u[i], self.horizon[i], self.status[i] = u, N, status
        try:
            self.plant.step(u, Ts)
        except (AssemblyError, SingularPoseError) as exc:
            self.stopped = f"plant stopped at t = {(i + 1) * Ts:.3f} s: {exc}"
            return False
        self._sample(i + 1)
        self.steps = i + 1
        return True


def _run_open_loop(model, plant, B, settings: PlanSettings, backend, rec: _Recorder) -> None:
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


def _run_receding(model, plant, B, settings: PlanSettings, backend, rec: _Recorder, mode: str,
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
