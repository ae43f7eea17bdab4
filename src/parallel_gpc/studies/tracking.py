"""Tracking experiments: the paper's Fig. 2 comparison as one library call.

``run_tracking(TrackingSettings(...), forms)`` (or ``TrackingSettings.from_flat(N=..., Qu=..., ...)``) builds the controller's model and the plant
(with optional mass mismatch, noise, disturbance force, drive saturation), runs each GPC form on
the reference and returns the results; ``metrics_table`` formats them.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, fields, replace

import numpy as np

from ..errors import InvalidParameterError, ShapeError
from ..gpc import (
    FORMS,
    GPCController,
    Weights,
    Horizons,
    Reference,
    SampledTrajectory,
    REFERENCE_KINDS,
    check_reference,
    check_times,
    is_file_reference,
    reference_for,
    GPCSettings,
    TERMINALS,
    unit_interval,
)
from ..limits import STATE_KINDS, Limits, as_limits, symmetric_limit
from ..model import ReducedModel, ConstrainedPlant, DEFAULT_ROBOT, ParallelRobot
from ..validation import finite_vector, positive
from ..estimation import StateEstimator, SensedPlant, Sensors
from ..gpc.settings import check_iterations
from ..gpc.stability import LINEAR_FORMS, closed_loop_poles
from .loop import run_loop
from .simulation import SimulationResult, simulate
from .tables import (FORM_WIDTH, Column, effort_columns, error_columns, gain_column, output_space_of, solver_column,
                     step_time_columns, text_table)

#: plants a tracking run can drive
PLANTS = ("own", "mujoco")


#: The flat keywords of :meth:`TrackingSettings.from_flat` that stand for the fields of the
#: embedded Limits: the input kinds as ``torque_limit``, ``du_limit``, every state kind by its own
#: name, the soft kinds and the penalty as ``soft_limits``, ``limit_penalty``.
LIMIT_KEYS = {"torque_limit": "torque", "du_limit": "du", **{kind: kind for kind in STATE_KINDS},
              "soft_limits": "soft", "limit_penalty": "penalty"}
#: The flat keywords of :meth:`TrackingSettings.from_flat` that stand for the embedded
#: Horizons, Weights and Limits (the CLI's options and a sweep's parameters are flat).
EMBEDDED_KEYS = ("N", "No", "Nu", "Qy", "Qu", "Qf") + tuple(LIMIT_KEYS)
#: What ``plant_torque_limit`` may name besides a limit: the controller's or the robot file's.
PLANT_LIMIT_SOURCES = ("controller", "robot")


@dataclass(frozen=True, eq=False)
class TrackingSettings:
    """Settings of a tracking run (SI units), validated when built.

    :meth:`from_flat` builds one from flat keywords (N, No, Nu, Qy, Qu, Qf, the limits'
    :data:`LIMIT_KEYS` and the other fields); :meth:`flat` gives them back, every one.

    Attributes:
        robot: embedded robot name or path.
        Ts: sample time in s (default 2 ms), of the controllers and the plant.
        horizons: N, No, Nu (default ``Horizons(20)``).
        weights: square-root weights (default ``Weights(1.0, 0.0)``: paper Fig. 2, Qy = 1, Qu = 0;
            its ``Qf`` is the terminal factor on the last predicted error, default 1).
        terminal: the controllers' optional terminal equality (``"pose"`` or ``"stop"``,
            :data:`~parallel_gpc.gpc.settings.TERMINALS`; hard rows, a QP back end), or None.
        limits: the controllers' input :class:`~parallel_gpc.limits.Limits` (a du limit: incremental
            forms only); default none.
        solver: back-end name or None (each form's default,
            :func:`~parallel_gpc.gpc.settings.default_solver`: the stage-wise ``riccati`` where it
            gives QR's minimizer, ``qr`` at Qu = 0; shown in the table's ``solver`` column).
        disturbance_gain: α ∈ [0, 1] of the state-disturbance estimate, the same for every form
            (so that form and estimator effects are never confounded); 0 = no estimator;
            None (default): each controller's own default (0 absolute, 0.5 incremental forms),
            shown in the table's ``est. α`` column.
        mass_scale: plant masses / model masses (model mismatch, > 0), 1 = exact model.
        noise_std: measurement noise on [y, ẏ] (m, rad, m/s, rad/s; a number or 2·n_y values ≥ 0), 0 = none.
        platform_force: constant disturbance on the platform coordinates (N, N·m; n_y values,
            all zeros = none).
        reference: a built-in path in the robot's output space — "auto" (the paper's S-curve
            for planar [x, y, ψ] outputs, the helix for three translational outputs, an S-curve
            in the plane of two, a line for one), "s-curve", "circle", "line", "helix" —, "hold",
            a reference file (".csv": a column t and one per output label, SI units; ".npz": a
            plan or saved reference) or a Reference object
            (:func:`~parallel_gpc.gpc.robot_references.reference_for`); duration: run length in s
            (default: motion + 0.2 s; a file's last time + 0.2 s; 2 s for a hold).
        s_curve_duration: time of a built-in path's motion in s.
        hold_pose: (n_y,) target of the "hold" reference (m, rad); None: near home
            (:func:`~parallel_gpc.gpc.references.hold_pose_for`).
        check_reference: assemble the reference at the run's sample poses before the run and
            refuse it, naming the first bad pose, if one is unreachable or near-singular
            (:func:`~parallel_gpc.gpc.robot_references.check_reference`).
        seed: seed of the measurement noise (an integer ≥ 0).
        plant_torque_limit: drive saturation of the plant alone: ``"controller"`` (the torque
            limit of ``limits``), ``"robot"`` (the limits in the robot file), a value in N·m
            (scalar or per drive, > 0) or a Limits, or None (no saturation).
        sensors: what the controller sees: ``"full"`` (the state [y, ẏ]) or ``"encoders"`` /
            ``"encoders:COUNTS_PER_REV"`` (quantized drive readings through a Kalman filter,
            :mod:`parallel_gpc.estimation`; the controller then runs without its own
            disturbance estimate).
        plant: ``"own"`` (our constrained plant) or ``"mujoco"`` (the robot exported to MuJoCo).
        iterations: Gauss–Newton iterations per step of the nonlinear form (1: the paper's single
            step; > 1: iterated to the nonlinear MPC optimum, :mod:`parallel_gpc.gpc.nmpc`); the other
            forms take their single step. tolerance: the iterations' relative step tolerance, or
            None: the controller's default (1e-8). time_budget: s per control step for the
            iterations (real-time mode), or None (:class:`~parallel_gpc.gpc.GPCSettings`).

    Raises:
        InvalidParameterError: a field out of range or of the wrong type (the message names it);
            InfeasibleLimitsError for a plant limit ≤ 0.
    """

    robot: str = DEFAULT_ROBOT
    Ts: float = 0.002
    horizons: Horizons = field(default_factory=lambda: Horizons(20))
    weights: Weights = field(default_factory=lambda: Weights(1.0, 0.0))
    limits: Limits = field(default_factory=Limits)
    terminal: str | None = None
    solver: str | None = None
    disturbance_gain: float | None = None
    mass_scale: float = 1.0
    noise_std: float | tuple[float, ...] = 0.0
    platform_force: tuple[float, ...] = (0.0, 0.0, 0.0)
    reference: str | Reference = "auto"
    duration: float | None = None
    s_curve_duration: float = 2.0
    hold_pose: tuple[float, ...] | None = None
    seed: int = 0
    check_reference: bool = True
    plant_torque_limit: str | Limits | None = "controller"
    sensors: str = "full"
    plant: str = "own"
    iterations: int = 1
    tolerance: float | None = None
    time_budget: float | None = None
    extra: dict = field(default_factory=dict)

    def __post_init__(self):
        def put(name, value):
            object.__setattr__(self, name, value)

        if not isinstance(self.robot, (str, os.PathLike)):
            raise InvalidParameterError(f"robot = {self.robot!r} must be an embedded robot name or a path")
        put("Ts", positive("Ts", self.Ts, " s"))
        if not isinstance(self.horizons, Horizons):
            raise InvalidParameterError(f"horizons must be a Horizons(N, No, Nu), got {self.horizons!r}")
        if not isinstance(self.weights, Weights):
            raise InvalidParameterError(f"weights must be a Weights(Qy, Qu), got {self.weights!r}")
        put("limits", as_limits(self.limits))
        if self.terminal is not None and self.terminal not in TERMINALS:
            raise InvalidParameterError(f"terminal = {self.terminal!r} is not one of {list(TERMINALS)} or None")
        if self.solver is not None and not isinstance(self.solver, str):
            raise InvalidParameterError(f"solver {self.solver!r} must be a back-end name such as 'qr', or None")
        if self.disturbance_gain is not None:
            put("disturbance_gain", unit_interval("disturbance_gain", self.disturbance_gain))
        put("mass_scale", positive("mass_scale", self.mass_scale))
        try:
            noise = None if isinstance(self.noise_std, (str, bytes, bool)) else np.asarray(self.noise_std, dtype=float)
        except (TypeError, ValueError):
            noise = None
        if noise is None or noise.ndim > 1 or noise.size == 0 or not np.all(np.isfinite(noise)) or np.any(noise < 0):
            raise InvalidParameterError(f"noise_std = {self.noise_std!r} must be a number or a vector of numbers, "
                                        "finite and ≥ 0 (m, rad, m/s, rad/s)")
        put("platform_force", tuple(finite_vector("platform_force", self.platform_force).tolist()))
        if not (isinstance(self.reference, Reference) or self.reference in REFERENCE_KINDS
                or is_file_reference(self.reference)):
            raise InvalidParameterError(f"reference {self.reference!r} is not one of {list(REFERENCE_KINDS)}, a .csv "
                                        "or .npz file, or a Reference")
        if self.duration is not None:
            put("duration", positive("duration", self.duration, " s"))
        put("s_curve_duration", positive("s_curve_duration", self.s_curve_duration, " s"))
        if self.hold_pose is not None:
            put("hold_pose", tuple(finite_vector("hold_pose", self.hold_pose).tolist()))
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise InvalidParameterError(f"seed = {self.seed!r} must be an integer ≥ 0")
        plant = self.plant_torque_limit
        if isinstance(plant, str):
            if plant not in PLANT_LIMIT_SOURCES:
                raise InvalidParameterError(f"plant_torque_limit {plant!r} is not one of {PLANT_LIMIT_SOURCES}, "
                                            "a value in N·m, a Limits or None")
        elif plant is not None and not isinstance(plant, Limits):
            put("plant_torque_limit", Limits(torque=symmetric_limit("plant torque", plant)))
        if not isinstance(self.extra, dict):
            raise InvalidParameterError(f"extra = {self.extra!r} must be a dict")
        if self.plant not in PLANTS:
            raise InvalidParameterError(f"plant {self.plant!r} is not one of {list(PLANTS)}")
        Sensors.parse(self.sensors)  # refuses an unknown sensor spec here, once
        put("iterations", check_iterations(self.iterations))
        if self.tolerance is not None:
            put("tolerance", positive("tolerance", self.tolerance))
        if self.time_budget is not None:
            put("time_budget", positive("time_budget", self.time_budget, " s"))

    @classmethod
    def from_flat(cls, *, N: int | None = None, No: int | None = None, Nu: int | None = None, Qy=None, Qu=None,
                  Qf=None, **fields) -> "TrackingSettings":
        """Settings from flat keywords: N, No, Nu make the horizons, Qy, Qu, Qf the weights, the
        :data:`LIMIT_KEYS` (``torque_limit``, ``du_limit``, ``drive_position``, ``drive_rate``,
        ``output_box``, ``output_velocity``, ``joint_position``, ``soft_limits``, ``limit_penalty``)
        the limits (each unset or None one: the default's); the other keywords are the other fields."""
        default = cls()
        H, W = default.horizons, default.weights
        horizons = Horizons(H.N if N is None else N, H.No if No is None else No, Nu)
        weights = Weights(W.Qy if Qy is None else Qy, W.Qu if Qu is None else Qu, W.Qf if Qf is None else Qf)
        limits = {LIMIT_KEYS[key]: fields.pop(key) for key in list(fields) if key in LIMIT_KEYS}
        limits = {kind: value for kind, value in limits.items() if value is not None}
        return cls(horizons=horizons, weights=weights, limits=Limits(**limits), **fields)

    def flat(self) -> dict:
        """The settings as the flat keywords of :meth:`from_flat`: every field, every limit (numbers,
        lists, a ``{joint: [lo, hi]}`` dict; None when unset), so that ``from_flat(**s.flat())``
        equals ``s``."""
        H, W = self.horizons, self.weights
        lim = self.limits
        values = lim.to_dict()
        out = {"N": H.N, "No": H.No, "Nu": H.Nu, "Qy": W.Qy, "Qu": W.Qu, "Qf": W.Qf}
        for key, kind in LIMIT_KEYS.items():
            if kind == "soft":
                out[key] = sorted(lim.soft)
            elif kind == "penalty":
                out[key] = lim.penalty
            else:
                out[key] = values.get(kind)
        out.update({f.name: getattr(self, f.name) for f in fields(self)
                    if f.name not in ("horizons", "weights", "limits", "extra")})
        return out

    def with_run_limits(self, robot: ParallelRobot, source: str = "robot", output_box=None, output_velocity=None,
                        hard: bool = False) -> "TrackingSettings":
        """These settings with the limits a command applies (:func:`run_limits`) added to their
        torque and du limits."""
        return replace(self, limits=run_limits(robot, source, self.limits, output_box, output_velocity, hard))

    def make_reference(self, robot: ParallelRobot, max_condition: float = 1e3) -> Reference:
        """The run's reference on ``robot`` (built-in paths sized to its workspace, whose probe
        stops where cond(M_r⁻¹ B_r) exceeds ``max_condition``)."""
        return reference_for(self.reference, robot, self.s_curve_duration, max_condition, self.hold_pose)

    def plant_limit(self, robot: ParallelRobot) -> Limits | None:
        """The plant's drive saturation: the controllers' torque limit, the robot file's, the
        given one, or None."""
        if self.plant_torque_limit == "controller":
            return Limits(torque=self.limits.torque)
        if self.plant_torque_limit == "robot":
            return robot.limits
        return self.plant_torque_limit

    def controller_settings(self, form: str) -> GPCSettings:
        """The validated :class:`~parallel_gpc.gpc.GPCSettings` of ``form`` in this run (the
        iterations and their stop: the nonlinear form's only)."""
        nmpc = {}
        if form == "nonlinear":
            nmpc = {"iterations": self.iterations, "time_budget": self.time_budget}
            if self.tolerance is not None:
                nmpc["tolerance"] = self.tolerance
        return GPCSettings(self.Ts, self.horizons, self.weights, form, self.solver, self.limits,
                           self.disturbance_gain, terminal=self.terminal, **nmpc)

    @property
    def run_duration(self) -> float:
        """Run length in s for a built-in path or hold (see :meth:`duration_for`)."""
        if self.duration is not None:
            return float(self.duration)
        return 2.0 if self.reference == "hold" else self.s_curve_duration + 0.2

    def duration_for(self, reference: Reference) -> float:
        """Run length in s: ``duration`` if set; else a sampled reference's last time + 0.2 s
        (a reference file), or :attr:`run_duration`."""
        if self.duration is None and is_file_reference(self.reference) and isinstance(reference, SampledTrajectory):
            return float(reference.t[-1]) + 0.2
        return self.run_duration


#: Every flat keyword of :meth:`TrackingSettings.from_flat` (a sweep's parameter names).
FLAT_KEYS = EMBEDDED_KEYS + tuple(f.name for f in fields(TrackingSettings)
                                  if f.name not in ("horizons", "weights", "limits", "extra"))


#: where a command's state limits come from: the robot file's ``[limits]`` table, or nowhere.
LIMIT_SOURCES = ("robot", "none")


def run_limits(robot: ParallelRobot, source: str = "robot", base: Limits | None = None, output_box=None,
               output_velocity=None, hard: bool = False) -> Limits:
    """The limits a command applies: ``base`` (torque, du), the robot file's limits
    (``source="robot"``: its drive limit ``[drives] torque_limit`` where ``base`` has no torque
    limit, and its state limits :attr:`~parallel_gpc.model.ParallelRobot.state_limits`; ``"none"``:
    none), then an explicit workspace box and output velocity limit, which replace the file's.

    Args:
        robot: the robot. source: one of :data:`LIMIT_SOURCES`.
        base: the input limits (None: none).
        output_box: 2·n_y numbers lo₁ hi₁ lo₂ hi₂ … (m, rad), or None.
        output_velocity: a number or n_y numbers (m/s, rad/s), or None.
        hard: every state kind hard (default: the file's choice, else soft).

    Raises:
        InvalidParameterError: an unknown source. ShapeError: a box of another length than 2·n_y.
        InfeasibleLimitsError: a lower bound above its upper one.
    """
    if source not in LIMIT_SOURCES:
        raise InvalidParameterError(f"limits source {source!r} is not one of {list(LIMIT_SOURCES)}")
    values = {} if base is None else dict(base.values())
    if source == "robot" and values.get("torque") is None and robot.torque_limit is not None:
        values["torque"] = robot.torque_limit  # the robot's own drive limit, unless one is given
    file_limits = robot.state_limits if source == "robot" else Limits()
    values.update(file_limits.values())
    options = {"soft": file_limits.soft, "penalty": file_limits.penalty}
    if output_box is not None:
        box = np.asarray(output_box, dtype=float).reshape(-1)
        if box.size != 2 * robot.n_y:
            raise ShapeError(f"output box {box.tolist()} has {box.size} numbers; expected 2 × {robot.n_y} = "
                             f"{2 * robot.n_y}: lower and upper bound of each output {list(robot.output_space.labels)}")
        values["output_box"] = box.reshape(-1, 2)
    if output_velocity is not None:
        values["output_velocity"] = output_velocity
    if hard:
        options["soft"] = ()
    limits = Limits(**values, **options)
    limits.for_drives(robot.n_u, robot.n_y)  # sizes checked against the robot here, once
    return limits


def run_tracking(settings: TrackingSettings, forms=("absolute", "nonlinear"), progress: bool = True,
                 robot: ParallelRobot | None = None, poles: bool = False) -> dict[str, SimulationResult]:
    """Run each GPC form on the reference with the plant of ``settings``; returns results by form.

    A form whose closed loop diverges keeps its samples up to there (``result.diverged``) and the
    next form runs (each form is an independent run); Ctrl-C keeps the forms finished so far and
    the samples of the current one, and stops. With ``poles`` (the ``track`` command's note), the
    linear forms' results carry ``meta["closed_loop_pole"]``: [Re, Im] of the dominant pole of their
    unconstrained closed loop on the controller's model at the start
    (:func:`~parallel_gpc.gpc.stability.closed_loop_poles`; |z| ≥ 1: not asymptotically stable, e.g.
    the dead-beat law's z = −1 at Qu = 0; ≈ 1–1.5 ms per form, left out of sweep cells).

    Raises:
        InvalidParameterError: an unknown form, or settings a form refuses (a du limit with the
            absolute form, iterations > 1 without the nonlinear form, a solver that cannot enforce the
            limits), before any run.
    """
    for form in forms:
        if form not in FORMS:
            raise InvalidParameterError(f"form {form!r} is not one of {FORMS}")
    if settings.limits.du is not None and "absolute" in forms:
        raise InvalidParameterError(
            f"du_limit = {settings.limits.to_dict()['du']!r} N·m per sample applies to the incremental forms only; "
            f"the absolute form has no increments (forms asked: {list(forms)}; use 'incremental' and/or 'nonlinear')")
    if settings.iterations > 1 and "nonlinear" not in forms:
        raise InvalidParameterError(
            f"iterations = {settings.iterations} iterates the nonlinear form; the forms asked are {list(forms)} "
            "(add 'nonlinear', or use iterations = 1)")
    per_form = {form: settings.controller_settings(form) for form in forms}  # every form checked first
    robot = robot or ParallelRobot.load(settings.robot)
    plant_robot = robot if settings.mass_scale == 1.0 else robot.with_mass_scale(settings.mass_scale)
    controllers = {form: GPCController(ReducedModel(robot), per_form[form]) for form in forms}
    max_condition = min((c.max_condition for c in controllers.values()), default=1e3)
    reference = settings.make_reference(robot, max_condition)
    duration = settings.duration_for(reference)
    if settings.check_reference:
        check_reference(robot, reference, check_times(reference, duration, settings.Ts), max_condition)
    start = reference.pose(0.0)
    if settings.reference == "hold":
        start = robot.home_pose
    settings.limits.check_pose(start, robot.output_space.labels)  # a box that excludes the start: refused
    results = {}
    machine = settings.sensors != "full" or settings.plant != "own"
    sensors = check_machine(settings) if machine else None
    X_start = np.concatenate([start, np.zeros(robot.n_y)])
    at_start = {form: closed_loop_poles(controllers[form], X_start) for form in forms if poles and form in LINEAR_FORMS}
    for form in forms:
        try:
            if machine:
                res = _run_machine(settings, sensors, per_form[form], robot, plant_robot, reference, start, duration)
            else:
                res = _run_own(settings, controllers[form], plant_robot, reference, start, duration, progress)
        except KeyboardInterrupt:  # interrupted before this form's first step: keep the earlier forms
            if not results:
                raise
            break
        results[form] = res
        if form in at_start:  # the unconstrained loop's dominant pole at the start, for the report
            pole = at_start[form][np.argmax(np.abs(at_start[form]))]
            res.meta["closed_loop_pole"] = [float(pole.real), float(pole.imag)]
        if res.interrupted:
            break
    return results


def _run_own(settings: TrackingSettings, ctrl: GPCController, plant_robot, reference, start, duration: float,
             progress: bool) -> SimulationResult:
    """One form on our constrained plant with the full measured state (and its optional noise)."""
    plant = ConstrainedPlant(plant_robot, np.concatenate([start, np.zeros(plant_robot.n_y)]), Ts=settings.Ts,
                             torque_limit=settings.plant_limit(plant_robot),
                             platform_force=settings.platform_force if any(settings.platform_force) else None)
    return simulate(ctrl, plant, reference, duration, seed=settings.seed, noise_std=settings.noise_std or None,
                    progress=progress, check=False,
                    meta={"mass_scale": settings.mass_scale, "noise_std": settings.noise_std,
                          "disturbance_gain": ctrl.disturbance_gain, "platform_force": list(settings.platform_force)})


def check_machine(settings: TrackingSettings) -> Sensors:
    """The sensors of a run through :func:`~parallel_gpc.studies.loop.run_loop` (encoder sensors or
    the MuJoCo plant), refusing the options that loop does not model."""
    sensors = Sensors.parse(settings.sensors)
    if settings.noise_std:
        raise InvalidParameterError(f"noise_std = {settings.noise_std!r} is state noise of full-state runs on our own "
                                    "plant; encoder noise is Sensors(noise_counts=...)")
    if settings.plant == "mujoco" and any(settings.platform_force):
        raise InvalidParameterError("the MuJoCo plant has no platform force; run it with platform_force zero")
    return sensors


def _run_machine(settings: TrackingSettings, sensors: Sensors, ctrl_settings: GPCSettings, robot, plant_robot,
                 reference, start, duration: float):
    """One form through run_loop: our plant behind sensors, or MuJoCo; an estimator for encoders."""
    Ts, encoders = settings.Ts, sensors.kind == "encoders"
    X0 = np.concatenate([start, np.zeros(robot.n_y)])
    if encoders:  # the Kalman filter estimates the disturbance: the controller's own estimate is off
        ctrl_settings = ctrl_settings.changed(disturbance_gain=0.0)
    ctrl = GPCController(ReducedModel(robot), ctrl_settings)
    if settings.plant == "mujoco":
        from ..estimation import MujocoPlant

        plant = MujocoPlant(plant_robot, Ts, X0, sensors, torque_limit=settings.plant_limit(robot), seed=settings.seed)
    else:
        plant = SensedPlant(ConstrainedPlant(plant_robot, X0, Ts=Ts, torque_limit=settings.plant_limit(robot),
                                             platform_force=settings.platform_force if any(settings.platform_force)
                                             else None), sensors, seed=settings.seed)
    estimator = StateEstimator(ReducedModel(robot), Ts, sensors, X0) if encoders else None
    return run_loop(ctrl, plant, reference, duration, estimator=estimator,
                    meta={"mass_scale": settings.mass_scale, "plant": settings.plant, "sensors_spec": settings.sensors,
                          "disturbance_gain": ctrl.disturbance_gain, "platform_force": list(settings.platform_force)})


def metrics_table(results: dict[str, SimulationResult], drive_unit: str | None = None) -> str:
    """A text table of the tracking metrics by form (position error in mm, orientation error in
    mrad — the norm of the angular output errors, ψ on a planar robot; only with angular
    outputs —, drive effort in ``drive_unit``, step times in ms), with the gain α of the
    disturbance estimate and the back end each form ran with and, for runs with an estimator,
    its RMS error.

    Args:
        results: simulation results by form name.
        drive_unit: unit of the drive efforts u ("N·m" for revolute drives, "N" for prismatic
            ones); None: the results' own (``SimulationResult.outputs``, N·m without).
    """
    space = output_space_of(results.values())
    cols = [gain_column(), *error_columns(space), *effort_columns(space, drive_unit), *step_time_columns(),
            Column("fallb.", 6, "", lambda res, m: f"{m['fallbacks']:6d}"), solver_column()]
    if any(res.estimate_error is not None for res in results.values()):
        cols.append(Column("est. err", 9, "[mm]", lambda res, m: f"{1e3 * m['rms_estimate_position_error_m']:9.2e}"
                           if "rms_estimate_position_error_m" in m else f"{'—':>9}"))
    return text_table([("form", FORM_WIDTH)], cols, (((form,), res) for form, res in results.items()))
