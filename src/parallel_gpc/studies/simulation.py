"""Closed-loop simulation: GPC controller on a nonlinear plant.

``simulate`` runs the controller against a plant (full constrained model by default), with
optional measurement noise; the plant may carry model mismatch, drive saturation and a
disturbance force. The result holds the time histories, per-step solver statistics and the
metrics table, and saves to ``.npz`` or ``.csv``. Ctrl-C ends the run early and keeps what was
computed (``result.interrupted``).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..gpc.controller import GPCController
from ..gpc.references import Reference, pose_error_norms
from ..errors import AssemblyError, InvalidParameterError, SingularPoseError, ShapeError, writing
from ..results import robot_reference, save_result, saturation_flags
from ..validation import check_allocation, finite_vector, positive


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
        interrupted: True if the run was stopped early (Ctrl-C).
        angular: (n_y,) bool, the angular output coordinates (rad), or None for the planar
            convention [x, y, ψ] (see :func:`~parallel_gpc.gpc.references.pose_error_norms`).
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
    interrupted: bool = False
    angular: np.ndarray | None = None

    @property
    def error(self) -> np.ndarray:
        """(K, n_y) tracking error pose − reference (m, rad)."""
        return self.pose - self.reference

    def metrics(self, skip: float = 0.0) -> dict:
        """Summary numbers (SI): RMS/max position error (m), orientation error (rad), peak torque
        (N·m), mean/max internal-force measure (N·m), mean and p99 step time (s), fallbacks."""
        sel = self.t >= skip
        e = self.error[sel]
        pos, ang = pose_error_norms(e, self.angular)
        return {
            "rms_position_error_m": float(np.sqrt(np.mean(pos**2))),
            "max_position_error_m": float(np.max(pos)),
            "rms_orientation_error_rad": float(np.sqrt(np.mean(ang**2))),
            "max_orientation_error_rad": float(np.max(ang)),
            "peak_torque_Nm": float(np.max(np.abs(self.u))),
            "mean_internal_force_Nm": float(np.mean(self.internal_force)),
            "max_internal_force_Nm": float(np.max(self.internal_force)),
            "mean_step_time_s": float(np.mean(self.step_time)),
            "p99_step_time_s": float(np.percentile(self.step_time, 99)),
            "fallbacks": int(np.sum(self.fallback)),
            "saturated_steps": int(np.sum(self.saturated)),
            "steps": int(len(self.t)),
        }

    def save(self, path) -> Path:
        """Save to ``.npz`` (a result file of :mod:`parallel_gpc.results`: everything, viewable with
        ``parallel-gpc view``) or ``.csv`` (time histories)."""
        path = Path(path)
        if path.suffix == ".csv":
            n_y, n_u = self.pose.shape[1], self.u.shape[1]
            header = (["t"] + [f"ref_{i}" for i in range(n_y)] + [f"pose_{i}" for i in range(n_y)]
                      + [f"vel_{i}" for i in range(n_y)] + [f"u_{i}" for i in range(n_u)]
                      + ["internal_force", "step_time", "solve_time", "status", "fallback"])
            with writing(path, "CSV file"), path.open("w", newline="") as fh:
                wr = csv.writer(fh)
                wr.writerow(header)
                for k in range(len(self.t)):
                    wr.writerow([self.t[k], *self.reference[k], *self.pose[k], *self.velocity[k], *self.u[k],
                                 self.internal_force[k], self.step_time[k], self.solve_time[k],
                                 self.status[k], int(self.fallback[k])])
            return path
        limit = self.meta.get("torque_limit")
        extra = {k: getattr(self, k) for k in ("pose", "velocity", "u", "internal_force", "step_time",
                                               "solve_time", "iterations", "status", "fallback")}
        # (K,) plant clipping flags; "saturated" in a result file means (K, n_u) drive flags
        extra.update(plant_saturated=self.saturated, interrupted=np.array(self.interrupted))
        save_result(path, self.meta.get("robot_file") or None, self.t, self.q, reference=self.reference,
                    saturated=None if limit is None else saturation_flags(self.u, limit, rtol=1e-5),
                    kind="tracking", meta=self.meta, arrays=extra)
        return path


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


def simulate(controller: GPCController, plant, reference: Reference, duration: float,
             noise_std=None, seed: int = 0, progress: bool = True, meta: dict | None = None) -> SimulationResult:
    """Run the closed loop for ``duration`` s at the controller's Ts.

    Args:
        controller: the GPC controller (its model is the controller's, not the plant's).
        plant: a :class:`~parallel_gpc.plant.ConstrainedPlant` or ``ReducedPlant`` (with redundant
            drives, its ``input_matrix()`` gives B_r for the internal-force record).
        reference: the reference motion w(t).
        duration: s.
        noise_std: measurement noise standard deviation on [y, ẏ] (scalar or (2·n_y,)).
        seed: random seed of the noise.
        progress: show a progress bar.
        meta: extra settings stored in the result.
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
    if (controller.n_y, controller.n_u) != (n_y, n_u):
        raise ShapeError(f"controller has {controller.n_y} outputs and {controller.n_u} drives, the plant "
                         f"{robot.name!r} has {n_y} and {n_u}; they must describe the same robot")
    if noise_std is not None:
        noise_std = np.broadcast_to(np.asarray(noise_std, dtype=float), (2 * n_y,)) if np.ndim(noise_std) == 0 \
            else finite_vector("noise_std", noise_std, 2 * n_y)
        if not np.all(np.isfinite(noise_std)) or np.any(noise_std < 0):
            raise InvalidParameterError(f"noise_std = {np.asarray(noise_std).tolist()} must be finite and ≥ 0 "
                                        f"(a scalar or {2 * n_y} values for [y, ẏ])")
    rec = {k: [] for k in ("t", "reference", "pose", "velocity", "u", "q", "step_time",
                           "solve_time", "iterations", "status", "fallback", "saturated")}
    B_rs = []  # (n_y, n_u) B_r per sample with redundant drives: internal force after the loop
    N = controller.horizons.N
    batched = type(reference).window is Reference.window  # else the subclass's own window()
    windows = None
    interrupted = False
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
            info = _step(controller, X, meas, w, noise_std)
            q = np.array(plant.q)
            if n_u > n_y:
                B_rs.append(plant.input_matrix())  # at the state u was computed for
            sat_before = plant.saturated
            plant.step(info.u, Ts)
            rec["t"].append(t)
            rec["reference"].append(pose_t)
            rec["pose"].append(X[:n_y])
            rec["velocity"].append(X[n_y:])
            rec["u"].append(info.u)
            rec["q"].append(q)
            rec["step_time"].append(info.step_time)
            rec["solve_time"].append(info.solve_time)
            rec["iterations"].append(-1 if info.result.iterations is None else info.result.iterations)
            rec["status"].append(info.result.status)
            rec["fallback"].append(info.fallback)
            rec["saturated"].append(plant.saturated > sat_before)
    except KeyboardInterrupt:
        interrupted = True
    if not rec["t"]:
        raise KeyboardInterrupt
    arrays = {k: np.asarray(v) for k, v in rec.items()}
    done = min(len(v) for v in rec.values())  # an interrupt may fall between a sample's records
    arrays = {k: v[:done] for k, v in arrays.items()}
    arrays["internal_force"] = null_space_components(np.asarray(B_rs[:done]), arrays["u"]) if B_rs \
        else np.zeros(done)
    info_meta = {"robot": robot.name, "robot_file": robot_reference(robot), "form": controller.form, "solver": controller.solver,
                 "N": controller.horizons.N, "No": controller.horizons.No, "Nu": controller.horizons.Nu,
                 "Qy": controller.weights.Qy, "Qu": controller.weights.Qu, "Ts": Ts,
                 "torque_limit": controller.torque_limit, **(meta or {})}
    return SimulationResult(**arrays, meta=info_meta, interrupted=interrupted, angular=robot.output_angular)
