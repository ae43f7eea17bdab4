"""A plain discrete state-space model for the GPC controller (LTI, or state-dependent/LTV).

    X(k+1) = A X(k) + B u(k) + c,    y(k) = C X(k)

Give the matrices (time-invariant), or a function X ↦ (A, B, c) for a model that depends on
the state (the nonlinear form pre-simulates with it, eq. (10)). Units are the user's; the
sample time Ts (s) is the one the matrices were discretized at and must equal the controller's.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from ..errors import InvalidParameterError, NonFiniteError, ShapeError
from ..validation import finite_matrix, finite_vector, positive, read_only


class DiscreteLinearModel:
    """Discrete affine state-space model implementing :class:`~parallel_gpc.gpc.ControlModel`.

    Args:
        A: (n_x, n_x) state matrix.
        B: (n_x, n_u) input matrix.
        C: (n_y, n_x) output matrix (any outputs: C = I gives full-state output).
        c: (n_x,) affine term, default zero.
        Ts: sample time (s) the model is discrete at.

    A plain linear model has no state-dependent input gain to guard: the controller's
    ``max_condition`` check does not apply to it (:meth:`input_gain` returns None).

    Raises:
        ShapeError: inconsistent shapes. NonFiniteError: NaN or inf entries.
        InvalidParameterError: Ts not finite and > 0.
    """

    def __init__(self, A, B, C, c=None, *, Ts: float):
        self.Ts = positive("Ts", Ts, " s")
        self.C = read_only(finite_matrix("C", C, (None, None)))
        self.n_y, self.n_x = self.C.shape
        self._fn: Callable | None = None
        if A is None:  # set by from_function
            return
        A = finite_matrix("A", A, (self.n_x, self.n_x))
        B = finite_matrix("B", B, (self.n_x, None))
        self.n_u = B.shape[1]
        c = np.zeros(self.n_x) if c is None else finite_vector("c", c, self.n_x)
        self._lti = (read_only(A), read_only(B), read_only(c))

    @classmethod
    def from_function(cls, fn: Callable, C, n_u: int, *, Ts: float) -> "DiscreteLinearModel":
        """A state-dependent (LTV along the trajectory) model: ``fn(X) -> (A, B, c)`` at state X.

        Args:
            fn: X (n_x,) ↦ (A (n_x, n_x), B (n_x, n_u), c (n_x,) or None), discrete at Ts.
            C: (n_y, n_x) output matrix.
            n_u: input size.
            Ts: sample time (s).
        """
        if not callable(fn):
            raise InvalidParameterError(f"fn = {fn!r} must be callable X -> (A, B, c)")
        if isinstance(n_u, bool) or not isinstance(n_u, (int, np.integer)) or n_u < 1:
            raise InvalidParameterError(f"n_u = {n_u!r} must be an integer ≥ 1")
        model = cls(None, None, C, Ts=Ts)
        model.n_u = int(n_u)
        model._fn = fn
        return model

    def input_gain(self, Bd: np.ndarray) -> None:
        """No conditioning check for a plain linear model (see the class docstring)."""
        return None

    def _check_Ts(self, Ts: float) -> None:
        if not math.isclose(float(Ts), self.Ts, rel_tol=1e-12, abs_tol=0.0):
            raise InvalidParameterError(
                f"sample time Ts = {Ts!r} s differs from the model's Ts = {self.Ts!r} s; a discrete model "
                f"only holds at its own sample time (rediscretize it, or run the controller at Ts = {self.Ts!r} s)"
            )

    def _at(self, X: np.ndarray):
        if self._fn is None:
            return self._lti
        out = self._fn(X)
        if not isinstance(out, tuple) or len(out) != 3:
            raise ShapeError(f"the model function must return (A, B, c); it returned {type(out).__name__}")
        A, B, c = (np.asarray(a, dtype=float) if a is not None else None for a in out)
        if A.shape != (self.n_x, self.n_x) or B.shape != (self.n_x, self.n_u) or (c is not None and c.shape != (self.n_x,)):
            raise ShapeError(
                f"the model function returned A {A.shape}, B {B.shape}, c {None if c is None else c.shape}; "
                f"expected ({self.n_x}, {self.n_x}), ({self.n_x}, {self.n_u}), ({self.n_x},) or None")
        c = np.zeros(self.n_x) if c is None else c
        if not (np.all(np.isfinite(A)) and np.all(np.isfinite(B)) and np.all(np.isfinite(c))):
            raise NonFiniteError(f"the model function returned NaN or inf at X = {np.asarray(X).tolist()}")
        return A, B, c

    def discrete(self, X: np.ndarray, Ts: float):
        """(A (n_x, n_x), B (n_x, n_u), c (n_x,)) at state X; Ts (s) must equal the model's."""
        self._check_Ts(Ts)
        return self._at(X)

    def simulate_factorized(self, X0: np.ndarray, u_seq: np.ndarray, Ts: float, offset=None):
        """Pre-simulate X(i+1) = A(X(i)) X(i) + B(X(i)) u(i) + c(X(i)) + offset.

        Args:
            X0: (n_x,) initial state; u_seq: (K, n_u) inputs; Ts: sample time (s);
            offset: (n_x,) constant added every step, or None.

        Returns:
            (A_seq (K, n_x, n_x), B_seq (K, n_x, n_u), c_seq (K, n_x) without the offset,
            X_seq (K + 1, n_x) with X_seq[0] = X0).
        """
        self._check_Ts(Ts)
        u_seq = np.asarray(u_seq, dtype=float)
        K, n = len(u_seq), self.n_x
        A_seq, B_seq = np.empty((K, n, n)), np.empty((K, n, self.n_u))
        c_seq, X_seq = np.empty((K, n)), np.empty((K + 1, n))
        X_seq[0] = X0
        d = np.zeros(n) if offset is None else np.asarray(offset, dtype=float)
        for i in range(K):
            A_seq[i], B_seq[i], c_seq[i] = self._at(X_seq[i])
            X_seq[i + 1] = A_seq[i] @ X_seq[i] + B_seq[i] @ u_seq[i] + c_seq[i] + d
        return A_seq, B_seq, c_seq, X_seq
