"""The package's exception hierarchy.

Every error raised on purpose by parallel-gpc derives from :class:`ParallelGPCError`, so a
caller can catch one type. Messages name the offending value (or its shape) and what would be
valid. Errors that also describe an invalid argument derive from :class:`ValueError` too.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path


class ParallelGPCError(Exception):
    """Base class of all parallel-gpc errors."""


class RobotFormatError(ParallelGPCError, ValueError):
    """A URDF or closure sidecar is malformed or names an unknown frame or joint."""


class UnderactuatedError(RobotFormatError):
    """Some motion of the mechanism is not determined by the output or not actuated by the drives
    (fewer closure rows than dependent coordinates, or rank of B_r = Tᵀ Sᵀ < n_y)."""


class ParallelGPCWarning(UserWarning):
    """A notice about something parallel-gpc did on its own that changes the model (e.g. idle
    motions locked at load)."""


class AssemblyError(ParallelGPCError):
    """The loop closures could not be assembled (Newton did not converge)."""


class UnreachablePoseError(AssemblyError, ValueError):
    """A platform pose is outside the workspace (the closures cannot be assembled there)."""


class SingularPoseError(ParallelGPCError):
    """A configuration is (near) singular: the reduced model is not defined there."""


class InvalidParameterError(ParallelGPCError, ValueError):
    """A horizon, weight, sample time, limit or other parameter is out of its valid range."""


class ShapeError(InvalidParameterError):
    """An array has the wrong shape."""


class NonFiniteError(InvalidParameterError):
    """A state, measurement or input contains NaN or infinity."""


class FastStateError(SingularPoseError, InvalidParameterError):
    """The pose is fine at rest, but the measured velocity makes the one-sample model near-singular:
    a measurement or unit error when it is the first state a controller sees; in a closed loop, a
    plant moving too fast through a near-singular region for its sample time (the run diverged:
    a :class:`SingularPoseError`, so the loops keep the samples before it)."""


class SensorError(InvalidParameterError):
    """A drive reading (or a plant's measurement) is NaN, out of the drive's range, inconsistent
    with every pose, or of the wrong kind; the message names the drive."""


class SolverNotFoundError(ParallelGPCError, ValueError):
    """The requested QP solver is not installed or not known."""


class SolverError(ParallelGPCError):
    """A least-squares or QP solve failed."""


class InfeasibleLimitsError(InvalidParameterError):
    """Torque or increment limits admit no input at all (e.g. lower > upper)."""


class ViewerError(ParallelGPCError):
    """The meshcat viewer or gallery server could not start or stop, or an export is not offline."""


class ResultFormatError(InvalidParameterError):
    """A result file is unreadable, of an unknown format or version, or lacks a needed key."""


class OutputError(ParallelGPCError, OSError):
    """A file could not be written (disk full, no permission, …); the message names the path and
    the reason. ``errno`` is the operating system's error number."""


@contextlib.contextmanager
def writing(path, what: str):
    """Context manager around writing one file: an :class:`OSError` inside (also from creating its
    folder) becomes an :class:`OutputError` naming ``what``, the path and the reason, and the
    partly written file is removed (a file that was there before and was not touched is kept).

    Args:
        path: the file being written. what: what it is (``"result file"``, ``"figure"``, …).
    """
    path = Path(path)
    before = _stat(path)
    try:
        yield path
    except OutputError:
        raise
    except OSError as exc:
        after = _stat(path)
        if after is not None and after != before:
            with contextlib.suppress(OSError):
                path.unlink()
        reason = exc.strerror or str(exc)
        where = f" ({exc.filename})" if exc.filename and str(exc.filename) != str(path) else ""
        error = OutputError(f"cannot write {what} {str(path)!r}: {reason}{where}")
        error.errno = exc.errno
        raise error from exc


def _stat(path: Path) -> tuple[int, int] | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_mtime_ns, st.st_size
