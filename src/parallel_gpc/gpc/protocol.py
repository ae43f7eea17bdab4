"""The small model protocol a :class:`~parallel_gpc.gpc.GPCController` uses.

Two implementations ship: :class:`~parallel_gpc.model.ReducedModel` (a parallel robot's
reduced dynamics, state X = [y, ẏ], output y = C X with C = [I 0]) and
:class:`~parallel_gpc.gpc.DiscreteLinearModel` (any discrete state-space model). Any object
with these members works.
"""

from __future__ import annotations

import math
from typing import Protocol, runtime_checkable

import numpy as np
from scipy.linalg import lapack

from ..errors import FastStateError, SingularPoseError
from ..model import compiled_part


@runtime_checkable
class ControlModel(Protocol):
    """A discrete, possibly state-dependent, affine model ``X(k+1) = A_d X + B_d u + c_d``, ``y = C X``.

    Attributes:
        n_x: state size; n_y: output size; n_u: input size.
        C: (n_y, n_x) output matrix.

    Optional members the controller uses when present:

    * ``Ts`` (s): the model's own sample time; it must equal the controller's.
    * ``input_gain(B_d) -> array | None``: the matrix whose condition number the controller
      bounds by ``max_condition`` at every step (None: no check). Without it, a model whose
      state is X = [y, ẏ] with C = [I 0] (the mechanical convention) has the velocity rows
      ``B_d[n_y:]`` ≈ Ts·g checked; any other model is not checked.
    * ``simulate_linearized(X0, u_seq, Ts, offset, start=1) -> (A_seq, B_seq, c_seq, X_seq, JX)``: the
      nonlinear MPC iterations' rollout (:meth:`simulate_factorized`) and the stage Jacobians ∂Φ/∂X of its
      states start..K−1 (``JX`` (K − start, n_x, n_x), ``stage_jacobians``) in one call. Without it the
      iterations call ``simulate_factorized`` then ``stage_jacobians(X_seq, u_seq, Ts, start=1)``.
    """

    n_x: int
    n_y: int
    n_u: int
    C: np.ndarray

    def discrete(self, X: np.ndarray, Ts: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(A_d (n_x, n_x), B_d (n_x, n_u), c_d (n_x,)) of the model at state X for sample time Ts (s)."""
        ...

    def simulate_factorized(self, X0: np.ndarray, u_seq: np.ndarray, Ts: float, offset=None):
        """Pre-simulate X(i+1) = A_d(X(i)) X(i) + B_d(X(i)) u(i) + c_d(X(i)) + offset, eq. (10).

        Returns:
            (A_seq (K, n_x, n_x), B_seq (K, n_x, n_u), c_seq (K, n_x) without the offset,
            X_seq (K + 1, n_x) with X_seq[0] = X0).
        """
        ...


def condition_number(gain: np.ndarray, native: bool | None = None) -> float:
    """Condition number σ_max/σ_min of an input gain (inf when singular or not finite).

    Checked on every control step: compiled (``_native.condition_number``, Eigen's Jacobi SVD
    read in place, a third of the LAPACK call's time at these sizes) when the core is available. The reference takes the singular values from LAPACK
    ``gesdd`` without vectors, called directly (half the time of ``numpy.linalg.svd`` on the 3×4 …
    6×8 gains of the robots). A gain with NaN or inf entries gives a failed call or a non-finite
    σ_max (σ_max ≥ every |entry|): inf.

    Args:
        gain: (p, m) float array. native: None = compiled when available, False = the LAPACK
            reference, True = compiled or :class:`~parallel_gpc.errors.InvalidParameterError`.
    """
    compiled = compiled_part(native, "condition_number", "the compiled condition number")
    if compiled is not None:
        return compiled(gain)
    if gain.size == 0:
        return math.inf
    s, info = lapack.dgesdd(gain, compute_uv=0)[1::2]
    cond = float(s[0] / s[-1]) if info == 0 and s[-1] > 0 else math.inf
    return cond if math.isfinite(cond) else math.inf


def condition_function(native: bool | None = None):
    """:func:`condition_number` with its compiled-or-reference choice made once (``native`` as there):
    a controller takes it when built, so its per-step check does not read ``PARALLEL_GPC_NATIVE``
    again (a third of the check's time), like its other compiled parts.

    Returns:
        A function (p, m) gain ↦ σ_max/σ_min (inf when singular or not finite).
    """
    compiled = compiled_part(native, "condition_number", "the compiled condition number")
    if compiled is not None:
        return compiled
    return lambda gain: condition_number(gain, native=False)


def conditioning_rule(model):
    """The map B_d ↦ input gain whose condition number the controller bounds at every step
    (see :class:`ControlModel`), decided once per controller; None: no check."""
    custom = getattr(model, "input_gain", None)
    if custom is not None:
        return custom
    n_y, n_x = model.n_y, model.n_x
    C = np.asarray(model.C)
    if n_x == 2 * n_y and C.shape == (n_y, n_x) and np.array_equal(C, np.eye(n_y, n_x)):
        return _velocity_rows(n_y)
    return None


def _velocity_rows(n_y: int):
    def gain(Bd: np.ndarray) -> np.ndarray:
        return Bd[n_y:]

    return gain


def check_conditioning(model, rule, X: np.ndarray, cond: float, max_condition: float, Ts: float) -> None:
    """Raise :class:`~parallel_gpc.errors.SingularPoseError` when the input gain at X is near-singular.

    For a robot, ``gain = B_d[n_y:]`` ≈ Ts·g with g = M_r⁻¹ B_r of eq. (1); its condition
    number grows without bound at an actuation (direct) singularity and as a leg stretches
    or folds. Other models: :func:`conditioning_rule` (``rule`` is its result for ``model``).

    Args:
        model: the controller's model; rule: the gain rule of :func:`conditioning_rule`.
        X: (n_x,) measured state; cond: the condition number of the checked gain at X (the
            controller's :func:`condition_function` of it; NaN fails like inf).
        max_condition: largest accepted condition number. Ts: sample time (s).

    Raises:
        FastStateError: the pose is fine at rest, the measured velocity is what makes the one-sample
            model near-singular (a measurement or unit error, or a closed loop that diverged; both an
            InvalidParameterError and a SingularPoseError).
        SingularPoseError: the pose itself is near-singular.
    """
    if cond <= max_condition:
        return
    n_y, n_x = model.n_y, model.n_x
    if n_x == 2 * n_y and np.any(X[n_y:]):  # [y, ẏ]: is it the pose or the velocity?
        rest = np.concatenate([X[:n_y], np.zeros(n_y)])
        at_rest = condition_number(rule(model.discrete(rest, Ts)[1]))
        if at_rest <= max_condition:
            raise FastStateError(
                f"measured velocity {np.asarray(X[n_y:]).tolist()} is too large for the one-sample model at "
                f"pose {np.round(X[:n_y], 6).tolist()}: cond(g) = {cond:.3g} at this velocity, {at_rest:.3g} "
                f"at rest (max_condition = {max_condition:.3g}); check the measurement and its units (in a closed "
                f"loop: the plant moves too fast here for Ts = {Ts:g} s)")
    raise SingularPoseError(
        f"near-singular pose {np.round(X[:n_y], 6).tolist()}: cond(g) = cond(M_r⁻¹ B_r) = {cond:.3g} "
        f"> max_condition = {max_condition:.3g}; the drives cannot move the platform in some "
        f"direction, so the controller stops instead of commanding unbounded torques"
    )
