"""What is measured: the sensor description and one sample of readings.

A real parallel robot measures its drive encoders (angles of rotary drives, lengths of
prismatic ones, quantized), sometimes the drive rates, rarely the platform pose. ``full``
sensors measure the state X = [y, ẏ] itself (the simulation studies' idealization).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidParameterError
from ..model import drive_resolution
from ..validation import number

#: what a :class:`Sensors` may measure
SENSOR_KINDS = ("full", "encoders")


@dataclass(frozen=True)
class Sensors:
    """What the machine measures.

    Attributes:
        kind: ``"full"`` (the state [y, ẏ], exact) or ``"encoders"`` (drive positions).
        counts_per_rev: encoder counts per revolution of a revolute drive; None: the robot
            file's ``[sensors]`` value, else 2^20.
        counts_per_m: counts per metre of a prismatic drive's scale; None: the robot file's
            value, else 10^7 (0.1 µm).
        rates: drive rates (rad/s, m/s) are measured too (None: the robot file's ``rates``, else False).
        noise_counts: white noise on each encoder reading, standard deviation in counts (added
            before quantization; 0: quantization only).
        rate_noise: standard deviation of the drive-rate noise (rad/s or m/s); also the rates'
            weight in the estimator. Default 1e-4.
        delay: samples between a reading and its arrival (0 or 1).
    """

    kind: str = "encoders"
    counts_per_rev: float | None = None
    counts_per_m: float | None = None
    rates: bool | None = None
    noise_counts: float = 0.0
    rate_noise: float = 1e-4
    delay: int = 0

    def __post_init__(self):
        if self.kind not in SENSOR_KINDS:
            raise InvalidParameterError(f"sensors kind {self.kind!r} is not one of {list(SENSOR_KINDS)}")
        for name in ("counts_per_rev", "counts_per_m"):
            value = getattr(self, name)
            if value is not None and not (number(name, value) > 0 and np.isfinite(value)):
                raise InvalidParameterError(f"{name} = {value!r} must be a finite number > 0 (counts)")
        for name in ("noise_counts", "rate_noise"):
            value = number(name, getattr(self, name))
            if not (value >= 0 and np.isfinite(value)):
                raise InvalidParameterError(f"{name} = {getattr(self, name)!r} must be finite and ≥ 0")
        if self.delay not in (0, 1) or isinstance(self.delay, bool):
            raise InvalidParameterError(f"sensor delay = {self.delay!r} samples must be 0 or 1")

    @classmethod
    def parse(cls, spec: str) -> "Sensors":
        """The CLI's ``--sensors``: ``"full"``, ``"encoders"`` or ``"encoders:RESOLUTION"``.

        RESOLUTION is one or two comma-separated items: ``N`` or ``rev=N`` — counts per revolution
        of the revolute drives — and ``m=N`` — counts per metre of the prismatic drives' scales.
        N is a number or a power of two ``2^k``: ``encoders:2^16``, ``encoders:m=1e5``,
        ``encoders:2^16,m=3.5e4``. What is not given comes from the robot file or the defaults.
        """
        kind, _, counts = str(spec).partition(":")
        if kind not in SENSOR_KINDS or (counts and kind != "encoders"):
            raise InvalidParameterError(f"sensors {spec!r} is not 'full', 'encoders' or 'encoders:RESOLUTION' "
                                        "(e.g. encoders:65536, encoders:2^16, encoders:m=1e5, encoders:2^16,m=1e5)")
        if not counts:
            return cls(kind)
        values = {}
        for item in counts.split(","):
            key, eq, text = item.strip().rpartition("=")
            field = {None: "counts_per_rev", "rev": "counts_per_rev", "m": "counts_per_m"}.get(key.strip() if eq else None)
            if field is None or field in values:
                raise InvalidParameterError(f"sensors {spec!r}: {item!r} is not N or rev=N (counts per revolution) "
                                            "or m=N (counts per metre), each at most once")
            values[field] = _count(spec, text.strip())
        return cls(kind, **values)
    def resolution(self, robot) -> np.ndarray:
        """(n_u,) size of one count of each drive (rad or m)."""
        return drive_resolution(robot, self.counts_per_rev, self.counts_per_m)

    def measures_rates(self, robot) -> bool:
        """Whether the drive rates are measured (this object's ``rates``, else the robot file's)."""
        return bool(robot.description.sensors.get("rates", False)) if self.rates is None else bool(self.rates)

    def reading_std(self, robot) -> np.ndarray:
        """(n_u,) standard deviation of a reading's error (rad or m): quantization (Δ/√12) and noise."""
        res = self.resolution(robot)
        return res * np.sqrt(1.0 / 12.0 + self.noise_counts**2)


def _count(spec: str, text: str) -> float:
    """A count of a ``--sensors`` spec: a number or ``2^k``."""
    try:
        base, caret, power = text.partition("^")
        value = float(base) ** float(power) if caret else float(text)
    except (ValueError, OverflowError):
        raise InvalidParameterError(f"sensors {spec!r}: {text!r} is not a number of counts (e.g. 1048576, 2^20 "
                                    "or 1e5)") from None
    if not (value > 0 and np.isfinite(value)):
        raise InvalidParameterError(f"sensors {spec!r}: {text!r} counts must be finite and > 0")
    return value


def encoder_readings(sensors: Sensors, resolution: np.ndarray, exact: np.ndarray,
                     rng: np.random.Generator) -> np.ndarray:
    """(n_u,) what the encoders read at the exact drive positions (rad or m): white noise of
    ``noise_counts`` counts, then quantized to the resolution (rounded to the nearest count)."""
    noisy = exact + rng.normal(0.0, sensors.noise_counts, exact.shape) * resolution if sensors.noise_counts else exact
    return np.round(noisy / resolution) * resolution


@dataclass(frozen=True)
class Measurement:
    """One sample of what the machine measured (None: not measured).

    Attributes:
        drives: (n_u,) drive positions (rad or m), in the order of the robot's drives.
        rates: (n_u,) drive rates (rad/s or m/s).
        state: (2 n_y,) the state [y, ẏ] (m, rad, m/s, rad/s), when the pose is measured.
    """

    drives: np.ndarray | None = None
    rates: np.ndarray | None = None
    state: np.ndarray | None = None
