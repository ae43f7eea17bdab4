"""Forward kinematics from drive readings: the platform pose that explains the encoders.

The unknown is the output y. For a trial y the configuration q(y) is assembled on the home
branch (the robot's warm Newton, its validated path when that fails), so the closures hold
exactly and no iterate can leave the branch; the drive coordinates of q(y) are compared with
the readings r. Weighted Gauss-Newton on

    min_y  Σ_i ((q_drive,i(y) − r_i) / σ_i)²

with the drive Jacobian J = ∂q_drive/∂y = T[drives] (rows of the velocity map q̇ = T ẏ) is
the least-squares answer over redundant drives, weighted by the resolution σ_i of each
encoder. Steps are bounded (trust region in drive space) and halved when the trial pose does
not assemble or does not lower the cost, so readings that some pose explains within their
resolution always give a pose. Readings that no pose explains (a broken encoder) end in
:class:`~parallel_gpc.errors.SensorError` naming the drive with the largest weighted residual.

Drive rates give ẏ by least squares through the same Jacobian: ẏ = argmin ‖(J ẏ − ṙ)/σ_ṙ‖.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import AssemblyError, InvalidParameterError, SensorError, ShapeError, SingularPoseError
from ..validation import finite_vector, rounded

#: default encoder resolution of a revolute drive: 2^20 counts per revolution
DEFAULT_COUNTS_PER_REV = 2.0**20
#: default resolution of a prismatic drive's linear scale: 10^7 counts per metre (0.1 µm)
DEFAULT_COUNTS_PER_M = 1e7
#: largest change of any drive coordinate (rad or m) that one Gauss-Newton step may predict
MAX_DRIVE_STEP = 0.1
#: step halvings tried before an iteration gives up
_HALVINGS = 30
#: converged when the next Gauss-Newton step would move no drive by more than this many counts.
#: The resolution demands far less: the accuracy bound resolution × cond(J) covers the ±½ count of
#: quantization on every drive, and the step not taken adds at most 2 × STOP_COUNTS of that;
#: 10^-4 counts (6e-10 rad at 2^20 counts per revolution) also keeps exact drive positions
#: (simulation, inverse-kinematics round trips) solved to ~1e-9. The loop converges
#: quadratically: on the estimator's path the step after the correction of ~1 count is ~10^-6
#: counts, so this stops one assembly earlier than 10^-6 counts did in 40 % of the calls
#: (planar_4rrr's S-curve: 3.34 → 2.94 iterations per call).
STOP_COUNTS = 1e-4
#: statuses of the compiled loop (native/src/forward.cpp): a solution, the best pose of readings no
#: pose explains; any other status hands the call to this module
SOLVED, INCONSISTENT = 0, 2


@dataclass(slots=True)
class ForwardSolution:
    """What :func:`solve_forward` found (built every sample: a slotted dataclass, not a frozen one,
    whose ``__init__`` costs five times as much).

    Attributes:
        pose: (n_y,) output y (m, rad).
        q: (nq,) assembled configuration at ``pose``.
        jacobian: (n_u, n_y) drive Jacobian J = ∂q_drive/∂y at ``q``.
        residual: (n_u,) q_drive(pose) − readings (rad or m).
        iterations: Gauss-Newton iterations taken.
    """

    pose: np.ndarray
    q: np.ndarray
    jacobian: np.ndarray
    residual: np.ndarray
    iterations: int

    def weighted_residual(self, resolution: np.ndarray) -> np.ndarray:
        """(n_u,) residual in units of each drive's resolution (counts)."""
        return self.residual / resolution


