"""Closed-loop simulation: GPC controller on a nonlinear plant.

``simulate`` runs the controller against a plant (full constrained model by default), with
optional measurement noise; the plant may carry model mismatch, drive saturation and a
disturbance force. The result holds the time histories, per-step solver statistics and the
metrics table, and saves to ``.npz`` or ``.csv``. A run that ends early keeps what it computed,
with the reason in ``result.stopped``: Ctrl-C (``result.interrupted``), or a closed loop that
diverged (``result.diverged``: the plant or the controller raised one of
:data:`DIVERGENCE_ERRORS` after the first sample, e.g. the platform left the workspace). A
reference that leaves the workspace is refused before the run (:func:`check_reference`).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..gpc import GPCController, check_reference, INTERRUPTED, Reference, pose_error_norms
from ..errors import (
    AssemblyError,
    InvalidParameterError,
    NonFiniteError,
    ShapeError,
    SingularPoseError,
    SolverError,
    writing,
)
from ..limits import Limits
from ..model import OutputSpace
from ..results import robot_reference, save_result, saturation_flags
from ..validation import check_allocation, check_sample_time, finite_vector, positive

#: Errors of the plant or the controller that mean "this closed loop diverged" once it has run:
#: the run stops there and keeps its samples (before the first sample they are raised).
DIVERGENCE_ERRORS = (AssemblyError, SingularPoseError, NonFiniteError, SolverError)
#: How :attr:`SimulationResult.stopped` starts when the closed loop diverged.
DIVERGED = "closed loop diverged"
#: Most reference poses :func:`simulate` assembles before a run (the cheap check).
REFERENCE_CHECKS = 50


@dataclass
class SimulationResult:
    """Time histories of one closed-loop run (row k is sample time t_k).

    Attributes:
        t: (K,) s. reference, pose: (K, n_y) m and rad. velocity: (K, n_y) m/s, rad/s.
        u: (K, n_u) applied drive torques over [t_k, t_k+1) (N·m).
        internal_force: (K,) norm of the drive-torque component in null(B_r) (N·m), the
            "drive fighting" that produces internal force only.
        q: (K, nq) full configurations (for the 3-D view).
        step_time, solve_time: (K,) s. iterations: (K,) (−1 if not reported).
        status: (K,) solver status strings. fallback: (K,) bool. saturated: (K,) bool.
        meta: settings of the run (robot, form, solver, horizons, weights, Ts, …).
        stopped: empty if the run reached its end; otherwise why it stopped early, the arrays
            ending there: ``"interrupted (Ctrl-C) after k of K samples"`` or
            ``"closed loop diverged at t = … s …: position error … m … (cause: Error: message)"``.
        limits: the controller's input :class:`~parallel_gpc.limits.Limits` (the result file's
            per-drive saturation flags mark where |u| reached its torque limit).
        outputs: names and units of the outputs and the drives' unit
            (:class:`~parallel_gpc.model.output_space.OutputSpace`), or None for the planar
            convention [x m, y m, ψ rad] driven in N·m.
        estimate_error: (K, 2 n_y) state estimate − true state, or None (no estimator, or a
            plant that does not know its true state; :func:`~parallel_gpc.studies.loop.run_loop`).
        overruns: steps whose estimate + control time exceeded Ts (run_loop; 0 otherwise).
        solver: (K,) the back end that solved each step (``result.solver``: e.g. ``"qr"`` on a
            step of a ``riccati`` controller whose stage-wise solve failed), or None (a result
            built without it).
        replaced: (K,) bool, True where the stage-wise solve failed and the condensed default
            solved the step (:attr:`~parallel_gpc.gpc.StepInfo.replaced`), or None.
        message: (K,) the solver's message on replaced and fallback steps (why), "" on the
            others, or None.
        nmpc_iterations: (K,) Gauss–Newton iterations of each step (1: the paper's single step;
            the nonlinear form's with ``iterations`` > 1, :attr:`~parallel_gpc.gpc.StepInfo.iterations`),
            or None. nmpc_residual: (K,) the last Gauss–Newton step's relative size
            (:attr:`~parallel_gpc.gpc.StepInfo.residual`; NaN after a single step), or None.
            budget_hit: (K,) bool, True where the time budget stopped the iterations, or None.
            nmpc_stop: (K,) why each step's iterations ended (:attr:`~parallel_gpc.gpc.StepInfo.stop`), or None.
    """

    t: np.ndarray
    reference: np.ndarray
    pose: np.ndarray
    velocity: np.ndarray
    u: np.ndarray
    internal_force: np.ndarray
    q: np.ndarray
    step_time: np.ndarray
    solve_time: np.ndarray
    iterations: np.ndarray
    status: np.ndarray
    fallback: np.ndarray
    saturated: np.ndarray
    meta: dict = field(default_factory=dict)
    stopped: str = ""
    limits: Limits = field(default_factory=Limits)
    estimate_error: np.ndarray | None = None
    overruns: int = 0
    outputs: OutputSpace | None = None
    solver: np.ndarray | None = None
    replaced: np.ndarray | None = None
    message: np.ndarray | None = None
    nmpc_iterations: np.ndarray | None = None
    nmpc_residual: np.ndarray | None = None
    budget_hit: np.ndarray | None = None
    nmpc_stop: np.ndarray | None = None

    @property
    def angular(self) -> np.ndarray | None:
        """(n_y,) bool, the angular output coordinates (rad), or None for the planar convention
        (see :func:`~parallel_gpc.gpc.references.pose_error_norms`)."""
        return None if self.outputs is None else np.array(self.outputs.angular)

    @property
    def output_space(self) -> OutputSpace:
        """:attr:`outputs`, or the planar convention's when the result has none."""
        return self.outputs or OutputSpace.from_angular(None, self.pose.shape[1])

    @property
    def interrupted(self) -> bool:
        """True if Ctrl-C stopped the run (the arrays hold the samples before)."""
        return self.stopped.startswith(INTERRUPTED)

    @property
    def diverged(self) -> bool:
        """True if the closed loop diverged (the arrays hold the samples up to there)."""
        return self.stopped.startswith(DIVERGED)

    @property
    def outcome(self) -> str:
        """``"ok"`` (ran to its end), ``"interrupted"`` or ``"diverged"``."""
        return "interrupted" if self.interrupted else "diverged" if self.diverged else "ok"

    @property
    def error(self) -> np.ndarray:
        """(K, n_y) tracking error pose − reference (m, rad)."""
        return self.pose - self.reference

    def metrics(self, skip: float = 0.0) -> dict:
        """Summary numbers (SI): RMS/max position error (m), orientation error (rad), peak drive
        effort and mean/max internal-force measure (in the drives' unit: N·m revolute, N
        prismatic; :attr:`OutputSpace.drive_unit`), mean and p99 step time (s), fallbacks."""
        sel = self.t >= skip
        e = self.error[sel]
        pos, ang = pose_error_norms(e, self.angular)
        extra = {"deadline_overruns": int(self.overruns)} if "deadline_overruns" in self.meta else {}
        if self.estimate_error is not None:
            est_pos, est_ang = pose_error_norms(self.estimate_error[sel, :e.shape[1]], self.angular)
            extra |= {"rms_estimate_position_error_m": float(np.sqrt(np.mean(est_pos**2))),
                     "rms_estimate_orientation_error_rad": float(np.sqrt(np.mean(est_ang**2)))}
        return {
            "rms_position_error_m": float(np.sqrt(np.mean(pos**2))),
            "max_position_error_m": float(np.max(pos)),
            "rms_orientation_error_rad": float(np.sqrt(np.mean(ang**2))),
            "max_orientation_error_rad": float(np.max(ang)),
            "peak_drive_effort": float(np.max(np.abs(self.u))),
            "mean_internal_force": float(np.mean(self.internal_force)),
            "max_internal_force": float(np.max(self.internal_force)),
            "mean_step_time_s": float(np.mean(self.step_time)),
            "p99_step_time_s": float(np.percentile(self.step_time, 99)),
            "fallbacks": int(np.sum(self.fallback)),
            "replaced_steps": int(np.sum(self.replaced)) if self.replaced is not None else 0,
            "saturated_steps": int(np.sum(self.saturated)),
            "steps": int(len(self.t)),
            **extra,
        }

    def solver_counts(self) -> dict[str, int]:
        """Steps solved by each back end, most used first (empty without :attr:`solver`)."""
        if self.solver is None:
            return {}
        names, counts = np.unique(np.asarray(self.solver, dtype=str), return_counts=True)
        return {str(n): int(c) for n, c in sorted(zip(names, counts), key=lambda nc: (-nc[1], nc[0]))}

    def solver_summary(self) -> str:
        """One line: the steps each back end solved, the stage-wise steps the condensed default
        replaced and the fallbacks, with the first such step's message, e.g. ``"riccati 499, qr 1;
        1 replaced (first at t = 0.120 s: riccati failed (…); solved by QR); 0 fallbacks"``."""
        counts = self.solver_counts()
        used = ", ".join(f"{name} {count}" for name, count in counts.items()) or "not recorded"
        replaced = np.zeros(len(self.t), bool) if self.replaced is None else np.asarray(self.replaced, bool)
        parts = [used, f"{int(replaced.sum())} replaced", f"{int(np.sum(self.fallback))} fallbacks"]
        first = np.flatnonzero(replaced | np.asarray(self.fallback, bool))
        if first.size and self.message is not None:
            k = int(first[0])
            parts.append(f"first at t = {self.t[k]:.3f} s: {self.message[k]}")
        nmpc = self.iterations_summary()
        return "; ".join(parts + ([nmpc] if nmpc else []))

    def iterations_summary(self) -> str:
        """One phrase on the nonlinear form's Gauss–Newton iterations when the run iterated (a step
        of more than one, or a time budget hit), else "": mean and largest count, the steps by why their
        iterations ended (:attr:`nmpc_stop`) and the largest last relative step (:attr:`nmpc_residual`), e.g.
        ``"Gauss–Newton iterations 3.28 a step (max 5), stopped: converged 300; last step ≤ 3.1e-09 relative"``."""
        if self.nmpc_iterations is None or not len(self.nmpc_iterations):
            return ""
        its = np.asarray(self.nmpc_iterations)
        hits = 0 if self.budget_hit is None else int(np.sum(self.budget_hit))
        if its.max() <= 1 and not hits:
            return ""
        stops = ""
        if self.nmpc_stop is not None:
            names, counts = np.unique(np.asarray(self.nmpc_stop, dtype=str), return_counts=True)
            stops = ", stopped: " + ", ".join(f"{names[i]} {counts[i]}" for i in np.lexsort((names, -counts)))
        res = np.asarray(self.nmpc_residual, dtype=float) if self.nmpc_residual is not None else np.full(len(its), np.nan)
        last = f"last step ≤ {np.nanmax(res):.2g} relative" if np.isfinite(res).any() else "no second linearization"
        return f"Gauss–Newton iterations {its.mean():.2f} a step (max {int(its.max())}){stops}; {last}"

    def save(self, path) -> Path:
        """Save to ``.npz`` (a result file of :mod:`parallel_gpc.results`: everything, viewable with
        ``parallel-gpc view``) or ``.csv`` (time histories)."""
        path = Path(path)
        if path.suffix == ".csv":
            n_y, n_u = self.pose.shape[1], self.u.shape[1]
            header = (["t"] + [f"ref_{i}" for i in range(n_y)] + [f"pose_{i}" for i in range(n_y)]
                      + [f"vel_{i}" for i in range(n_y)] + [f"u_{i}" for i in range(n_u)]
                      + ["internal_force", "step_time", "solve_time", "status", "fallback", "solver", "replaced"])
            with writing(path, "CSV file"), path.open("w", newline="") as fh:
                wr = csv.writer(fh)
                wr.writerow(header)
                for k in range(len(self.t)):
                    wr.writerow([self.t[k], *self.reference[k], *self.pose[k], *self.velocity[k], *self.u[k],
                                 self.internal_force[k], self.step_time[k], self.solve_time[k],
                                 self.status[k], int(self.fallback[k]),
                                 "" if self.solver is None else self.solver[k],
                                 "" if self.replaced is None else int(self.replaced[k])])
            return path
        extra = {k: getattr(self, k) for k in ("pose", "velocity", "u", "internal_force", "step_time",
                                               "solve_time", "iterations", "status", "fallback", "solver",
                                               "replaced", "message", "nmpc_iterations", "nmpc_residual",
                                               "budget_hit", "nmpc_stop") if getattr(self, k) is not None}
        # (K,) plant clipping flags; "saturated" in a result file means (K, n_u) drive flags
        extra.update(plant_saturated=self.saturated, interrupted=np.array(self.interrupted),
                     diverged=np.array(self.diverged))
        save_result(path, self.meta.get("robot_file") or None, self.t, self.q, reference=self.reference,
                    saturated=saturation_flags(self.u, self.limits, rtol=1e-5),
                    kind="tracking", meta={**self.meta, "stopped": self.stopped}, arrays=extra)
        return path


#: What a closed loop records of each controller step (:func:`step_record`).
STEP_RECORD = ("solve_time", "iterations", "status", "fallback", "solver", "replaced", "message", "nmpc_iterations",
               "nmpc_residual", "budget_hit", "nmpc_stop")


def step_record(info) -> dict:
    """The :data:`STEP_RECORD` of one :class:`~parallel_gpc.gpc.StepInfo`: solve time (s), the back
    end's iterations (−1 if not reported), status, fallback, the back end that solved the step, whether
    it replaced a failed stage-wise solve, the solver's message on such and fallback steps, and the
    nonlinear form's Gauss–Newton iterations, last relative step, whether the time budget stopped them and why
    they ended."""
    result = info.result
    return {"solve_time": info.solve_time, "iterations": -1 if result.iterations is None else result.iterations,
            "status": result.status, "fallback": info.fallback, "solver": result.solver, "replaced": info.replaced,
            "message": result.message if info.replaced or info.fallback else "", "nmpc_iterations": info.iterations,
            "nmpc_residual": info.residual, "budget_hit": info.budget_hit, "nmpc_stop": info.stop}


def null_space_component(B_r: np.ndarray, u: np.ndarray) -> float:
    """‖(I − B_r⁺ B_r) u‖: the part of u that only produces internal force (N·m). One pair; the
    simulation records all samples at once with :func:`null_space_components`."""
    return float(np.linalg.norm(u - np.linalg.pinv(B_r) @ (B_r @ u)))


def null_space_components(B_r: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(K,) :func:`null_space_component` of K pairs at once (one batched SVD).

    Args:
        B_r: (K, n_y, n_u) input matrices. u: (K, n_u) drive torques (N·m).
    """
    _, s, Vt = np.linalg.svd(B_r, full_matrices=False)
    keep = s > 1e-15 * s[:, :1]  # all False where s_max = 0: V_r is empty, the whole u counts
    V = Vt * keep[:, :, None]
    return np.linalg.norm(u - np.einsum("kri,kr->ki", V, np.einsum("kri,ki->kr", V, u)), axis=1)


#: samples whose reference windows are evaluated in one vectorized call
_WINDOW_CHUNK = 500


def _windows(reference: Reference, k0: int, count: int, Ts: float, N: int) -> np.ndarray:
    """(count, N + 1, n_y) poses at t_k + j·Ts (t_k = k·Ts, k = k0 … k0 + count − 1, j = 0 … N):
    row 0 the reference at t_k, rows 1… the window ``reference.window(t_k, Ts, N)``, in one
    :meth:`~parallel_gpc.gpc.references.Reference.sample` call (the same times, to the bit)."""
    t = np.arange(k0, k0 + count) * Ts
    times = t[:, None] + Ts * np.arange(0, N + 1)
    return reference.sample(times.ravel()).reshape(count, N + 1, -1)


def _step(controller: GPCController, X: np.ndarray, meas: np.ndarray, w: np.ndarray, noise_std):
    """controller.step on the measurement; an error caused by the noise names ``noise_std``."""
    try:
        return controller.step(meas, w)
    except (AssemblyError, SingularPoseError) as exc:
        if noise_std is None or np.array_equal(X, meas):
            raise
        n_y = controller.n_y
        raise type(exc)(f"measurement noise noise_std = {np.asarray(noise_std).tolist()} moved the measured pose "
                        f"from {np.round(X[:n_y], 6).tolist()} to {np.round(meas[:n_y], 6).tolist()}, where the "
                        f"controller's model fails: {exc}") from None


def divergence_message(exc: Exception, t: float, rec: dict, K: int, angular) -> str:
    """The :attr:`SimulationResult.stopped` text of a run that raised ``exc`` in the step from t_k = ``t``."""
    n = len(rec["t"])
    last = np.asarray(rec["pose"][-1]) - np.asarray(rec["reference"][-1])
    position = float(pose_error_norms(last[None, :], angular)[0][0])
    return (f"{DIVERGED} at t = {t:.6g} s after {n} of {K} samples: position error {position:.3g} m at "
            f"t = {rec['t'][-1]:.6g} s (cause: {type(exc).__name__}: {' '.join(str(exc).split())})")


def run_meta(controller: GPCController, robot) -> dict:
    """The settings a closed-loop result records: robot, form, solver, horizons, weights, Ts, limits, and
    an iterated nonlinear form's iterations, tolerance and time budget (s, or None)."""
    H, W, s = controller.horizons, controller.weights, controller.settings
    iterated = {} if s.iterations == 1 else {"iterations": s.iterations, "tolerance": s.tolerance,
                                             "time_budget": s.time_budget}
    return {"robot": robot.name, "robot_file": robot_reference(robot), "form": controller.form,
            "solver": controller.solver, "N": H.N, "No": H.No, "Nu": H.Nu, "Qy": W.Qy, "Qu": W.Qu,
            "Ts": controller.Ts, "limits": controller.limits.to_dict(), **iterated}


def simulate(controller: GPCController, plant, reference: Reference, duration: float,
             noise_std=None, seed: int = 0, progress: bool = True, meta: dict | None = None,
             check: bool = True) -> SimulationResult:
    """Run the closed loop for ``duration`` s at the controller's Ts.

    Args:
        controller: the GPC controller (its model is the controller's, not the plant's).
        plant: a :class:`~parallel_gpc.plant.ConstrainedPlant` or ``ReducedPlant`` built with the
            controller's Ts (checked once, here; with redundant drives, its ``input_matrix()``
            gives B_r for the internal-force record).
        reference: the reference motion w(t).
        duration: s.
        noise_std: measurement noise standard deviation on [y, ẏ] (scalar or (2·n_y,)).
        seed: random seed of the noise.
        progress: show a progress bar.
        meta: extra settings stored in the result.
        check: assemble the reference at up to :data:`REFERENCE_CHECKS` sample times before the
            run (:func:`~parallel_gpc.gpc.robot_references.check_reference`, assembly only);
            False when the caller checked it already (``run_tracking`` checks conditioning too).

    Returns:
        The :class:`SimulationResult`; ``stopped`` says why it ended early, if it did. Ctrl-C, or
        one of :data:`DIVERGENCE_ERRORS` raised by the controller or the plant after the first
        sample, ends the run and keeps the samples so far (a step whose plant integration fails
        still records its state and input).

    Raises:
        UnreachablePoseError: the reference leaves the workspace (``check``).
        KeyboardInterrupt: Ctrl-C before the first sample.
        AssemblyError, SingularPoseError, NonFiniteError, SolverError: the controller fails at
            the initial state, or the plant within the first sample (no run to keep: the
            settings, e.g. a force or Ts, are at fault).
    """
    Ts = controller.Ts
    duration = positive("duration", duration, " s")
    K = int(round(duration / Ts))
    if K < 1:
        raise InvalidParameterError(f"duration = {duration:g} s is shorter than one sample Ts = {Ts:g} s; the run "
                                    "needs duration ≥ Ts (reduce Ts or lengthen the run)")
    rng = np.random.default_rng(seed)
    robot = plant.robot
    n_y, n_u = robot.n_y, robot.n_u
    check_allocation(f"the record of {K} samples (duration {duration:g} s / Ts {Ts:g} s)",
                     K * (robot.model.nq + 3 * n_y + 2 * n_u + 16), "shorten the run or increase Ts")
    check_sample_time(plant, Ts, "plant", "the controller's")
    if (controller.n_y, controller.n_u) != (n_y, n_u):
        raise ShapeError(f"controller has {controller.n_y} outputs and {controller.n_u} drives, the plant "
                         f"{robot.name!r} has {n_y} and {n_u}; they must describe the same robot")
    if noise_std is not None:
        noise_std = np.broadcast_to(np.asarray(noise_std, dtype=float), (2 * n_y,)) if np.ndim(noise_std) == 0 \
            else finite_vector("noise_std", noise_std, 2 * n_y)
        if not np.all(np.isfinite(noise_std)) or np.any(noise_std < 0):
            raise InvalidParameterError(f"noise_std = {np.asarray(noise_std).tolist()} must be finite and ≥ 0 "
                                        f"(a scalar or {2 * n_y} values for [y, ẏ])")
    if check:
        ks = np.unique(np.linspace(0, K - 1, min(K, REFERENCE_CHECKS)).round())
        check_reference(robot, reference, ks * Ts, None)
    rec = {k: [] for k in ("t", "reference", "pose", "velocity", "u", "q", "step_time", *STEP_RECORD, "saturated")}
    B_rs = []  # (n_y, n_u) B_r per sample with redundant drives: internal force after the loop
    N = controller.horizons.N
    batched = type(reference).window is Reference.window  # else the subclass's own window()
    windows = None
    stopped = ""
    try:
        for k in tqdm(range(K), disable=not progress, desc=f"{controller.form} GPC", unit="step", leave=False):
            t = k * Ts
            if batched and k % _WINDOW_CHUNK == 0:
                windows = _windows(reference, k, min(_WINDOW_CHUNK, K - k), Ts, N)
            X = plant.X
            meas = X if noise_std is None else X + rng.normal(0.0, 1.0, X.shape) * noise_std
            if batched:
                rows = windows[k % _WINDOW_CHUNK]
                w, pose_t = rows[1:], rows[0]
            else:
                w, pose_t = reference.window(t, Ts, N), reference.pose(t)
            try:
                info = _step(controller, X, meas, w, noise_std)
                q = np.array(plant.q)
                B_r = plant.input_matrix() if n_u > n_y else None  # at the state u was computed for
            except DIVERGENCE_ERRORS as exc:  # no input for t_k: the samples before t_k are the run
                if not rec["t"]:
                    raise
                stopped = divergence_message(exc, t, rec, K, robot.output_angular)
                break
            sat_before = plant.saturated
            failure = None
            try:
                plant.step(info.u)
            except DIVERGENCE_ERRORS as exc:  # the state at t_k and the input applied from it are a sample
                if k == 0:  # within the first sample: the input (e.g. a force) is at fault, not a run
                    raise
                failure = exc
            if B_r is not None:
                B_rs.append(B_r)
            rec["t"].append(t)
            rec["reference"].append(pose_t)
            rec["pose"].append(X[:n_y])
            rec["velocity"].append(X[n_y:])
            rec["u"].append(info.u)
            rec["q"].append(q)
            rec["step_time"].append(info.step_time)
            for key, value in step_record(info).items():
                rec[key].append(value)
            rec["saturated"].append(plant.saturated > sat_before)
            if failure is not None:
                stopped = divergence_message(failure, t, rec, K, robot.output_angular)
                break
    except KeyboardInterrupt:
        stopped = f"{INTERRUPTED} after {min(len(v) for v in rec.values())} of {K} samples"
    if not rec["t"]:
        raise KeyboardInterrupt
    arrays = {k: np.asarray(v) for k, v in rec.items()}
    done = min(len(v) for v in rec.values())  # an interrupt may fall between a sample's records
    arrays = {k: v[:done] for k, v in arrays.items()}
    arrays["internal_force"] = null_space_components(np.asarray(B_rs[:done]), arrays["u"]) if B_rs \
        else np.zeros(done)
    info_meta = {**run_meta(controller, robot), **(meta or {})}
    return SimulationResult(**arrays, meta=info_meta, stopped=stopped, outputs=robot.output_space,
                            limits=controller.limits)
