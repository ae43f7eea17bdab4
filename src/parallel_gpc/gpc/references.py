"""Reference platform motions w(t): the paper's S-curve, holds, sampled trajectories.

Every reference gives ``pose(t)`` (n_y,) in m and rad, and ``window(t, Ts, N)`` — the poses at
t + Ts, …, t + N·Ts that the controller compares its predictions with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InvalidParameterError, NonFiniteError, ResultFormatError, ShapeError
from ..results import load_result, save_result
from ..validation import finite_vector, positive


class Reference:
    """Base class: subclasses implement :meth:`pose`."""

    def pose(self, t: float) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def window(self, t: float, Ts: float, N: int) -> np.ndarray:
        """(N, n_y) poses at t + Ts … t + N·Ts."""
        return np.array([self.pose(t + (j + 1) * Ts) for j in range(N)])

    def initial_state(self, t: float = 0.0) -> np.ndarray:
        """(2·n_y,) state X = [y, ẏ] at rest on the reference at time t (s): pose (m, rad), zero velocity.

        The usual start of a closed-loop run: ``ConstrainedPlant(robot, ref.initial_state())``.
        """
        pose = np.asarray(self.pose(t), dtype=float)
        return np.concatenate([pose, np.zeros_like(pose)])

    def sample(self, times) -> np.ndarray:
        """(K, n_y) poses at the given times (s)."""
        return np.array([self.pose(float(t)) for t in times])


def quintic(tau: float) -> float:
    """Smooth time scaling s(τ) = 10τ³ − 15τ⁴ + 6τ⁵ on [0, 1] (zero velocity and acceleration at the ends)."""
    tau = min(max(tau, 0.0), 1.0)
    return tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)


@dataclass(frozen=True)
class SCurve(Reference):
    """The S-shaped platform path of the paper's Fig. 2: two half circles joined.

    The path starts at ``start`` (x, y), runs a half circle of ``radius`` counter-clockwise on
    the right, then a half circle clockwise on the left, ending 4·radius above the start. ψ
    goes smoothly from ``psi_start`` to ``psi_end``. Arc length follows a quintic time
    scaling over ``duration`` after ``t_start``; before and after, the pose is held.

    Attributes:
        start: (x, y) of the start point in m. radius: in m. psi_start, psi_end: in rad.
        duration, t_start: in s.
    """

    start: tuple[float, float] = (0.5, 0.2)
    radius: float = 0.15
    psi_start: float = math.radians(-15.0)
    psi_end: float = math.radians(15.0)
    duration: float = 2.0
    t_start: float = 0.0

    def __post_init__(self):
        positive("S-curve radius", self.radius, " m")
        positive("S-curve duration", self.duration, " s")

    def pose(self, t: float) -> np.ndarray:
        s = quintic((t - self.t_start) / self.duration)
        x0, y0 = self.start
        r = self.radius
        if s <= 0.5:
            theta = -math.pi / 2 + 2 * math.pi * s
            cx, cy = x0, y0 + r
        else:
            theta = -math.pi / 2 - 2 * math.pi * (s - 0.5)
            cx, cy = x0, y0 + 3 * r
        psi = self.psi_start + (self.psi_end - self.psi_start) * s
        return np.array([cx + r * math.cos(theta), cy + r * math.sin(theta), psi])


@dataclass(frozen=True)
class Hold(Reference):
    """A constant pose (m, m, rad) — step or hold references."""

    target: tuple[float, ...]

    def pose(self, t: float) -> np.ndarray:
        return np.asarray(self.target, dtype=float)


class SampledTrajectory(Reference):
    """A reference given by samples (e.g. a planned trajectory), linearly interpolated and held
    at its ends.

    Args:
        t: (K,) increasing sample times in s.
        poses: (K, n_y) poses (m, rad).
        velocities: optional (K, n_y) velocities (m/s, rad/s), kept for plots and saving.
    """

    def __init__(self, t, poses, velocities=None):
        self.t = finite_vector("trajectory times", t)
        self.poses = np.asarray(poses, dtype=float)
        if self.poses.ndim != 2 or self.poses.shape[0] != self.t.shape[0]:
            raise ShapeError(f"trajectory poses have shape {self.poses.shape}; expected ({self.t.shape[0]}, n_y)")
        if self.t.shape[0] < 2 or np.any(np.diff(self.t) <= 0):
            raise InvalidParameterError("trajectory times must be ≥ 2 strictly increasing values")
        if not np.all(np.isfinite(self.poses)):
            bad = np.argwhere(~np.isfinite(self.poses))[0]
            raise NonFiniteError(f"trajectory pose {self.poses[bad[0]].tolist()} at t = {self.t[bad[0]]} s "
                                 "contains NaN or inf; poses must be finite")
        self.velocities = None if velocities is None else np.asarray(velocities, dtype=float)

    def pose(self, t: float) -> np.ndarray:
        return np.array([np.interp(t, self.t, self.poses[:, i]) for i in range(self.poses.shape[1])])

    def window(self, t: float, Ts: float, N: int) -> np.ndarray:
        times = t + Ts * np.arange(1, N + 1)
        return np.stack([np.interp(times, self.t, self.poses[:, i]) for i in range(self.poses.shape[1])], axis=1)

    def save(self, path) -> Path:
        """Write a result file (:mod:`parallel_gpc.results`, kind ``"reference"``): ``t``,
        ``reference`` (the poses) and ``velocities`` if given."""
        extra = {} if self.velocities is None else {"velocities": self.velocities}
        return save_result(path, None, self.t, reference=self.poses, kind="reference", arrays=extra)

    @classmethod
    def load(cls, path) -> "SampledTrajectory":
        """Read the poses of a result file: a plan's (``parallel-gpc plan``), a saved reference's,
        or a tracking run's reference.

        Raises:
            ResultFormatError: the file holds no poses (or is not a result file).
        """
        result = load_result(path)
        poses = result.planned if result.planned is not None else result.reference
        if poses is None:
            raise ResultFormatError(f"{str(path)!r} (kind {result.kind!r}) holds no planned or reference poses")
        return cls(result.t, poses, result.arrays.get("velocities"))
