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


def condition_number(gain: np.ndarray) -> float:
    """Condition number σ_max/σ_min of an input gain (inf when singular or not finite).

    The singular values come from LAPACK ``gesdd`` without vectors, called directly (half the
    time of ``numpy.linalg.svd`` on the 3×4 … 6×8 gains of the robots). A gain with NaN or inf
    entries gives a failed call or a non-finite σ_max (σ_max ≥ every |entry|): inf.
    """
    if gain.size == 0:
        return math.inf
    s, info = lapack.dgesdd(gain, compute_uv=0)[1::2]
    cond = float(s[0] / s[-1]) if info == 0 and s[-1] > 0 else math.inf
    return cond if math.isfinite(cond) else math.inf


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
