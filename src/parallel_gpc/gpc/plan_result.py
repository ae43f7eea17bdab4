"""The outcome of a planned move: recorded time histories, metrics, result file and reference w."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import AssemblyError, SingularPoseError
from ..model import OutputSpace, effort_integral_unit
from ..results import save_result
from .references import SampledTrajectory, pose_error_norms
from .plan_settings import INTERRUPTED, MODE_LABELS, PlanSettings


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
        outputs: names and units of the outputs and the drives' unit
            (:class:`~parallel_gpc.model.output_space.OutputSpace`), or None for the planar
            convention [x m, y m, ψ rad] driven in N·m.
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
    outputs: OutputSpace | None = None

    @property
    def angular(self) -> np.ndarray | None:
        """(n_y,) bool, the angular output coordinates (rad), or None for the planar convention."""
        return None if self.outputs is None else np.array(self.outputs.angular)

    @property
    def interrupted(self) -> bool:
        """True if Ctrl-C stopped the plan (the arrays hold the samples applied before)."""
        return self.stopped.startswith(INTERRUPTED)

    @property
    def label(self) -> str:
        return MODE_LABELS.get(self.mode, self.mode)

    def __repr__(self) -> str:
        pos, ang = self.end_error if len(self.t) else (math.nan, math.nan)
        space = self.output_space
        return (f"PlanResult(mode={self.mode!r}, steps={len(self.u)}, end_error=({pos:.3g} m, {ang:.3g} rad), "
                f"peak_drive_effort={self.peak_drive_effort:.4g} {space.drive_unit}, "
                f"effort_integral={self.effort_integral:.4g} {space.effort_unit}"
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
    def output_space(self) -> OutputSpace:
        """:attr:`outputs`, or the planar convention's when the plan has none."""
        return self.outputs or OutputSpace.from_angular(None, self.poses.shape[1])

    @property
    def overshoot(self) -> float:
        """Largest distance (m) the platform went past B along the direction A → B in the
        translational outputs (0 if never)."""
        lin = self.output_space.translational
        d = (self.target - self.start)[lin]
        norm = float(np.linalg.norm(d))
        if norm == 0.0:
            return 0.0
        return float(max(0.0, np.max((self.poses[:, lin] - self.target[lin]) @ (d / norm))))

    @property
    def orientation_excursion(self) -> float:
        """Largest excursion (rad) of an angular output outside the interval between its values
        at A and B: 0 for a move that turns the platform only as far as it must; about 2π for a
        full spin; 0 without angular outputs."""
        excursion = 0.0
        for i in self.output_space.rotational:
            lo, hi = sorted((float(self.start[i]), float(self.target[i])))
            psi = self.poses[:, i]
            excursion = max(excursion, float(np.max(psi - hi)), float(np.max(lo - psi)))
        return excursion

    # ------------------------------------------------------------ effort
    @property
    def effort_integral(self) -> float:
        """The effort integral ∫‖u‖² dt = Σ‖u‖²·Ts of the zero-order-held inputs, in N²·m²·s
        (revolute drives; N²·s prismatic: :attr:`OutputSpace.effort_unit`). A measure of how
        hard the drives work, not an energy in J."""
        return float(np.sum(self.u**2) * self.settings.Ts)

    @property
    def peak_drive_effort(self) -> float:
        """max |u| over drives and samples: N·m for revolute drives, N for prismatic ones."""
        return float(np.max(np.abs(self.u))) if self.u.size else 0.0

    def metrics(self) -> dict:
        """Summary numbers (SI units in the key names; ``effort_integral`` in
        :attr:`OutputSpace.effort_unit`, ``peak_drive_effort`` in N·m for revolute drives and N
        for prismatic ones)."""
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
            "effort_integral": self.effort_integral,
            "peak_drive_effort": self.peak_drive_effort,
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



class PlanRecorder:
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
            self.plant.step(u)
        except (AssemblyError, SingularPoseError) as exc:
            self.stopped = f"plant stopped at t = {(i + 1) * Ts:.3f} s: {exc}"
            return False
        self._sample(i + 1)
        self.steps = i + 1
        return True


def _fmt(value: float, spec: str = ".3g") -> str:
    return "not reached" if isinstance(value, float) and math.isnan(value) else format(value, spec)


def plan_table(results: list[PlanResult], drive_unit: str = "N·m") -> str:
    """An aligned text table comparing planned moves, one column per result; orientation rows
    only when the outputs have angles.

    Args:
        results: the :class:`PlanResult` s to compare (the first one's reach tolerance is used).
        drive_unit: ``"N·m"`` (revolute drives) or ``"N"`` (prismatic), for the effort rows.
    """
    tol_p, tol_a = results[0].settings.reach_tolerance
    angular = any(r.angular is None or np.any(r.angular) for r in results)
    rows = [("end-point error, position [m]", lambda r: _fmt(r.end_error[0], ".2e"))]
    if angular:
        rows += [("end-point error, orientation [deg]", lambda r: _fmt(math.degrees(r.end_error[1]), ".2e")),
                 ("error at t = Nmax·Ts [m, deg]",
                  lambda r: f"{r.arrival_error[0]:.2e}, {math.degrees(r.arrival_error[1]):.2e}"),
                 ("end speed [m/s, deg/s]", lambda r: f"{r.end_speed[0]:.2e}, {math.degrees(r.end_speed[1]):.2e}"),
                 (f"time to reach B ±{tol_p:g} m, ±{math.degrees(tol_a):.2g}° [s]",
                  lambda r: _fmt(r.time_to_reach, ".3f"))]
    else:
        rows += [("error at t = Nmax·Ts [m]", lambda r: f"{r.arrival_error[0]:.2e}"),
                 ("end speed [m/s]", lambda r: f"{r.end_speed[0]:.2e}"),
                 (f"time to reach B ±{tol_p:g} m [s]", lambda r: _fmt(r.time_to_reach, ".3f"))]
    rows += [("time to within 1 mm of B [s]", lambda r: _fmt(r.time_within(1e-3), ".3f")),
             ("overshoot past B along A→B [m]", lambda r: f"{r.overshoot:.2e}")]
    if angular:
        rows.append(("rotation outside [A, B] (spin) [deg]", lambda r: f"{math.degrees(r.orientation_excursion):.3g}"))
    rows += [(f"effort integral ∫‖u‖² dt [{effort_integral_unit(drive_unit)}]",
              lambda r: _fmt(r.effort_integral, ".4g")),
             (f"peak drive effort [{drive_unit}]", lambda r: _fmt(r.peak_drive_effort, ".4g")),
             ("recorded duration [s]", lambda r: f"{r.t[-1]:.2f}"),
             ("solves (failed)", lambda r: f"{r.metrics()['solves']} ({r.metrics()['failed_solves']})"),
             ("mean solve time [ms]", lambda r: f"{1000 * r.metrics()['mean_solve_time_s']:.2f}")]
    table = [(label, [get(r) for r in results]) for label, get in rows]
    headers = [r.label for r in results]
    lw = max(len(label) for label, _ in table)
    widths = [max(len(h), *(len(vals[i]) for _, vals in table)) for i, h in enumerate(headers)]
    lines = ["  " + " " * lw + "  " + "  ".join(h.ljust(w) for h, w in zip(headers, widths))]
    lines += ["  " + label.ljust(lw) + "  " + "  ".join(v.ljust(w) for v, w in zip(vals, widths)) for label, vals in table]
    return "\n".join(lines)
