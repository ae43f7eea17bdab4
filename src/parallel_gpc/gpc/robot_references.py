"""References for a given robot: the built-in paths in its own output space, sized to its
workspace around home, reference files, and the check of every reference before a run.

* :func:`reference_for` turns a name (``"auto"``, ``"s-curve"``, ``"circle"``, ``"line"``,
  ``"helix"``, ``"hold"``), a file (``.csv``: a column ``t`` and one per output label, SI units;
  ``.npz``: a plan or saved reference) or a :class:`~parallel_gpc.gpc.references.Reference`
  into the reference of a run.
* :func:`sized_path` probes the workspace along rays from home with the robot's own assembly
  and the controller's conditioning check (:func:`ray_reach`); a built-in path reaches at most
  :data:`WORKSPACE_FRACTION` of the distance found along each ray (its default size if the
  workspace is larger).
* :func:`check_reference` assembles the reference at its sample poses before the run and names
  the first pose that is unreachable or near-singular.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import (AssemblyError, InvalidParameterError, NonFiniteError, ShapeError, SingularPoseError,
                      UnreachablePoseError)
from ..model import ReducedModel
from ..validation import positive, rounded
from .protocol import condition_number
from .references import (PATH_KINDS, Helix, Hold, Reference, SampledTrajectory, SCurve,
                         hold_pose_for, moving_columns, path_for)

#: Names :func:`reference_for` accepts (besides a file path or a Reference).
REFERENCE_KINDS = (*PATH_KINDS, "hold")
#: Largest fraction of the probed workspace radius a built-in path may reach from home.
WORKSPACE_FRACTION = 0.5
#: Most poses :func:`check_reference` assembles (the run's samples, thinned evenly beyond this).
MAX_CHECKED_POSES = 200
#: Probe steps along each ray of :func:`workspace_radius`.
PROBE_STEPS = 16


def probe_directions(d: int) -> np.ndarray:
    """(n, d) unit directions of the workspace probe: ±1 (d = 1); 8 at 45° (d = 2); the 6 axes
    and 8 diagonals (d = 3); the 2·d axes (d > 3)."""
    if d == 1:
        return np.array([[1.0], [-1.0]])
    if d == 2:
        phi = np.arange(8) * math.pi / 4
        return np.column_stack([np.cos(phi), np.sin(phi)])
    axes = np.vstack([np.eye(d), -np.eye(d)])
    if d > 3:
        return axes
    diag = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float) / math.sqrt(3)
    return np.vstack([axes, diag])


def gain_condition(model: ReducedModel, q: np.ndarray) -> float:
    """cond(g) = cond(M_r⁻¹ B_r) at configuration q, at rest: the number the controller bounds by
    its ``max_condition`` (inf at a singular pose)."""
    try:
        return condition_number(model.terms_at_q(q, np.zeros(model.n_y)).g)
    except SingularPoseError:
        return math.inf


def ray_reach(robot, columns, direction, max_distance: float, max_condition: float, steps: int = PROBE_STEPS,
              model: ReducedModel | None = None) -> float:
    """How far the outputs ``columns`` can move from home along ``direction`` (the others held).

    Poses at ``max_distance·k/steps``, k = 1 … steps, are assembled warm-started from the
    previous one; the ray ends at the first pose that cannot be assembled on the home branch or
    whose cond(M_r⁻¹ B_r) exceeds ``max_condition`` (the controller's limit).

    Args:
        robot: the :class:`~parallel_gpc.model.robot.ParallelRobot`.
        columns: indices of the outputs probed (m, or rad for angular outputs).
        direction: (len(columns),) unit direction.
        max_distance: how far to probe (same unit), > 0.
        max_condition: the controller's limit on cond(g).
        steps: poses on the ray.

    Returns:
        The last good distance (``max_distance`` if every pose passed, 0 if the first fails).
    """
    max_distance = positive("probe distance", max_distance, "")
    model = ReducedModel(robot) if model is None else model
    columns, direction = list(columns), np.asarray(direction, dtype=float)
    q, good = robot.q_home, 0.0
    for k in range(1, steps + 1):
        distance = max_distance * k / steps
        pose = robot.home_pose.copy()
        pose[columns] += distance * direction
        try:
            q = robot.assemble(pose, q)
        except AssemblyError:
            break
        if gain_condition(model, q) > max_condition:
            break
        good = distance
    return good


def workspace_radius(robot, columns, max_distance: float, max_condition: float, steps: int = PROBE_STEPS) -> float:
    """Distance from home to the nearest pose found unreachable or near-singular: the smallest
    :func:`ray_reach` over the rays of :func:`probe_directions` in the outputs ``columns``
    (``max_distance`` if none ends before)."""
    model = ReducedModel(robot)
    return min(ray_reach(robot, columns, d, max_distance, max_condition, steps, model)
               for d in probe_directions(len(list(columns))))


def sized_path(kind: str, robot, duration: float, max_condition: float) -> Reference:
    """The built-in path ``kind`` for ``robot`` (see :func:`~parallel_gpc.gpc.references.path_for`)
    sized to the workspace around home.

    The path at its default size reaches h_i = max_s (p(s) − home)·d_i along each probe
    direction d_i of its moved outputs; the workspace is probed along d_i to h_i /
    :data:`WORKSPACE_FRACTION` (:func:`ray_reach`, giving ρ_i), and the path is scaled by
    min(1, min_i WORKSPACE_FRACTION·ρ_i / h_i): its default size where the workspace is large
    enough, smaller where it is not. The paper's S-curve (planar outputs at the paper's home) is
    returned as it is.

    Raises:
        InvalidParameterError: the path does not fit the robot's outputs (one line naming them).
        UnreachablePoseError: the workspace ends next to home (no path fits).
    """
    labels = robot.description.output_labels
    ref = path_for(kind, robot.home_pose, robot.output_angular, duration, labels=labels)
    if isinstance(ref, SCurve):
        return ref
    cols = moving_columns(robot.output_angular)
    points = ref.sample(np.linspace(0.0, duration, 201))[:, cols] - robot.home_pose[cols]
    model = ReducedModel(robot)
    scale = 1.0
    for direction in probe_directions(len(cols)):
        support = float(np.max(points @ direction))
        if support <= 0.0:
            continue
        reach = ray_reach(robot, cols, direction, support / WORKSPACE_FRACTION, max_condition, model=model)
        scale = min(scale, WORKSPACE_FRACTION * reach / support)
    if scale >= 1.0:
        return ref
    if scale <= 0.0:
        raise UnreachablePoseError(f"the workspace of {robot.name!r} ends next to its home pose "
                                   f"{rounded(robot.home_pose, 6)}: no {kind} fits; give a CSV reference")
    size = scale if isinstance(ref, Helix) else scale * ref.size
    return path_for(kind, robot.home_pose, robot.output_angular, duration, size=size, labels=labels)


def reference_for(spec, robot, duration: float, max_condition: float = 1e3, hold_pose=None) -> Reference:
    """The reference of a run on ``robot``.

    Args:
        spec: a name of :data:`REFERENCE_KINDS` (built-in paths via :func:`sized_path`;
            ``"hold"``: ``hold_pose``), a path to a ``.csv`` file (a column ``t`` and one column
            per output label, SI units: :meth:`SampledTrajectory.from_csv`) or to a result file
            (``.npz``: :meth:`SampledTrajectory.load`), or a :class:`Reference` (returned as is).
        robot: the :class:`~parallel_gpc.model.robot.ParallelRobot`.
        duration: s, time of the motion of a built-in path.
        max_condition: the controller's limit on cond(g), for the workspace probe.
        hold_pose: (n_y,) target of ``"hold"`` (m, rad); None: near home (:func:`hold_pose_for`).

    Raises:
        InvalidParameterError: an unknown name, a missing file, a malformed file, or a path that
            does not fit the robot's outputs.
    """
    if isinstance(spec, Reference):
        return spec
    if not isinstance(spec, (str, Path)):
        raise InvalidParameterError(f"reference {spec!r} is not one of {list(REFERENCE_KINDS)}, a .csv or .npz "
                                    "file, or a Reference")
    if spec == "hold":
        pose = hold_pose_for(robot.home_pose, robot.output_angular) if hold_pose is None else hold_pose
        return Hold(tuple(float(v) for v in pose))
    if spec in PATH_KINDS:
        return sized_path(spec, robot, duration, max_condition)
    path = Path(spec)
    if path.suffix.lower() not in (".csv", ".npz"):
        raise InvalidParameterError(f"reference {str(spec)!r} is not one of {list(REFERENCE_KINDS)}, nor a .csv or "
                                    ".npz file")
    if not path.is_file():
        raise InvalidParameterError(f"reference file {str(spec)!r} does not exist (or is not a regular file)")
    if path.suffix.lower() == ".csv":
        return SampledTrajectory.from_csv(path, robot.description.output_labels)
    return SampledTrajectory.load(path)


def is_file_reference(spec) -> bool:
    """True when ``spec`` names a reference file (``.csv`` or ``.npz``) rather than a built-in path."""
    return isinstance(spec, (str, Path)) and Path(spec).suffix.lower() in (".csv", ".npz")


def check_times(reference: Reference, duration: float, Ts: float) -> np.ndarray:
    """The times (s) at which :func:`check_reference` checks a run of ``duration`` sampled at
    ``Ts``: every sample (thinned evenly to :data:`MAX_CHECKED_POSES`), plus the knots of a
    sampled trajectory inside the run (its corners)."""
    n = int(math.floor(duration / Ts + 1e-9)) + 1
    times = Ts * np.unique(np.linspace(0, n - 1, min(n, MAX_CHECKED_POSES)).round())
    if isinstance(reference, SampledTrajectory):
        times = np.union1d(times, reference.t[(reference.t >= 0.0) & (reference.t <= duration)])
    return times


def check_reference(robot, reference: Reference, times, max_condition: float | None,
                    model: ReducedModel | None = None) -> None:
    """Assemble ``reference`` at ``times`` (s) on ``robot``'s home branch, warm-started along
    the path, and check cond(M_r⁻¹ B_r) ≤ ``max_condition`` (the controller's limit) at each pose
    (None: assembly only, the cheap check).

    Raises:
        ShapeError: the reference has another number of outputs than the robot.
        NonFiniteError: a pose is NaN or infinite.
        UnreachablePoseError: a pose cannot be assembled (outside the workspace).
        SingularPoseError: a pose is near-singular.
        Both name the first bad pose and its time in one line.
    """
    times = np.asarray(times, dtype=float)
    poses = np.atleast_2d(reference.sample(times))
    space = robot.output_space
    if poses.shape[1] != robot.n_y:
        raise ShapeError(f"the reference has {poses.shape[1]} outputs; robot {robot.name!r} has {robot.n_y}: "
                         f"{space.describe()}")
    if max_condition is not None:
        model = ReducedModel(robot) if model is None else model
    q = None
    for t, pose in zip(times, poses):
        where = (f"reference pose {rounded(pose, 6)} ({', '.join(space.labels)}) at t = {t:.4g} s")
        if not np.all(np.isfinite(pose)):
            raise NonFiniteError(f"the {where} is not finite; poses must be finite")
        try:
            q = robot.assemble(pose, q)
        except AssemblyError:
            raise UnreachablePoseError(f"{where} is outside the workspace of {robot.name!r} (it cannot be "
                                       "assembled on the home branch); use a smaller or shifted reference") from None
        if max_condition is None:
            continue
        cond = gain_condition(model, q)
        if cond > max_condition:
            raise SingularPoseError(f"{where} is near-singular on {robot.name!r}: cond(M_r⁻¹ B_r) = {cond:.3g} > "
                                    f"{max_condition:.3g}, the controller's limit; use a smaller or shifted reference")