class CompiledForward:
    """The compiled loop of :func:`solve_forward` on one robot (native/src/forward.cpp): a
    ``_native.ModelUpdate`` with the drives set, and where its answer lies in the buffer it fills.

    Args:
        update: the model update (:func:`~parallel_gpc.model.native_update.compiled_forward`).
        n_y, nq, n_u: outputs, configuration size and drives of its robot.

    Attributes:
        size: length of the buffer [pose (n_y), q (nq), J (n_u × n_y, row by row), residual (n_u)].
        q, jacobian, residual: slices of the buffer (the pose is its first n_y entries).
        shape: (n_u, n_y), the drive Jacobian's shape.
    """

    __slots__ = ("update", "size", "q", "jacobian", "residual", "n_y", "shape")

    def __init__(self, update, n_y: int, nq: int, n_u: int):
        self.update = update
        self.n_y, self.shape = n_y, (n_u, n_y)
        a, b = n_y + nq, n_y + nq + n_u * n_y  # the buffer: [pose, q, J row by row, residual]
        self.size = b + n_u
        self.q, self.jacobian, self.residual = slice(n_y, a), slice(a, b), slice(b, b + n_u)

    def solve(self, readings: np.ndarray, resolution: np.ndarray, q_guess: np.ndarray, max_iter: int,
              max_residual: float):
        """(status, solution): :data:`SOLVED` or :data:`INCONSISTENT` with the
        :class:`ForwardSolution` (views of one new buffer), or another status and None (a shape,
        reading, resolution or start the Python checks must judge)."""
        out = np.empty(self.size)
        status, iterations = self.update.solve_forward_into(readings, resolution, q_guess, max_iter, max_residual,
                                                             out)
        if status != SOLVED and status != INCONSISTENT:
            return status, None
        return status, ForwardSolution(out[:self.n_y], out[self.q], out[self.jacobian].reshape(self.shape),
                                       out[self.residual], iterations)


def drive_resolution(robot, counts_per_rev: float | None = None, counts_per_m: float | None = None) -> np.ndarray:
    """(n_u,) size of one count of each drive's encoder: 2π/counts_per_rev (rad) for revolute
    drives, 1/counts_per_m (m) for prismatic ones; None takes the robot file's ``[sensors]``
    value, else :data:`DEFAULT_COUNTS_PER_REV` / :data:`DEFAULT_COUNTS_PER_M`."""
    sidecar = robot.description.sensors or {}
    cpr = counts_per_rev if counts_per_rev is not None else sidecar.get("counts_per_rev", DEFAULT_COUNTS_PER_REV)
    cpm = counts_per_m if counts_per_m is not None else sidecar.get("counts_per_m", DEFAULT_COUNTS_PER_M)
    return np.where(robot.drive_angular, 2.0 * np.pi / cpr, 1.0 / cpm)


def resolution_array(robot, resolution) -> np.ndarray:
    """(n_u,) encoder resolutions (rad or m) from ``resolution``: None = :func:`drive_resolution`,
    a scalar or n_u values; finite and > 0 is checked by :func:`check_resolution` (the compiled
    loop checks it too and hands a bad one to it)."""
    if resolution is None:
        return drive_resolution(robot)
    if type(resolution) is np.ndarray and resolution.shape == (robot.n_u,) and resolution.dtype == float:
        return resolution  # the estimator's case: no copy, no broadcast (a hot path)
    try:
        return np.broadcast_to(np.asarray(resolution, dtype=float), (robot.n_u,))
    except (TypeError, ValueError):
        raise _resolution_error(robot, resolution) from None


def check_resolution(robot, resolution: np.ndarray) -> np.ndarray:
    """``resolution`` ((n_u,) from :func:`resolution_array`) if every entry is finite and > 0."""
    if not (np.all(np.isfinite(resolution)) and np.all(resolution > 0)):
        raise _resolution_error(robot, resolution)
    return resolution


def _resolution_error(robot, resolution) -> InvalidParameterError:
    return InvalidParameterError(f"encoder resolution {np.asarray(resolution).tolist()} must be finite and > 0 "
                                 f"(rad or m per count, a scalar or {robot.n_u} values)")


