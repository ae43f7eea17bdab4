"""The package's exception hierarchy.

Every error raised on purpose by parallel-gpc derives from :class:`ParallelGPCError`, so a
caller can catch one type. Messages name the offending value (or its shape) and what would be
valid. Errors that also describe an invalid argument derive from :class:`ValueError` too.
"""

from __future__ import annotations


class ParallelGPCError(Exception):
    """Base class of all parallel-gpc errors."""


class RobotFormatError(ParallelGPCError, ValueError):
    """A URDF or closure sidecar is malformed or names an unknown frame or joint."""


class UnderactuatedError(RobotFormatError):
    """The drives span fewer directions than the robot has DOF (rank of B_r = Tᵀ Sᵀ < n_y)."""


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
