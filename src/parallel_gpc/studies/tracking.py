"""Tracking experiments: the paper's Fig. 2 comparison as one library call.

``run_tracking(TrackingSettings(...), forms)`` builds the controller's model and the plant
(with optional mass mismatch, noise, disturbance force, drive saturation), runs each GPC form on
the reference and returns the results; ``metrics_table`` formats them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..gpc.controller import FORMS, GPCController
from ..model.dynamics import ReducedModel
from ..errors import InvalidParameterError
from ..model.plant import ConstrainedPlant
from ..gpc.prediction import Horizons
from ..gpc.references import PATH_KINDS, Hold, Reference, hold_pose_for, path_for
from ..model.robot import DEFAULT_ROBOT, ParallelRobot
from .simulation import SimulationResult, simulate
from ..gpc.criterion import Weights


@dataclass(frozen=True)
class TrackingSettings:
    """Settings of a tracking run (SI units).

    Attributes:
        robot: embedded robot name or path.
        Ts: sample time in s (default 2 ms).
        N, No, Nu: horizons in samples (Nu None = N).
        Qy, Qu: square-root weights (paper Fig. 2: Qy = 1, Qu = 0).
        solver: back-end name or None (QR without limits, QR-first + ProxQP with limits).
        torque_limit: drive torque limit in N·m for the controller and the plant, or None.
        plant_torque_limit: drive saturation of the plant alone: ``"controller"`` (= torque_limit),
            ``"robot"`` (the limits in the robot file), a value in N·m, or None (no saturation).
        du_limit: increment limit in N·m per sample (incremental forms), or None.
        disturbance_gain: α ∈ [0, 1] of the state-disturbance estimate, the same for every form
            (so that form and estimator effects are never confounded); 0 = no estimator;
            None (default): each controller's own default (0 absolute, 0.5 incremental forms),
            shown in the table's ``est. α`` column.
        mass_scale: plant masses / model masses (model mismatch), 1 = exact model.
        noise_std: measurement noise on [y, ẏ] (m, rad, m/s, rad/s), 0 = none.
        platform_force: constant disturbance on the platform coordinates (N, N·m; n_y values,
            all zeros = none).
        reference: "auto" (the S-curve for planar [x, y, ψ] outputs, else the helix), "s-curve",
            "helix", "hold" or a Reference object; duration: run length in s (default: motion + 0.2 s).
        s_curve_duration: time of the path's motion (S-curve or helix) in s.
        hold_pose: (n_y,) target of the "hold" reference (m, rad); None: near home
            (:func:`~parallel_gpc.gpc.references.hold_pose_for`).
        seed: seed of the measurement noise.
    """

    robot: str = DEFAULT_ROBOT
    Ts: float = 0.002
    N: int = 20
    No: int = 0
    Nu: int | None = None
    Qy: float = 1.0
    Qu: float = 0.0
    solver: str | None = None
    torque_limit: float | None = None
    du_limit: float | None = None
    disturbance_gain: float | None = None
    mass_scale: float = 1.0
    noise_std: float = 0.0
    platform_force: tuple[float, ...] = (0.0, 0.0, 0.0)
    reference: str = "auto"
    duration: float | None = None
    s_curve_duration: float = 2.0
    hold_pose: tuple[float, ...] | None = None
    seed: int = 0
    plant_torque_limit: float | str | None = "controller"
    extra: dict = field(default_factory=dict)

    def make_reference(self, robot: ParallelRobot) -> Reference:
        if isinstance(self.reference, Reference):
            return self.reference
        if self.reference == "hold":
            pose = hold_pose_for(robot.home_pose, robot.output_angular) if self.hold_pose is None else self.hold_pose
            return Hold(tuple(pose))
        if self.reference not in PATH_KINDS:
            raise InvalidParameterError(f"reference {self.reference!r} is not one of {[*PATH_KINDS, 'hold']}")
        return path_for(self.reference, robot.home_pose, robot.output_angular, self.s_curve_duration)

    def plant_limit(self, robot: ParallelRobot):
        """The plant's drive saturation: None, a value in N·m or the robot's (n_u,) limits."""
        if isinstance(self.plant_torque_limit, str):
            if self.plant_torque_limit not in ("controller", "robot"):
                raise InvalidParameterError(f"plant_torque_limit {self.plant_torque_limit!r} is not 'controller', "
                                            f"'robot', a value in N·m or None")
            return self.torque_limit if self.plant_torque_limit == "controller" else robot.torque_limit
        return self.plant_torque_limit

    @property
    def run_duration(self) -> float:
        if self.duration is not None:
            return float(self.duration)
        return 2.0 if self.reference == "hold" else self.s_curve_duration + 0.2


def run_tracking(settings: TrackingSettings, forms=("absolute", "nonlinear"), progress: bool = True,
                 robot: ParallelRobot | None = None) -> dict[str, SimulationResult]:
    """Run each GPC form on the reference with the plant of ``settings``; returns results by form.

    A form whose closed loop diverges keeps its samples up to there (``result.diverged``) and the
    next form runs (each form is an independent run); Ctrl-C keeps the forms finished so far and
    the samples of the current one, and stops.
    """
    for form in forms:
        if form not in FORMS:
            raise InvalidParameterError(f"form {form!r} is not one of {FORMS}")
    if settings.du_limit is not None and "absolute" in forms:
        raise InvalidParameterError(
            f"du_limit = {settings.du_limit!r} N·m per sample applies to the incremental forms only; the absolute "
            f"form has no increments (forms asked: {list(forms)}; use 'incremental' and/or 'nonlinear')")
    robot = robot or ParallelRobot.load(settings.robot)
    plant_robot = robot if settings.mass_scale == 1.0 else robot.with_mass_scale(settings.mass_scale)
    reference = settings.make_reference(robot)
    start = reference.pose(0.0)
    if settings.reference == "hold":
        start = robot.home_pose
    results = {}
    for form in forms:
        ctrl = GPCController(
            ReducedModel(robot), settings.Ts, Horizons(settings.N, settings.No, settings.Nu),
            Weights(settings.Qy, settings.Qu), form=form, solver=settings.solver,
            torque_limit=settings.torque_limit, du_limit=settings.du_limit,
            disturbance_gain=settings.disturbance_gain,
        )
        plant = ConstrainedPlant(plant_robot, np.concatenate([start, np.zeros(robot.n_y)]),
                                 torque_limit=settings.plant_limit(robot),
                                 platform_force=settings.platform_force if any(settings.platform_force) else None)
        try:
            res = simulate(ctrl, plant, reference, settings.run_duration, seed=settings.seed,
                           noise_std=settings.noise_std or None, progress=progress,
                           meta={"mass_scale": settings.mass_scale, "noise_std": settings.noise_std,
                                 "disturbance_gain": ctrl.disturbance_gain,
                                 "platform_force": list(settings.platform_force)})
        except KeyboardInterrupt:  # interrupted before this form's first step: keep the earlier forms
            if not results:
                raise
            break
        results[form] = res
        if res.interrupted:
            break
    return results


def metrics_table(results: dict[str, SimulationResult], drive_unit: str = "N·m") -> str:
    """A text table of the tracking metrics by form (position error in mm, orientation error in
    mrad — the norm of the angular output errors, ψ on a planar robot —, drive effort in
    ``drive_unit``, step times in ms), with the gain α of the disturbance estimate each form ran with.

    Args:
        results: simulation results by form name.
        drive_unit: unit of the drive efforts u (``ParallelRobot.drive_unit``: "N·m" for revolute
            drives, "N" for prismatic ones).
    """
    unit = f"[{drive_unit}]"
    head = (f"{'form':<20} {'est. α':>6} {'rms pos':>9} {'max pos':>9} {'rms ang':>9} {'max ang':>9} {'peak u':>8} "
            f"{'int. f':>8} {'mean step':>9} {'p99 step':>9} {'fallb.':>6}")
    units = (f"{'':<20} {'':>6} {'[mm]':>9} {'[mm]':>9} {'[mrad]':>9} {'[mrad]':>9} {unit:>8} "
             f"{unit:>8} {'[ms]':>9} {'[ms]':>9} {'':>6}")
    lines = [head, units]
    for form, res in results.items():
        m = res.metrics()
        lines.append(
            f"{form:<20} {res.meta.get('disturbance_gain', float('nan')):6.2f} "
            f"{1e3 * m['rms_position_error_m']:9.2e} {1e3 * m['max_position_error_m']:9.2e} "
            f"{1e3 * m['rms_orientation_error_rad']:9.2e} {1e3 * m['max_orientation_error_rad']:9.2e} "
            f"{m['peak_torque_Nm']:8.2f} {m['max_internal_force_Nm']:8.1e} {1e3 * m['mean_step_time_s']:9.3f} "
            f"{1e3 * m['p99_step_time_s']:9.3f} {m['fallbacks']:6d}"
            + ("" if res.outcome == "ok" else f"  ({res.outcome})")
        )
    return "\n".join(lines)
