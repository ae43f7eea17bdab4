"""The plant interface of a machine, and our constrained plant behind simulated sensors.

A plant the controller runs on — a real machine, or a simulator the user trusts — needs two
methods and two attributes::

    class MyPlant:
        robot: ParallelRobot      # the controller's description of the machine (drives, outputs)
        Ts: float                 # sample time (s)
        def measure(self) -> Measurement: ...   # what the sensors read now
        def apply(self, u) -> None: ...         # hold drive torques u (N·m, N) for one sample

Simulators may also offer ``true_state()`` → (2 n_y,) the true [y, ẏ], which the loop records
to measure tracking and estimation errors (a real machine has none: the estimate is recorded).
"""

from __future__ import annotations

from collections import deque
from typing import Protocol, runtime_checkable

import numpy as np

from ..errors import InvalidParameterError, SensorError, ShapeError
from .sensors import Measurement, Sensors, encoder_readings


@runtime_checkable
class MachinePlant(Protocol):
    """What :func:`~parallel_gpc.studies.loop.run_loop` needs of a plant (see the module docstring)."""

    robot: object
    Ts: float

    def measure(self) -> Measurement: ...

    def apply(self, u) -> None: ...


def check_measurement(measurement, sensors: Sensors, n_y: int, n_u: int) -> Measurement:
    """The plant's measurement, checked against what ``sensors`` say is measured.

    Raises:
        SensorError: not a :class:`Measurement`, or a missing field. ShapeError: a wrong shape.
    """
    if not isinstance(measurement, Measurement):
        raise SensorError(f"plant.measure() returned {type(measurement).__name__}; it must return a "
                          "parallel_gpc.estimation.Measurement(drives=..., rates=..., state=...)")
    need = {"state": 2 * n_y} if sensors.kind == "full" else {"drives": n_u}
    if sensors.kind == "encoders" and measurement.rates is not None:
        need["rates"] = n_u
    for field, size in need.items():
        value = getattr(measurement, field)
        if value is None:
            raise SensorError(f"{sensors.kind} sensors need Measurement.{field} ({size} values); plant.measure() "
                              "returned None there")
        if np.shape(value) != (size,):
            raise ShapeError(f"plant.measure() returned {field} of shape {np.shape(value)}; expected ({size},)")
    return measurement


class SensedPlant:
    """A :class:`~parallel_gpc.model.ConstrainedPlant` (or ReducedPlant) behind simulated sensors.

    Args:
        plant: the simulated machine; its sample time ``plant.Ts`` (s) is the one of :meth:`apply`.
        sensors: what is measured; encoder readings are quantized to the resolution (after
            ``noise_counts`` of white noise) and arrive ``delay`` samples late.
        seed: seed of the reading noise.
    """

    def __init__(self, plant, sensors: Sensors = Sensors(), seed: int = 0):
        if not isinstance(sensors, Sensors):
            raise InvalidParameterError(f"sensors must be a Sensors, got {type(sensors).__name__}")
        self.plant = plant
        self.robot = plant.robot
        self.Ts = plant.Ts
        self.sensors = sensors
        self._rng = np.random.default_rng(seed)
        self._resolution = sensors.resolution(self.robot)
        self._rates = sensors.measures_rates(self.robot)
        self._queue = deque(maxlen=sensors.delay + 1)

    @property
    def q(self) -> np.ndarray:
        """(nq,) the simulated configuration (for the 3-D view)."""
        return self.plant.q

    @property
    def saturated(self) -> int:
        return self.plant.saturated

    def input_matrix(self) -> np.ndarray:
        return self.plant.input_matrix()

    def true_state(self) -> np.ndarray:
        """(2 n_y,) the true [y, ẏ]."""
        return self.plant.X

    def _read(self) -> Measurement:
        if self.sensors.kind == "full":
            return Measurement(state=self.plant.X)
        r = self.robot
        drives = encoder_readings(self.sensors, self._resolution, np.asarray(self.plant.q)[r.drive_q_indices],
                                  self._rng)
        rates = None
        if self._rates:
            v = np.asarray(self.plant.v) if hasattr(self.plant, "v") else \
                r.velocity_map(self.plant.q)[0] @ self.plant.X[r.n_y:]
            rates = v[r.drive_idx] + self._rng.normal(0.0, self.sensors.rate_noise, r.n_u)
        return Measurement(drives=drives, rates=rates)

    def measure(self) -> Measurement:
        """The readings of ``delay`` samples ago (the first sample repeats the first reading)."""
        self._queue.append(self._read())
        return self._queue[0]

    def apply(self, u) -> None:
        """Hold u for one sample Ts."""
        self.plant.step(u)
