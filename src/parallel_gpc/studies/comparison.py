"""The paper's Fig. 2 comparison, measured: what each GPC form does where forms differ.

Two parts, one library call each (``parallel-gpc demo`` runs both):

* :func:`deadbeat_check` — the paper's tracking setting Qu = 0: the stacked G has full row
  rank, so every form reduces to the one-step dead-beat law u(k) = (C B_d)⁺ (w(k+1) − C(A_d X +
  c_d)) (the minimum-norm input that puts the next output on the reference). All forms run in
  lockstep on the same measured states of one closed loop and their u(k) are compared with
  that law: the forms are indistinguishable at Qu = 0. The delayed incremental form is left
  out: its u(k) was decided at k−1 by construction.
* :func:`run_comparison` — Qu > 0 (the horizon matters) on a plant that differs from the model
  (heavier, with a steady load on the platform): every form, each with the state-disturbance
  estimate off and on, so that the effect of the form (absolute, incremental, nonlinear
  prediction) and the effect of the estimator are never confounded.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import InvalidParameterError
from ..gpc import FORMS, GPCController, Weights, Horizons, pose_error_norms
from ..model import ReducedModel, ConstrainedPlant, ParallelRobot
from ..validation import check_allocation, positive
from .simulation import SimulationResult
from .tables import FORM_WIDTH, effort_columns, error_columns, output_space_of, step_time_columns, text_table
from .tracking import TrackingSettings, run_tracking

#: The comparison's default setting: Ts = 10 ms and N = 30 (a 0.3 s horizon), Qu = 1e-3 so
#: that the horizon and the form matter, a plant 20 % heavier than the model with a steady
#: load of (5 N, −5 N, 0.5 N·m) on the platform; 2 s S-curve, then 1 s holding its end pose.
DEMO_SETTINGS = TrackingSettings(Ts=0.01, horizons=Horizons(30), weights=Weights(1.0, 1e-3), mass_scale=1.2,
                                 platform_force=(5.0, -5.0, 0.5), duration=3.0, disturbance_gain=0.5)
#: Gains α of the state-disturbance estimate compared: off and on.
ESTIMATOR_GAINS = (0.0, 0.5)
#: Length (s) of the window at the end of a run over which the steady-state error is averaged.
STEADY_WINDOW = 0.3


@dataclass
class DeadbeatCheck:
    """Lockstep comparison of the forms at Qu = 0 (see :func:`deadbeat_check`).

    Attributes:
        forms: the forms compared.
        u: (K, n_forms, n_u) each form's u(k) at the same measured states (N·m).
        u_deadbeat: (K, n_u) the one-step dead-beat minimum-norm u(k) (N·m).
        t: (K,) s. error: (K, n_y) pose − reference of the closed loop driven by the first
            form's inputs (m, rad).
    """

    forms: tuple[str, ...]
    u: np.ndarray
    u_deadbeat: np.ndarray
    t: np.ndarray
    error: np.ndarray

    def max_difference(self) -> dict[str, float]:
        """Largest |u_form(k) − u_dead-beat(k)| over samples and drives (N·m), by form."""
        return {f: float(np.max(np.abs(self.u[:, i] - self.u_deadbeat))) for i, f in enumerate(self.forms)}


def steady_state_error(result: SimulationResult, window: float = STEADY_WINDOW) -> float:
    """Mean position error (norm of the translational error, m) over the last ``window`` s of a run."""
    sel = result.t >= result.t[-1] - window
    return float(np.mean(pose_error_norms(result.error[sel], result.angular)[0]))


def one_step_deadbeat_input(model: ReducedModel, X: np.ndarray, w_next: np.ndarray, Ts: float) -> np.ndarray:
    """The one-step dead-beat minimum-norm input: argmin ‖u‖ s.t. C(A_d X + B_d u + c_d) = w(k+1) (N·m)."""
    Ad, Bd, cd = model.discrete(X, Ts)
    C = model.C
    return np.linalg.pinv(C @ Bd) @ (w_next - C @ (Ad @ X + cd))


def deadbeat_check(settings: TrackingSettings = DEMO_SETTINGS, duration: float = 1.0,
                   forms=("absolute", "incremental", "nonlinear"), robot: ParallelRobot | None = None) -> DeadbeatCheck:
    """Run the forms in lockstep at Qu = 0 on the exact plant (no mismatch, no load, no estimator).

    The plant is driven by the first form's u(k); every form computes its u(k) from the same
    measured state, and the one-step dead-beat law is evaluated there too.

    Args:
        settings: robot, Ts, horizons, Qy, solver (Qu, limits, mismatch, load and estimator are overridden).
        duration: s of the S-curve run (finite, at least one sample Ts).
        forms: forms to compare (not ``"incremental-delayed"``: its u(k) is decided at k−1).
        robot: the loaded robot (default: load ``settings.robot``).

    Raises:
        InvalidParameterError: bad forms, or a duration that is not finite, shorter than Ts or
            too long to record.
    """
    bad = [f for f in forms if f not in FORMS or f == "incremental-delayed"]
    if bad or not forms:
        raise InvalidParameterError(f"forms {list(forms)} must be a non-empty subset of "
                                    f"{[f for f in FORMS if f != 'incremental-delayed']}")
    duration = positive("dead-beat check duration", duration, " s")
    K = int(round(duration / settings.Ts))
    if K < 1:
        raise InvalidParameterError(f"dead-beat check duration = {duration!r} s must be at least one sample "
                                    f"(Ts = {settings.Ts!r} s)")
    robot = robot or ParallelRobot.load(settings.robot)
    check_allocation(f"the dead-beat check's record of {K} samples (duration {duration:g} s / Ts {settings.Ts:g} s)",
                     K * ((len(forms) + 1) * robot.n_u + robot.n_y + 1), "reduce the duration")
    s = replace(settings, weights=Weights(settings.weights.Qy, 0.0), mass_scale=1.0, platform_force=(0.0, 0.0, 0.0),
                disturbance_gain=0.0, duration=duration, limits=None)
    reference = s.make_reference(robot)
    model = ReducedModel(robot)
    ctrls = [GPCController(model, s.controller_settings(f)) for f in forms]
    plant = ConstrainedPlant(robot, reference.initial_state(), Ts=s.Ts)
    K, N = int(round(duration / s.Ts)), s.horizons.N
    u = np.empty((K, len(forms), robot.n_u))
    u_db = np.empty((K, robot.n_u))
    error = np.empty((K, robot.n_y))
    for k in range(K):
        X = plant.X
        window = reference.window(k * s.Ts, s.Ts, N)
        for i, ctrl in enumerate(ctrls):
            u[k, i] = ctrl.step(X, window).u
        u_db[k] = one_step_deadbeat_input(model, X, window[0], s.Ts)
        error[k] = X[:robot.n_y] - reference.pose(k * s.Ts)
        plant.step(u[k, 0])
    return DeadbeatCheck(tuple(forms), u, u_db, s.Ts * np.arange(K), error)


def run_comparison(settings: TrackingSettings = DEMO_SETTINGS, forms=FORMS, gains=ESTIMATOR_GAINS,
                   progress: bool = False, robot: ParallelRobot | None = None) -> dict[tuple[str, float], SimulationResult]:
    """Every form with every estimator gain on the plant of ``settings``.

    Returns:
        Results keyed by (form, α), in the order of ``gains`` then ``forms``.
    """
    robot = robot or ParallelRobot.load(settings.robot)
    runs = {}
    for gain in gains:
        results = run_tracking(replace(settings, disturbance_gain=float(gain)), forms, progress=progress, robot=robot)
        runs.update({(form, float(gain)): res for form, res in results.items()})
    return runs


def comparison_table(runs: dict[tuple[str, float], SimulationResult]) -> str:
    """Text table: form, estimator gain α, RMS / max / steady-state position error (mm), RMS and
    max orientation error (mrad, with angular outputs), peak drive effort and internal-force
    measure (the robot's drive unit), mean and p99 step time (ms)."""
    space = output_space_of(runs.values())
    cols = [*error_columns(space, steady_state_error, ".3g"), *effort_columns(space), *step_time_columns()]
    return text_table([("form", FORM_WIDTH), ("est. α", 6)], cols,
                      (((form, f"{gain:6.2f}"), res) for (form, gain), res in runs.items()))


def sensors_table(full: dict[str, SimulationResult], encoders: dict[str, SimulationResult], Ts: float) -> str:
    """Text table: each form of ``encoders`` with full-state feedback (its run in ``full``) and
    with drive encoders only (quantized readings → forward kinematics → Kalman filter), one row
    each: RMS / max / steady-state position error (mm), orientation errors (mrad, with angular
    outputs), mean and largest step time (ms, estimation included) and the steps longer than
    ``Ts`` (s)."""
    def rows():
        for form, enc in encoders.items():
            ref = full[form]
            yield (form, f"full, α {ref.meta.get('disturbance_gain', float('nan')):g}"), ref
            yield (form, str(enc.meta.get("sensors_spec", "encoders"))), enc

    space = output_space_of(encoders.values())
    cols = [*error_columns(space, steady_state_error, ".3g"), *step_time_columns(Ts)]
    return text_table([("form", FORM_WIDTH), ("sensors", 16)], cols, rows())
