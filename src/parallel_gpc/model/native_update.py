"""The compiled model update of a :class:`~parallel_gpc.model.robot.ParallelRobot`.

``parallel_gpc._native.ModelUpdate`` is the C++ twin of ``ReducedModel._factor_rows`` and
everything under it (warm-started assembly, velocity map, Ψ̇_q, RNEA derivatives, reduction,
factorization (3), the ZOH exponential (4) and the pre-simulation (10)), against Pinocchio's C++
API. It receives the model in Pinocchio's serialization (mass scale and gravity included) and the
index tables the robot computed. Whenever the compiled path meets something unusual (Newton not
converging in a few steps, another branch, a singular K, a non-SPD M_r, NaN/inf) it calls back
into :class:`_ValidatedPath`, the pure-Python code, which raises the package's errors
(:class:`~parallel_gpc.errors.UnreachablePoseError`, :class:`~parallel_gpc.errors.SingularPoseError`,
:class:`~parallel_gpc.errors.NonFiniteError`) exactly as the Python model does.

Its per-stage loop of stage Jacobians runs on ``PARALLEL_GPC_THREADS`` threads (:func:`compiled_threads`;
default min(2, available cores), 1 = one thread): the stages are independent given the trajectory, each
thread has its own Pinocchio data, and the numbers are the same bit for bit as on one thread. Its
fused rollout and Jacobians (``simulate_linearized``) compute the Jacobians of the stages the rollout has
finished on those threads while the rollout goes on.
"""

from __future__ import annotations

import os
from functools import lru_cache

import numpy as np

from ..errors import InvalidParameterError, NonFiniteError, SingularPoseError
from ..validation import rounded
from .discretization import DEGREE_NORMS
from .forward import CompiledForward, assemble_validated
from .linalg import spd_solve
from .native import compiled_part, native_module, native_status

__all__ = ["available_cores", "compiled_forward", "compiled_model_update", "compiled_threads", "forward_status",
           "model_update_status", "thread_count", "use_native"]

#: environment variable: the threads of the compiled model update's per-stage loops (read once per process)
THREADS_ENV = "PARALLEL_GPC_THREADS"
#: the most threads it may ask for (each holds its own copy of the robot's Pinocchio data)
MAX_THREADS = 64


class _ValidatedPath:
    """The Python calls the compiled model update makes in unusual cases (see the module doc)."""

    def __init__(self, robot):
        self.robot = robot

    def assemble(self, y: np.ndarray, q_last: np.ndarray) -> np.ndarray:
        """ReducedModel._kinematics' fallback: Newton from the last q, continuation from home."""
        q = self.robot.assemble(y, q_last)
        self.robot.velocity_map_nocopy(q)  # SingularPoseError where K loses rank
        return q

    def singular(self, q: np.ndarray) -> None:
        """The compiled rank check failed where Python's passed (a borderline K): raise."""
        cond = self.robot.singularity(q)["cond_phi_z"]
        raise SingularPoseError(f"legs singular at platform pose {rounded(self.robot.platform_pose(q), 6)}: "
                                f"cond(Φ_z) = {cond:.3g} (compiled model update)")

    def assembled(self, pose, q_guess):
        """Forward kinematics' trial pose (lists of floats) on the validated path: q, or None where
        it does not assemble (forward._assembled)."""
        out = assemble_validated(self.robot, np.asarray(pose, dtype=float), np.asarray(q_guess, dtype=float))
        return None if out is None else out[0]

    @staticmethod
    def nonfinite() -> None:
        raise NonFiniteError("matrix exponential of a matrix with NaN or inf entries")

    @staticmethod
    def spd_solve(A: np.ndarray, B: np.ndarray) -> np.ndarray:
        return spd_solve(A, B)


def available_cores() -> int:
    """The CPU cores this process may run on (its affinity mask where the platform has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def thread_count(value: str | None) -> int:
    """The thread count that ``PARALLEL_GPC_THREADS = value`` asks for: min(2, available cores) when
    unset or blank, else the whole number itself (1 = one thread).

    Raises:
        InvalidParameterError: value is not a whole number in 1..MAX_THREADS.
    """
    if value is None or not value.strip():
        return min(2, available_cores())
    text = value.strip()
    if not (text.isascii() and text.isdigit()) or not 1 <= int(text) <= MAX_THREADS:
        raise InvalidParameterError(f"{THREADS_ENV} = {value!r}; valid: a whole number 1..{MAX_THREADS} "
                                    f"(1: one thread; unset: min(2, available cores) = {min(2, available_cores())})")
    return int(text)


@lru_cache(maxsize=1)
def compiled_threads() -> int:
    """The threads of the compiled per-stage loops (:meth:`~parallel_gpc.model.ReducedModel.stage_jacobians`):
    :func:`thread_count` of ``PARALLEL_GPC_THREADS``, read once per process (at the first compiled model update).

    Raises:
        InvalidParameterError: the variable is set to anything but a whole number in 1..MAX_THREADS.
    """
    return thread_count(os.environ.get(THREADS_ENV))


def _output_q_indices(robot) -> list[int]:
    """Indices in q of the output joints (none for task-space outputs): the robot's own table."""
    if robot.task_output is not None:
        return []
    return robot.output_q_indices