def check_readings(robot, readings, resolution: np.ndarray, what: str = "drive readings") -> np.ndarray:
    """(n_u,) readings as floats; NaN/inf or values outside the drives' joint range (by more
    than two counts) raise :class:`SensorError` naming the drive."""
    arr = np.asarray(readings, dtype=float)
    if arr.shape != (robot.n_u,):
        raise ShapeError(f"{what} have shape {arr.shape}; {robot.name!r} has {robot.n_u} drives "
                         f"{list(robot.description.drive_joints)}, expected ({robot.n_u},)")
    names = robot.description.drive_joints
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        i = int(bad[0])
        units = robot.drive_position_units  # looked up only for the message (a hot path: every sample)
        raise SensorError(f"{what}: drive {i} ({names[i]!r}) reads {arr[i]}; a reading must be a finite "
                          f"position in {units[i]} (a broken or disconnected encoder?)")
    lo, hi = robot.drive_range
    out = np.flatnonzero((arr < lo - 2 * resolution) | (arr > hi + 2 * resolution))
    if out.size:
        i = int(out[0])
        units = robot.drive_position_units
        raise SensorError(f"{what}: drive {i} ({names[i]!r}) reads {arr[i]:.9g} {units[i]}, outside its range "
                          f"[{lo[i]:.6g}, {hi[i]:.6g}] {units[i]} (a broken encoder or a wrong zero offset?)")
    return arr


def assemble_validated(robot, pose: np.ndarray, q_guess: np.ndarray):
    """(q, T) at ``pose`` on the validated path (:meth:`assemble` from q_guess, continuation from
    home, and the velocity map), or None where the pose does not assemble or is singular."""
    try:
        q = robot.assemble(pose, q_guess)
        T, _ = robot.velocity_map_nocopy(q)
    except (AssemblyError, SingularPoseError):
        return None
    return q, T


def _assembled(robot, pose: np.ndarray, q_guess: np.ndarray):
    """(q, T) at ``pose`` on the home branch from q_guess, or None if it does not assemble there."""
    out = robot.assemble_warm(pose, q_guess)
    if out is not None:
        return out[0], out[1]
    return assemble_validated(robot, pose, q_guess)


def solve_forward(robot, readings, resolution: np.ndarray, q_guess, pose_guess: np.ndarray | None = None,
                  max_residual: float = 50.0, max_iter: int = 50, compiled=None) -> ForwardSolution:
    """Weighted least-squares forward kinematics (see the module docstring).

    Args:
        robot: the :class:`~parallel_gpc.model.robot.ParallelRobot`.
        readings: (n_u,) drive positions (rad or m), checked here (:func:`check_readings`).
        resolution: (n_u,) σ_i, the resolution of each drive's encoder (rad or m): the weights;
            checked here (:func:`check_resolution`).
        q_guess: (nq,) start configuration (the last one for a warm start, else home).
        pose_guess: (n_y,) its output (default ``robot.platform_pose(q_guess)``).
        max_residual: largest accepted |residual_i| / σ_i (counts) at the solution.
        max_iter: Gauss-Newton iterations.
        compiled: the robot's :class:`CompiledForward`
            (:func:`~parallel_gpc.model.native_update.compiled_forward`): the checks, the same
            Gauss-Newton loop and the residual test in C++; None = this module (the reference).
            What the compiled checks refuse, and a start its warm Newton cannot assemble, is
            redone here, so the errors are this module's.

    Raises:
        ShapeError, InvalidParameterError, NonFiniteError: readings, resolution or q_guess of
            the wrong shape, a resolution not finite and > 0, a q_guess with NaN or inf.
        SensorError: a reading that is NaN or out of range, readings no pose explains within
            ``max_residual`` counts (the message names the worst drive), or a start that does not
            assemble.
    """
    readings, resolution = np.asarray(readings, dtype=float), np.asarray(resolution, dtype=float)
    q_guess = np.asarray(q_guess, dtype=float)
    if compiled is not None:  # shapes, values and the start are checked in C++ (other statuses: here)
        status, sol = compiled.solve(readings, resolution, q_guess, max_iter, max_residual)
        if status == SOLVED:
            return sol
        if status == INCONSISTENT:
            raise SensorError(_inconsistency(robot, readings, sol, resolution, max_residual))
    resolution = check_resolution(robot, resolution)
    readings = check_readings(robot, readings, resolution)
    q_guess = finite_vector("q_guess", q_guess, robot.model.nq)
    sol = _gauss_newton(robot, readings, resolution, q_guess, pose_guess, max_iter)
    counts = np.abs(sol.weighted_residual(resolution))
    if not counts.max() <= max_residual:
        raise SensorError(_inconsistency(robot, readings, sol, resolution, max_residual))
    return sol


