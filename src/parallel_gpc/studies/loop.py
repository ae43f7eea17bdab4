"""The closed loop on a machine: measure → estimate → control → apply, each step timed against Ts.

:func:`run_loop` drives any plant of the interface :class:`~parallel_gpc.estimation.MachinePlant`
(``measure()`` and ``apply(u)``): our constrained plant behind simulated sensors
(:class:`~parallel_gpc.estimation.SensedPlant`), a MuJoCo model, or a real machine. With encoder
sensors a :class:`~parallel_gpc.estimation.StateEstimator` turns the readings into the state and
the disturbance the controller uses; with full sensors the measured state goes to the
controller as it is. The time of each estimate + control step is compared with Ts and the
overruns of that deadline are counted.
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import InvalidParameterError, ShapeError
from ..estimation import StateEstimator, check_measurement, Sensors
from ..validation import check_allocation, positive
from ..gpc import INTERRUPTED
from .simulation import (DIVERGENCE_ERRORS, STEP_RECORD, SimulationResult, divergence_message, null_space_components,
                         run_meta, step_record)


def _window(reference, t: float, Ts: float, N: int) -> np.ndarray:
    return reference.window(t, Ts, N)


def _control(controller, estimator, reference, X_hat, u_pending, t: float, Ts: float, N: int, delay: bool):
    """One controller step from the estimate: (step info, input applied now, input pending); with a
    one-sample computation delay u(k) is computed from x̂(k+1|k) and applied one sample later."""
    if not delay:
        info = controller.step(X_hat, _window(reference, t, Ts, N))
        return info, info.u, u_pending
    if estimator is not None:
        X_ctrl = estimator.ahead(u_pending)
    else:
        Ad, Bd, cd = controller.discrete_model(X_hat)
        X_ctrl = Ad @ X_hat + Bd @ u_pending + cd
    info = controller.step(X_ctrl, _window(reference, t + Ts, Ts, N))
    return info, u_pending, info.u


def run_loop(controller, plant, reference, duration: float, sensors: Sensors | None = None,
             estimator: StateEstimator | None = None, computation_delay: bool = False,
             meta: dict | None = None) -> SimulationResult:
    """Run the controller on ``plant`` for ``duration`` s at the controller's Ts.

    Args:
        controller: a :class:`~parallel_gpc.gpc.GPCController` of the robot's reduced model.
            With an estimator it must run without its own disturbance estimate
            (``disturbance_gain=0``): the estimator's disturbance replaces it.
        plant: a :class:`~parallel_gpc.estimation.MachinePlant` (``robot``, ``Ts``,
            ``measure()``, ``apply(u)``; ``true_state()`` if it knows the truth).
        reference: the reference motion (:class:`~parallel_gpc.gpc.Reference`).
        duration: s.
        sensors: what ``plant.measure()`` returns (default: the plant's ``sensors``, else
            full state).
        estimator: the state estimator for encoder sensors (required for them).
        computation_delay: u computed during sample k is applied at k+1; the controller is
            given x̂(k+1|k), the state predicted under the input applied meanwhile, and the
            reference from k+1 on.
        meta: extra settings stored in the result.

    Returns:
        A :class:`~parallel_gpc.studies.SimulationResult`: pose and velocity are the true ones
        when the plant offers ``true_state()`` (else the estimate); ``estimate_error`` (x̂ − X)
        and ``overruns`` (steps whose estimate + control time exceeded Ts) are filled.

    Raises:
        InvalidParameterError: mismatched Ts, encoder sensors without an estimator, or two
            disturbance estimators. ShapeError / SensorError: the plant's first measurement
            does not match the sensors (refused at the first step).
    """
    Ts = controller.Ts
    robot = plant.robot
    n_y, n_u = robot.n_y, robot.n_u
    sensors = sensors or getattr(plant, "sensors", None) or Sensors("full")
    if not np.isclose(float(plant.Ts), Ts, rtol=1e-12, atol=0.0):
        raise InvalidParameterError(f"plant Ts = {plant.Ts!r} s differs from the controller's Ts = {Ts!r} s")
    if (controller.n_y, controller.n_u) != (n_y, n_u):
        raise ShapeError(f"controller has {controller.n_y} outputs and {controller.n_u} drives, the plant "
                         f"{robot.name!r} has {n_y} and {n_u}; they must describe the same robot")
    if sensors.kind == "encoders" and estimator is None:
        raise InvalidParameterError("encoder sensors need a StateEstimator (estimator=...) to give the controller "
                                    "its state")
    if estimator is not None and controller.disturbance_gain:
        raise InvalidParameterError(
            f"the controller runs its own disturbance estimate (disturbance_gain = {controller.disturbance_gain}); "
            "with a StateEstimator build it with disturbance_gain=0: the estimator's disturbance replaces it")
    duration = positive("duration", duration, " s")
    K = int(round(duration / Ts))
    if K < 1:
        raise InvalidParameterError(f"duration = {duration:g} s is shorter than one sample Ts = {Ts:g} s")
    check_allocation(f"the record of {K} samples", K * (robot.model.nq + 7 * n_y + 2 * n_u + 16),
                     "shorten the run or increase Ts")
    truth = getattr(plant, "true_state", None)
    N = controller.horizons.N
    rec = {k: [] for k in ("t", "reference", "pose", "velocity", "u", "q", "step_time", *STEP_RECORD, "saturated",
                           "estimate", "truth", "B_r")}
    u_pending = controller.u_prev.copy()
    overruns = 0
    stopped = ""
    try:
        for k in range(K):
            t = k * Ts
            t0 = time.perf_counter()
            meas = check_measurement(plant.measure(), sensors, n_y, n_u)
            if estimator is None:
                X_hat = np.asarray(meas.state, dtype=float)
            else:
                X_hat = estimator.update(meas)
                controller.disturbance = estimator.disturbance
            try:
                info, u_applied, u_pending = _control(controller, estimator, reference, X_hat, u_pending, t, Ts, N,
                                                      computation_delay)
            except DIVERGENCE_ERRORS as exc:  # no input for t_k: the samples before t_k are the run
                if not rec["t"]:
                    raise
                stopped = divergence_message(exc, t, rec, K, robot.output_angular)
                break
            elapsed = time.perf_counter() - t0
            overruns += elapsed > Ts
            X_true = None if truth is None else np.asarray(truth(), dtype=float)
            X_rec = X_hat if X_true is None else X_true
            q = np.array(plant.q) if hasattr(plant, "q") else (estimator.q.copy() if estimator is not None
                                                              else robot.assemble(X_hat[:n_y]))
            if n_u > n_y:
                rec["B_r"].append(robot.velocity_map(q)[0].T @ robot.drive_selection)
            sat_before = getattr(plant, "saturated", 0)
            plant.apply(u_applied)
            if estimator is not None:
                estimator.predict(u_applied)
            rec["t"].append(t)
            rec["reference"].append(reference.pose(t))
            rec["pose"].append(X_rec[:n_y])
            rec["velocity"].append(X_rec[n_y:])
            rec["u"].append(np.array(u_applied))
            rec["q"].append(q)
            rec["step_time"].append(elapsed)
            for key, value in step_record(info).items():
                rec[key].append(value)
            rec["saturated"].append(getattr(plant, "saturated", 0) > sat_before)
            rec["estimate"].append(X_hat)
            rec["truth"].append(X_rec)
    except KeyboardInterrupt:
        stopped = f"{INTERRUPTED} after {min(len(v) for k, v in rec.items() if k != 'B_r')} of {K} samples"
    done = min(len(v) for k, v in rec.items() if k != "B_r")
    if not done:
        raise KeyboardInterrupt
    arrays = {k: np.asarray(v[:done]) for k, v in rec.items() if k not in ("B_r", "estimate", "truth")}
    arrays["internal_force"] = null_space_components(np.asarray(rec["B_r"][:done]), arrays["u"]) \
        if rec["B_r"] else np.zeros(done)
    estimate_error = (np.asarray(rec["estimate"][:done]) - np.asarray(rec["truth"][:done])) \
        if truth is not None and estimator is not None else None
    info_meta = {**run_meta(controller, robot), "sensors": sensors.kind,
                 "computation_delay": bool(computation_delay), "deadline_overruns": int(overruns), **(meta or {})}
    return SimulationResult(**arrays, meta=info_meta, stopped=stopped, outputs=robot.output_space,
                            limits=controller.limits, estimate_error=estimate_error, overruns=int(overruns))