def model_update_status(native) -> str:
    """Why the compiled model update is or is not available (``native`` as in ReducedModel)."""
    if native is False:
        return "pure-Python model update (native=False)"
    module = native_module()
    if module is None:
        return f"pure-Python model update: {native_status()}"
    if not hasattr(module, "ModelUpdate"):
        return "pure-Python model update: the compiled core has no model update"
    return "compiled model update"


def use_native(native=None) -> bool:
    """Whether a ReducedModel built with ``native`` uses the compiled model update.

    Args:
        native: None = when the compiled core is available, False = never, True = required.

    Raises:
        InvalidParameterError: ``native`` is not None/True/False, or True while the compiled
            core is not available (the message says why).
    """
    return compiled_part(native, "ModelUpdate", "the compiled model update") is not None


def compiled_model_update(robot):
    """The ``_native.ModelUpdate`` of ``robot`` (the compiled core must be available, see
    :func:`use_native`): the model in Pinocchio's serialization, the robot's index tables and the
    threads of its per-stage loops (:func:`compiled_threads`).

    Raises:
        InvalidParameterError: ``PARALLEL_GPC_THREADS`` is not a valid thread count.
    """
    task = robot.task_output
    threads = compiled_threads()  # validated even where the compiled core predates the threads (one thread)
    threaded = {"threads": threads} if hasattr(native_module(), "adapt_threads") else {}
    return compiled_part(True, "ModelUpdate", "the compiled model update")(
        model=robot.model.saveToString(),
        closure_frames=[(int(fa), int(fb)) for fa, fb, _ in robot.closure_frames],
        jac_rows=robot.closure_jacobian_rows, n_y=robot.n_y, n_u=robot.n_u,
        y_q=_output_q_indices(robot), y_idx=robot.y_idx.tolist(), z_idx=robot.z_idx.tolist(),
        drive_idx=robot.drive_idx.tolist(),
        task_frame=-1 if task is None else task.frame_id,
        task_rows=[] if task is None else task.rows.tolist(),
        R_ref=np.eye(3) if task is None else np.array(task.R_ref, dtype=float),
        branch_q=robot.branch_q_indices, branch=robot.home_branch,
        q_home=robot.q_home, bias_symmetric=bool(robot.bias_symmetric),
        universal=[(int(j), int(i)) for j, i in robot.universal_joints.columns],
        degree_norms=list(DEGREE_NORMS), handler=_ValidatedPath(robot), **threaded,
    )


def compiled_forward(robot):
    """The compiled path of :func:`~parallel_gpc.model.forward.solve_forward` on ``robot`` (a
    :class:`~parallel_gpc.model.forward.CompiledForward`; the compiled core must be available,
    see :func:`use_native`): its own ``_native.ModelUpdate`` with the drives' q indices and ranges
    set, so forward kinematics never disturbs the warm starts of a model or plant. None when the
    compiled core predates this forward kinematics (a build older than its sources, without
    ``solve_forward_into``: the Python loop runs)."""
    if not hasattr(native_module().ModelUpdate, "solve_forward_into"):
        return None
    update = compiled_model_update(robot)
    lower, upper = robot.drive_range
    update.set_drives([int(i) for i in robot.drive_q_indices], lower, upper)
    return CompiledForward(update, robot.n_y, robot.model.nq, robot.n_u)


def forward_status() -> str:
    """Which loop :meth:`~parallel_gpc.model.robot.ParallelRobot.forward_solution` runs, and if
    not the compiled one, why."""
    module = native_module()
    if module is None:
        return f"Python loop ({native_status()})"
    if not hasattr(getattr(module, "ModelUpdate", None), "solve_forward_into"):
        return "Python loop (the compiled core predates this forward kinematics: rebuild it)"
    return "compiled"