def _gauss_newton(robot, readings, resolution, q_guess, pose_guess, max_iter) -> ForwardSolution:
    """The Gauss-Newton loop of :func:`solve_forward` (the reference of native/src/forward.cpp)."""
    if pose_guess is None:
        pose_guess = robot.platform_pose(q_guess)
    drive_q, drive_v = robot.drive_q_indices, robot.drive_idx
    start = _assembled(robot, np.asarray(pose_guess, dtype=float), q_guess)
    if start is None:
        start = _assembled(robot, robot.home_pose, robot.q_home)
        pose = robot.home_pose.copy()
    else:
        pose = np.array(pose_guess, dtype=float)
    q, T = start
    J = T[drive_v]
    e = q[drive_q] - readings
    cost = float(np.sum((e / resolution) ** 2))
    it = 0
    for it in range(1, max_iter + 1):
        Jw, ew = J / resolution[:, None], e / resolution
        step = -np.linalg.lstsq(Jw, ew, rcond=1e-12)[0]
        predicted = J @ step
        if not np.max(np.abs(predicted / resolution)) > STOP_COUNTS:  # converged
            break
        lam = min(1.0, MAX_DRIVE_STEP / max(float(np.max(np.abs(predicted))), 1e-300))
        for _ in range(_HALVINGS):
            trial = pose + lam * step
            out = _assembled(robot, trial, q)
            if out is not None:
                e_new = out[0][drive_q] - readings
                cost_new = float(np.sum((e_new / resolution) ** 2))
                if cost_new <= cost * (1 + 1e-12) + 1e-18:
                    break
            lam *= 0.5
        else:  # no step lowers the cost: a (local) minimum of the residual
            break
        improvement = cost - cost_new
        pose, (q, T), e, cost = trial, out, e_new, cost_new
        J = T[drive_v]
        if improvement <= 1e-14 * max(cost, 1.0) and lam < 1.0:
            break
    return ForwardSolution(pose, q, J, e, it)


def _inconsistency(robot, readings, sol: ForwardSolution, resolution: np.ndarray, max_residual: float) -> str:
    """Message for readings no pose explains, naming the suspect drive(s).

    The suspect is the drive of the largest standardized residual |r_i| / √P_ii (P the projector
    onto the residual space of the weighted Jacobian): for one broken encoder it is the broken
    one. With a single redundant drive every drive's standardized residual is the same, and the
    message names them all.
    """
    Jw = sol.jacobian / resolution[:, None]
    P = np.eye(len(resolution)) - Jw @ np.linalg.pinv(Jw)
    r = sol.weighted_residual(resolution)
    std = np.abs(r) / np.sqrt(np.maximum(np.diag(P), 1e-30))
    names, units = robot.description.drive_joints, robot.drive_position_units
    suspects = [int(i) for i in np.flatnonzero(std >= 0.999 * std.max())]
    worst = max(suspects, key=lambda i: abs(r[i]))
    which = (f"drive {worst} ({names[worst]!r}) is off by {abs(r[worst]):.3g} counts ({sol.residual[worst]:.3g} "
             f"{units[worst]}) at the best pose {rounded(sol.pose, 6)}")
    if len(suspects) > 1:
        which += (f"; drives {[names[i] for i in suspects]} explain the mismatch equally (one redundant drive "
                  "cannot tell which encoder is broken)")
    return (f"drive readings {rounded(readings, 9)} are inconsistent: no pose of {robot.name!r} explains "
            f"them within {max_residual:g} counts; {which} (a broken encoder?)")


def rates_to_velocity(jacobian: np.ndarray, rates: np.ndarray, rate_resolution: np.ndarray) -> np.ndarray:
    """(n_y,) ẏ from (n_u,) drive rates ṙ: weighted least squares through J (ṙ = J ẏ)."""
    return np.linalg.lstsq(jacobian / rate_resolution[:, None], rates / rate_resolution, rcond=1e-12)[0]
