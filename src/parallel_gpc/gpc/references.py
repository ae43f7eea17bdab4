"""Reference platform motions w(t): the paper's S-curve, holds, sampled trajectories.

Every reference gives ``pose(t)`` (n_y,) in m and rad, and ``window(t, Ts, N)`` — the poses at
t + Ts, …, t + N·Ts that the controller compares its predictions with.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..errors import InvalidParameterError, NonFiniteError, ResultFormatError, ShapeError
from ..results import load_result, save_result
from ..validation import finite_vector, positive


#: Largest CSV reference file read (bytes).
MAX_CSV_BYTES = 64 * 2**20


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

    def to_csv(self, path, labels) -> Path:
        """Write the poses as CSV: a column ``t`` (s) and one column per output label (SI: m, rad),
        the format :meth:`from_csv` reads (``--reference FILE.csv`` on the command line)."""
        labels = [str(x) for x in labels]
        if len(labels) != self.poses.shape[1]:
            raise ShapeError(f"{len(labels)} labels {labels} for poses with {self.poses.shape[1]} columns")
        path = Path(path)
        with path.open("w", newline="") as fh:
            wr = csv.writer(fh)
            wr.writerow(["t", *labels])
            wr.writerows([[repr(float(t)), *(repr(float(v)) for v in row)] for t, row in zip(self.t, self.poses)])
        return path

    @classmethod
    def from_csv(cls, path, labels) -> "SampledTrajectory":
        """Read a CSV reference: a header row with ``t`` and each output label once (any order),
        then one row per sample in SI units (s, m, rad); times strictly increasing, at least 2
        rows, every value finite. The columns are returned in the order of ``labels``.

        Args:
            path: the CSV file (at most :data:`MAX_CSV_BYTES`).
            labels: (n_y,) the robot's output labels (``robot.description.output_labels``).

        Raises:
            InvalidParameterError: a missing, duplicated or unknown column, a value that is not
                a number, fewer than 2 rows, times not strictly increasing, NaN or inf — one
                message naming the file, the line and what is valid.
            OSError: the file cannot be read.
        """
        path = Path(path)
        labels = [str(x) for x in labels]
        where = f"reference file {str(path)!r}"
        expected = f"a header row 't,{','.join(labels)}' (SI units: s, m, rad)"
        if path.stat().st_size > MAX_CSV_BYTES:
            raise InvalidParameterError(f"{where} is {path.stat().st_size} bytes; at most {MAX_CSV_BYTES} are read")
        with path.open(newline="", encoding="utf-8") as fh:
            rows = [row for row in csv.reader(fh) if row and any(c.strip() for c in row)]
        if not rows:
            raise InvalidParameterError(f"{where} is empty; expected {expected}")
        header = [c.strip() for c in rows[0]]
        seen = {name: header.count(name) for name in header}
        twice = sorted(name for name, n in seen.items() if n > 1)
        missing = [name for name in ["t", *labels] if name not in seen]
        unknown = [name for name in header if name not in ["t", *labels]]
        if twice or missing or unknown:
            parts = ([f"duplicated {twice}"] if twice else []) + ([f"missing {missing}"] if missing else []) \
                + ([f"unknown {unknown}"] if unknown else [])
            raise InvalidParameterError(f"{where} has columns {header}: {', '.join(parts)}; expected {expected}")
        order = [header.index(name) for name in ["t", *labels]]
        data = np.empty((len(rows) - 1, len(order)))
        for k, row in enumerate(rows[1:]):
            if len(row) != len(header):
                raise InvalidParameterError(f"{where} line {k + 2} has {len(row)} values; the header has "
                                            f"{len(header)}")
            for j, col in enumerate(order):
                try:
                    data[k, j] = float(row[col])
                except ValueError:
                    raise InvalidParameterError(f"{where} line {k + 2}, column {header[col]!r}: {row[col]!r} is "
                                                "not a number") from None
        if data.shape[0] < 2:
            raise InvalidParameterError(f"{where} has {data.shape[0]} data rows; at least 2 are needed")
        bad = np.argwhere(~np.isfinite(data))
        if bad.size:
            k, j = bad[0]
            raise InvalidParameterError(f"{where} line {k + 2}, column {(['t', *labels])[j]!r} is {data[k, j]}; "
                                        "every value must be finite")
        steps = np.flatnonzero(np.diff(data[:, 0]) <= 0)
        if steps.size:
            k = int(steps[0])
            raise InvalidParameterError(f"{where}: t = {data[k + 1, 0]!r} s on line {k + 3} does not follow "
                                        f"t = {data[k, 0]!r} s; times must be strictly increasing")
        return cls(data[:, 0], data[:, 1:])

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


@dataclass(frozen=True)
class OutputPath(Reference):
    """A built-in path in any robot's output space: a unit curve scaled by ``size`` about ``centre``.

    The curve moves the output columns ``columns`` (usually the translational outputs, m):

    * ``"s-curve"`` (2 columns): the shape of the paper's Fig. 2, two half circles of radius
      ``size`` joined, from ``centre − 2·size`` to ``centre + 2·size`` along the second column;
    * ``"circle"`` (2 columns): one counter-clockwise turn of radius ``size`` about ``centre``,
      starting at ``centre + size`` along the first column;
    * ``"line"`` (any number of columns): the straight segment from ``centre − size·e`` to
      ``centre + size·e``, e = (1, …, 1)/√d along the d columns.

    Every other column follows ``centre + swing·sin(2π s)`` (leaving and returning to its
    centre value; zeros hold it). The path parameter s follows a quintic time scaling over
    ``duration`` after ``t_start``; before and after, the pose is held.

    Attributes:
        kind: ``"s-curve"``, ``"circle"`` or ``"line"``. centre: (n_y,) pose (m, rad).
        size: in the unit of the moved columns (m, or rad for angular ones), > 0.
        columns: indices of the moved outputs. swing: one amplitude per other column (in its
        unit), or () for none. duration, t_start: in s.
    """

    kind: str
    centre: tuple[float, ...]
    size: float
    columns: tuple[int, ...]
    swing: tuple[float, ...] = ()
    duration: float = 2.0
    t_start: float = 0.0

    #: columns each kind moves (None: any number ≥ 1)
    DIMENSIONS = {"s-curve": 2, "circle": 2, "line": None}
    #: largest distance of the unit curve from its centre (size = 1)
    EXTENT = {"s-curve": 2.0, "circle": 1.0, "line": 1.0}

    def __post_init__(self):
        if self.kind not in self.DIMENSIONS:
            raise InvalidParameterError(f"path kind {self.kind!r} is not one of {list(self.DIMENSIONS)}")
        centre = finite_vector("path centre", self.centre)
        cols = tuple(int(c) for c in self.columns)
        need = self.DIMENSIONS[self.kind]
        if (need is not None and len(cols) != need) or not cols or len(set(cols)) != len(cols) \
                or not all(0 <= c < centre.size for c in cols):
            raise InvalidParameterError(f"{self.kind} columns {list(self.columns)} must be "
                                        f"{need or '≥ 1'} distinct indices into the {centre.size} outputs")
        n_other = centre.size - len(cols)
        swing = tuple(self.swing) or (0.0,) * n_other
        object.__setattr__(self, "swing", tuple(finite_vector(f"{self.kind} swing", swing, n_other)))
        object.__setattr__(self, "centre", tuple(centre))
        object.__setattr__(self, "columns", cols)
        positive(f"{self.kind} size", self.size, "")
        positive(f"{self.kind} duration", self.duration, " s")

    @property
    def extent(self) -> float:
        """Largest distance of the moved columns from the centre (size × the unit curve's)."""
        return self.EXTENT[self.kind] * self.size

    def unit_curve(self, s: np.ndarray) -> np.ndarray:
        """(K, d) points of the curve of size 1 about 0 at path parameters s ∈ [0, 1]."""
        s = np.asarray(s, dtype=float)
        if self.kind == "circle":
            phi = 2 * math.pi * s
            return np.column_stack([np.cos(phi), np.sin(phi)])
        if self.kind == "line":
            d = len(self.columns)
            return np.multiply.outer(2.0 * s - 1.0, np.full(d, 1.0 / math.sqrt(d)))
        first = s <= 0.5
        theta = np.where(first, -math.pi / 2 + 2 * math.pi * s, -math.pi / 2 - 2 * math.pi * (s - 0.5))
        return np.column_stack([np.cos(theta), np.where(first, -1.0, 1.0) + np.sin(theta)])

    def pose(self, t: float) -> np.ndarray:
        return self.sample([t])[0]

    def sample(self, times) -> np.ndarray:
        """(K, n_y) poses at the given times (s)."""
        s = quintic_array((np.atleast_1d(np.asarray(times, dtype=float)) - self.t_start) / self.duration)
        poses = np.tile(np.array(self.centre), (s.size, 1))
        cols = list(self.columns)
        poses[:, cols] += self.size * self.unit_curve(s)
        others = [i for i in range(poses.shape[1]) if i not in self.columns]
        poses[:, others] += np.multiply.outer(np.sin(2 * math.pi * s), np.asarray(self.swing))
        return poses


#: Built-in paths :func:`path_for` builds ("auto": the robot's default path).
PATH_KINDS = ("auto", "s-curve", "circle", "line", "helix")
#: Default size of the generic paths (m for translational outputs, rad for angular ones): the
#: S-curve's and circle's radius, the line's half length.
DEFAULT_PATH_SIZE = {"s-curve": 0.05, "circle": 0.08, "line": 0.1}
#: Swing (rad) of the angular outputs a path does not move (and of the helix's angles).
ANGLE_SWING = 0.05
#: Home pose (x m, y m, ψ rad) of the embedded planar robots: the centre of the paper's S-curve
#: (:class:`SCurve`'s defaults) and the pose the paper's hold target (0.55 m, 0.55 m, 5°) is near.
PAPER_PLANAR_HOME = (0.5, 0.5, 0.0)


def _is_planar(angular: np.ndarray) -> bool:
    return angular.tolist() == [False, False, True]


def is_paper_planar(home, angular) -> bool:
    """Planar [x, y, ψ] outputs with the paper's home (:data:`PAPER_PLANAR_HOME`): the robots the
    paper's S-curve, hold target and poses A, B are drawn for (another planar robot's workspace
    need not hold them).

    Args:
        home: (n_y,) home pose (m, rad). angular: (n_y,) bool, True for angular outputs.
    """
    angular = np.asarray(angular, dtype=bool)
    return _is_planar(angular) and bool(np.allclose(home, PAPER_PLANAR_HOME, rtol=0.0, atol=1e-9))


def moving_columns(angular) -> list[int]:
    """Outputs a built-in path moves: the translational ones (m), or every output when all are
    angles (rad)."""
    angular = np.asarray(angular, dtype=bool)
    lin = np.flatnonzero(~angular)
    return [int(i) for i in (lin if lin.size else np.arange(angular.size))]


def _describe(angular, labels) -> str:
    angular = np.asarray(angular, dtype=bool)
    labels = list(labels) if labels is not None else [f"y{i + 1}" for i in range(angular.size)]
    return "[" + ", ".join(f"{name} {'rad' if a else 'm'}" for name, a in zip(labels, angular)) + "]"


def default_path_kind(angular) -> str:
    """What ``"auto"`` means for these outputs: an S-curve for planar [x, y, ψ] outputs (the
    paper's on the paper's home, see :func:`path_for`), the helix for three translational outputs, an S-curve for two, a line for one."""
    angular = np.asarray(angular, dtype=bool)
    if _is_planar(angular):
        return "s-curve"
    d = len(moving_columns(angular))
    return "helix" if d == 3 else "s-curve" if d == 2 else "line"


def path_for(kind: str, home_pose, angular, duration: float, size: float | None = None,
             labels=None) -> Reference:
    """A built-in path in the output space of a robot (sized by ``size``; no workspace check:
    :func:`~parallel_gpc.gpc.robot_references.reference_for` sizes and checks it for a robot).

    Args:
        kind: ``"s-curve"`` (planar [x m, y m, ψ rad] outputs with the paper's home
            :data:`PAPER_PLANAR_HOME`: the paper's S-curve :class:`SCurve`, unchanged; else an
            :class:`OutputPath` S-curve in the plane of the first two translational outputs,
            centred on home), ``"circle"`` (ditto, a circle about
            home), ``"line"`` (a segment through home along the diagonal of the translational
            outputs), ``"helix"`` (three translational outputs: one turn of radius 0.08 m rising
            0.12 m, centred on the home pose) or ``"auto"`` (:func:`default_path_kind`). Angular
            outputs a path does not move swing by ±:data:`ANGLE_SWING` rad and back; other
            translational outputs are held. Without translational outputs the paths move the angles.
        home_pose: (n_y,) home pose of the robot (m, rad).
        angular: (n_y,) bool, True for angular outputs (``ParallelRobot.output_angular``).
        duration: s, time of the motion.
        size: the path's size (m; rad when it moves angles): the radius of the S-curve's half
            circles or of the circle, the line's half length; for the helix a scale of its
            radius and rise (1 = 0.08 m, 0.12 m). None: :data:`DEFAULT_PATH_SIZE` (helix 1).
            Ignored by the planar S-curve.
        labels: (n_y,) output names for the error messages.

    Raises:
        InvalidParameterError: an unknown kind, or a path that needs more outputs than there are.
    """
    angular = np.asarray(angular, dtype=bool)
    home = finite_vector("home pose", home_pose, angular.size)
    if kind not in PATH_KINDS:
        raise InvalidParameterError(f"reference {kind!r} is not one of {list(PATH_KINDS)}")
    if kind == "auto":
        kind = default_path_kind(angular)
    if kind == "s-curve" and is_paper_planar(home, angular):
        return SCurve(duration=duration)
    cols = moving_columns(angular)
    outputs = _describe(angular, labels)
    if kind == "helix":
        if len(cols) != 3 or angular[cols].any():
            raise InvalidParameterError(f"the helix needs 3 translational outputs; this robot's outputs are {outputs} "
                                        "(use s-curve, circle, line, hold or a CSV file)")
        scale = 1.0 if size is None else positive("helix size", size, "")
        helix = Helix(tuple(home), radius=0.08 * scale, rise=0.12 * scale, duration=duration,
                      position_columns=tuple(cols), angle_amplitude=(ANGLE_SWING,) * int(angular.sum()))
        start = home.copy()
        start[cols] += [helix.radius, 0.0, -helix.rise / 2]  # centre the helix on the home pose
        return replace(helix, start=tuple(start))
    need = OutputPath.DIMENSIONS[kind]
    if need is not None:
        if len(cols) < need:
            raise InvalidParameterError(f"the {kind} needs {need} translational outputs; this robot's outputs are "
                                        f"{outputs} (use line, hold or a CSV file)")
        cols = cols[:need]
    others = [i for i in range(angular.size) if i not in cols]
    return OutputPath(kind, tuple(home), DEFAULT_PATH_SIZE[kind] if size is None else size, tuple(cols),
                      tuple(ANGLE_SWING if angular[i] and not angular[cols].any() else 0.0 for i in others),
                      duration=duration)


def hold_pose_for(home_pose, angular) -> np.ndarray:
    """A hold target near home: the paper's (0.55 m, 0.55 m, 5°) for planar [x, y, ψ] outputs
    with the paper's home :data:`PAPER_PLANAR_HOME`; else home + 0.02 m on each translational
    output."""
    angular = np.asarray(angular, dtype=bool)
    home = finite_vector("home pose", home_pose, angular.size)
    if is_paper_planar(home, angular):
        return np.array([0.55, 0.55, math.radians(5.0)])
    return home + np.where(angular, 0.0, 0.02)
