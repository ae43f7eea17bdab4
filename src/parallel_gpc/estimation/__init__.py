"""What a real machine measures and how the controller's state is estimated from it.

A layer between the model and the controller:

* :mod:`.sensors` — :class:`Sensors`, the description of what is measured (drive encoders with
  their resolution, optional drive rates, or the full state), and :class:`Measurement`, one
  sample of readings;
* :mod:`.kalman` — :class:`StateEstimator`, a Kalman filter on the controller's own discrete
  reduced model with the state [y, ẏ] augmented by a velocity disturbance (offset-free tracking
  from one estimator), fed by forward kinematics of the encoder readings;
* :mod:`.plant` — :class:`MachinePlant`, the plant interface (``measure()`` → readings,
  ``apply(u)`` for one sample), and :class:`SensedPlant`, our constrained plant behind
  simulated sensors (quantization, noise, delay).

The closed loop over such a plant is :func:`parallel_gpc.studies.loop.run_loop`.
"""

from .._lazy import lazy_exports

_PUBLIC = {
    "MujocoPlant": "mujoco_plant",
    "Sensors": "sensors", "Measurement": "sensors", "SENSOR_KINDS": "sensors",
    "StateEstimator": "kalman",
    "MachinePlant": "plant", "SensedPlant": "plant", "check_measurement": "plant",
}

__all__ = list(_PUBLIC)

__getattr__, __dir__ = lazy_exports(__name__, globals(), _PUBLIC)
