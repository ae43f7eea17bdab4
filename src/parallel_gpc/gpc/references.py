"""Reference platform motions w(t): the paper's S-curve, holds, sampled trajectories.

Every reference gives ``pose(t)`` (n_y,) in m and rad, and ``window(t, Ts, N)`` — the poses at
t + Ts, …, t + N·Ts that the controller compares its predictions with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
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
        """(N, n_y) poses at t + Ts … t + N·Ts (one vectorized :meth:`sample` where the
        subclass has one)."""
        return self.sample(t + Ts * np.arange(1, N + 1))

    def initial_state(self, t: float = 0.0) -> np.ndarray:
        """(2·n_y,) state X = [y, ẏ] at rest on the reference at time t (s): pose (m, rad), zero velocity.

        The usual start of a closed-loop run: ``ConstrainedPlant(robot, ref.initial_state())``.
        """
        pose = np.asarray(self.pose(t), dtype=float)
        return np.concatenate([pose, np.zeros_like(pose)])

    def sample(self, times) -> np.ndarray:
        """(K, n_y) poses at the given times (s)."""
        return np.array([self.pose(float(t)) for t in np.asarray(times, dtype=float)])


def pose_error_norms(e, angular=None) -> tuple[np.ndarray, np.ndarray]:
    """Position and orientation parts of pose errors (or velocities).

    Args:
        e: (K, n_y) differences of poses (m, rad).
        angular: (n_y,) bool, True for angular coordinates (``ParallelRobot.output_angular``);
            None: the planar convention, columns 0-1 in m and the rest in rad.

    Returns:
        (K,) Euclidean norms of the translational columns (m) and of the angular columns (rad;
        zeros if there are none).
    """
    e = np.atleast_2d(np.asarray(e, dtype=float))
    if angular is None:
        angular = np.arange(e.shape[1]) >= 2
    angular = np.asarray(angular, dtype=bool)
    return np.linalg.norm(e[:, ~angular], axis=1), np.linalg.norm(e[:, angular], axis=1)


def quintic(tau: float) -> float:
    """Smooth time scaling s(τ) = 10τ³ − 15τ⁴ + 6τ⁵ on [0, 1] (zero velocity and acceleration at the ends)."""
    tau = min(max(tau, 0.0), 1.0)
    return tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)


def quintic_array(tau: np.ndarray) -> np.ndarray:
    """:func:`quintic` of every entry of ``tau`` (the same arithmetic, elementwise)."""
    tau = np.minimum(np.maximum(tau, 0.0), 1.0)
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

    def sample(self, times) -> np.ndarray:
        """(K, 3) poses at the given times (s): :meth:`pose` vectorized over the times."""
        s = quintic_array((np.asarray(times, dtype=float) - self.t_start) / self.duration)
        x0, y0 = self.start
        r = self.radius
        first = s <= 0.5
        if first.all():  # the usual window: on one half circle (np.where for the few that span both)
            theta, cy = -math.pi / 2 + 2 * math.pi * s, y0 + r
        elif not first.any():
            theta, cy = -math.pi / 2 - 2 * math.pi * (s - 0.5), y0 + 3 * r
        else:
            theta = np.where(first, -math.pi / 2 + 2 * math.pi * s, -math.pi / 2 - 2 * math.pi * (s - 0.5))
            cy = np.where(first, y0 + r, y0 + 3 * r)
        out = np.empty((s.size, 3))
        out[:, 0] = x0 + r * np.cos(theta)
        out[:, 1] = cy + r * np.sin(theta)
        out[:, 2] = self.psi_start + (self.psi_end - self.psi_start) * s
        return out


@dataclass(frozen=True)
class Helix(Reference):
    """A spatial helix for robots with three translational outputs (any number of angles).

    The translational columns ``position_columns`` (x, y, z) run ``turns`` turns of a circle
    of ``radius`` about a vertical axis while z rises by ``rise``; the circle's centre is
    ``radius`` along −x from ``start``, so the path starts at ``start``. Every other column
    (angles, in rad) follows ``start + amplitude·sin(2π s)``, leaving and returning to its start
    value (``angle_amplitude`` per angular column in order; zeros keep the orientation
    constant). Arc length follows a quintic time scaling over ``duration`` after ``t_start``;
    before and after, the pose is held.

    Attributes:
        start: (n_y,) start pose (m, rad). radius, rise: in m. turns: number of turns.
        angle_amplitude: (n_y − 3,) in rad, or () for constant angles. duration, t_start: in s.
        position_columns: indices of x, y, z in the pose.
    """

    start: tuple[float, ...]
    radius: float = 0.08
    rise: float = 0.12
    turns: float = 1.0
    angle_amplitude: tuple[float, ...] = ()
    duration: float = 2.0
    t_start: float = 0.0
    position_columns: tuple[int, int, int] = (0, 1, 2)

    def __post_init__(self):
        start = finite_vector("helix start pose", self.start)
        cols = tuple(int(c) for c in self.position_columns)
        if len(cols) != 3 or len(set(cols)) != 3 or not all(0 <= c < start.size for c in cols):
            raise InvalidParameterError(f"helix position_columns = {self.position_columns!r} must be three "
                                        f"distinct indices into the {start.size} pose coordinates")
        n_ang = start.size - 3
        amp = tuple(self.angle_amplitude) or (0.0,) * n_ang
        if len(amp) != n_ang:
            raise InvalidParameterError(f"helix angle_amplitude has {len(amp)} values; expected {n_ang} "
                                        "(one per non-translational pose coordinate, rad) or none")
        object.__setattr__(self, "angle_amplitude", tuple(finite_vector("helix angle_amplitude", amp, n_ang)))
        positive("helix radius", self.radius, " m")
        positive("helix duration", self.duration, " s")
        positive("helix turns", self.turns, "")
        finite_vector("helix rise", [self.rise], 1)

    def pose(self, t: float) -> np.ndarray:
        s = quintic((t - self.t_start) / self.duration)
        pose = np.array(self.start, dtype=float)
        ix, iy, iz = self.position_columns
        phi = 2 * math.pi * self.turns * s
        pose[ix] += self.radius * (math.cos(phi) - 1.0)
        pose[iy] += self.radius * math.sin(phi)
        pose[iz] += self.rise * s
        others = [i for i in range(pose.size) if i not in self.position_columns]
        pose[others] += np.asarray(self.angle_amplitude) * math.sin(2 * math.pi * s)
        return pose

    def sample(self, times) -> np.ndarray:
        """(K, n_y) poses at the given times (s): :meth:`pose` vectorized over the times."""
        s = quintic_array((np.asarray(times, dtype=float) - self.t_start) / self.duration)
        poses = np.tile(np.array(self.start, dtype=float), (s.size, 1))
        ix, iy, iz = self.position_columns
        phi = 2 * math.pi * self.turns * s
        poses[:, ix] += self.radius * (np.cos(phi) - 1.0)
        poses[:, iy] += self.radius * np.sin(phi)
        poses[:, iz] += self.rise * s
        others = [i for i in range(poses.shape[1]) if i not in self.position_columns]
        poses[:, others] += np.multiply.outer(np.sin(2 * math.pi * s), np.asarray(self.angle_amplitude))
        return poses


@dataclass(frozen=True)
class Hold(Reference):
    """A constant pose (m, m, rad) — step or hold references."""

    target: tuple[float, ...]

    def pose(self, t: float) -> np.ndarray:
        return np.asarray(self.target, dtype=float)

    def sample(self, times) -> np.ndarray:
        return np.tile(np.asarray(self.target, dtype=float), (np.asarray(times).size, 1))


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

    def sample(self, times) -> np.ndarray:
        times = np.asarray(times, dtype=float)
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


#: Reference kinds that :func:`path_for` builds.
PATH_KINDS = ("auto", "s-curve", "helix")


def _is_planar(angular: np.ndarray) -> bool:
    return angular.tolist() == [False, False, True]


def path_for(kind: str, home_pose, angular, duration: float) -> Reference:
    """A tracking path for a robot with the given outputs.

    Args:
        kind: ``"s-curve"`` (the paper's planar S-curve, for [x m, y m, ψ rad] outputs),
            ``"helix"`` (one turn of radius 0.08 m rising 0.12 m, centred on the home pose, the
            angles swinging by ±0.05 rad and back; for three translational outputs plus any
            angles) or ``"auto"`` (the S-curve for planar outputs, else the helix).
        home_pose: (n_y,) home pose of the robot (m, rad).
        angular: (n_y,) bool, True for angular outputs (``ParallelRobot.output_angular``).
        duration: s, time of the motion.

    Raises:
        InvalidParameterError: an unknown kind, or a path that does not fit the outputs.
    """
    angular = np.asarray(angular, dtype=bool)
    home = finite_vector("home pose", home_pose, angular.size)
    if kind not in PATH_KINDS:
        raise InvalidParameterError(f"reference {kind!r} is not one of {list(PATH_KINDS)}")
    if kind == "auto":
        kind = "s-curve" if _is_planar(angular) else "helix"
    if kind == "s-curve":
        if not _is_planar(angular):
            raise InvalidParameterError(f"the S-curve is a path of planar [x m, y m, psi rad] outputs; this robot's "
                                        f"outputs have angular flags {angular.tolist()} (use 'helix' or 'hold')")
        return SCurve(duration=duration)
    lin = np.flatnonzero(~angular)
    if lin.size != 3:
        raise InvalidParameterError(f"the helix needs 3 translational outputs (x, y, z in m); this robot has "
                                    f"{lin.size} (angular flags {angular.tolist()}); use 'hold'")
    helix = Helix(tuple(home), duration=duration, position_columns=tuple(int(i) for i in lin),
                  angle_amplitude=(0.05,) * int(angular.sum()))
    start = home.copy()
    start[lin] += [helix.radius, 0.0, -helix.rise / 2]  # centre the helix on the home pose
    return replace(helix, start=tuple(start))


def hold_pose_for(home_pose, angular) -> np.ndarray:
    """A hold target near home: the planar robots' (0.55 m, 0.55 m, 5°) for [x, y, ψ] outputs
    (the home pose there is (0.5, 0.5, 0)); else home + 0.02 m on each translational output."""
    angular = np.asarray(angular, dtype=bool)
    if _is_planar(angular):
        return np.array([0.55, 0.55, math.radians(5.0)])
    return finite_vector("home pose", home_pose, angular.size) + np.where(angular, 0.0, 0.02)
