"""Reduced ODE of the closed-chain robot, state space, factorization, ZOH (DESIGN §2, eq. (1)–(4)).

Full model (Pinocchio): ``M q̈ + h = Sᵀ u + Φ_qᵀ λ`` with closures Φ(q) = 0. With the platform
coordinates y independent and the leg coordinates z dependent,

* ``q̇ = T ẏ``, ``T = [I; −Φ_z⁺ Φ_y]`` and ``q̈ = T ÿ + ℓ`` with ``ℓ_z = −Φ_z⁺ γ``;
* ``M_r = Tᵀ M T``, ``h_r = Tᵀ (h + M ℓ)``, ``B_r = Tᵀ Sᵀ``;
* eq. (1): ``ÿ = f + g u``, ``f = −M_r⁻¹ h_r``, ``g = M_r⁻¹ B_r``.

Φ_z⁺ comes from :meth:`ParallelRobot.velocity_map` (rank-revealing SVD: planar point closures
have zero z rows, so no plain inverse of a rank-deficient block is taken).

State X = [y, ẏ] (m, rad, m/s, rad/s); output y = C X with C = [I 0].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.linalg import expm

from .robot import ParallelRobot
from .validation import finite_vector, positive

@dataclass
class ReducedTerms:
    """Reduced-model terms at one state (all SI).

    Attributes:
        q, v: (nv,) full configuration and velocity.
        T: (nv, n_y) velocity map q̇ = T ẏ.
        ell: (nv,) acceleration offset ℓ (q̈ = T ÿ + ℓ).
        M: (nv, nv) full mass matrix.
        M_r: (n_y, n_y) reduced mass matrix (kg, kg·m²).
        h_r: (n_y,) reduced nonlinear forces (N, N·m).
        B_r: (n_y, n_u) reduced input matrix.
        pinv_z: (n_z, m) rank-revealing pseudo-inverse of Φ_z.
    """

    q: np.ndarray
    v: np.ndarray
    T: np.ndarray
    ell: np.ndarray
    M: np.ndarray
    M_r: np.ndarray
    h_r: np.ndarray
    B_r: np.ndarray
    pinv_z: np.ndarray

    @property
    def f(self) -> np.ndarray:
        """(n_y,) drift acceleration f(y, ẏ) of eq. (1)."""
        return -np.linalg.solve(self.M_r, self.h_r)

    @property
    def g(self) -> np.ndarray:
        """(n_y, n_u) input gain g(y) of eq. (1)."""
        return np.linalg.solve(self.M_r, self.B_r)

    def acceleration(self, u: np.ndarray) -> np.ndarray:
        """(n_y,) ÿ for drive torques u (N·m)."""
        return np.linalg.solve(self.M_r, self.B_r @ u - self.h_r)


class ReducedModel:
    """Reduced ODE ``ÿ = f(y, ẏ) + g(y) u`` of a :class:`ParallelRobot`.

    Holds a warm start for assembly (the last full configuration): evaluating at a platform pose
    near the previous one costs one or two Newton steps. Results do not depend on it.

    Args:
        robot: the robot (its model may carry a mass scale or another gravity).
    """

    def __init__(self, robot: ParallelRobot):
        self.robot = robot
        self.n_y = robot.n_y
        self.n_u = robot.n_u
        self.n_x = 2 * robot.n_y
        self.C = np.hstack([np.eye(self.n_y), np.zeros((self.n_y, self.n_y))])
        self._q_last = robot.q_home.copy()
        self._S = robot.drive_selection

    # -------------------------------------------------------------- reduced terms
    def terms_at_q(self, q: np.ndarray, ydot: np.ndarray) -> ReducedTerms:
        """Reduced terms at an assembled configuration q and platform velocity ẏ."""
        r = self.robot
        model, data = r.model, r.data
        T, pinv_z = r.velocity_map(q)
        v = T @ np.asarray(ydot, dtype=float)
        gamma = r.closure_acceleration_bias(q, v)
        ell = np.zeros(model.nv)
        ell[r.z_idx] = -pinv_z @ gamma
        M = pin.crba(model, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        h = pin.nonLinearEffects(model, data, q, v)
        return ReducedTerms(
            q=q, v=v, T=T, ell=ell, M=M,
            M_r=T.T @ M @ T, h_r=T.T @ (h + M @ ell), B_r=T.T @ self._S, pinv_z=pinv_z,
        )

    def assemble(self, y: np.ndarray) -> np.ndarray:
        """Full configuration at platform pose y, warm-started from the last one."""
        q = self.robot.assemble(y, self._q_last)
        self._q_last = q
        return q

    def terms(self, X: np.ndarray) -> ReducedTerms:
        """Reduced terms at state X = [y, ẏ]."""
        X = np.asarray(X, dtype=float)
        return self.terms_at_q(self.assemble(X[: self.n_y]), X[self.n_y:])

    # -------------------------------------------------------------- eq. (1), (2)
    def acceleration(self, X: np.ndarray, u: np.ndarray) -> np.ndarray:
        """(n_y,) ÿ = f + g u at state X for drive torques u (N·m), eq. (1)."""
        return self.terms(X).acceleration(np.asarray(u, dtype=float))

    def state_derivative(self, X: np.ndarray, u: np.ndarray) -> np.ndarray:
        """(n_x,) Ẋ = F(X) + G(X) u, eq. (2)."""
        X = np.asarray(X, dtype=float)
        return np.concatenate([X[self.n_y:], self.acceleration(X, u)])

    # -------------------------------------------------------------- eq. (3)
    def factorize(self, X: np.ndarray):
        """State-dependent factorization ``Ẋ = A(X) X + B(X) u + c(X)``, eq. (3).

        h_r is quadratic in ẏ plus a gravity part: h_r = C_r(y, ẏ) ẏ + g_r(y) with
        C_r = ½ ∂h_r/∂ẏ (exact for a quadratic form). The gravity part is the affine term c.

        Returns:
            A: (n_x, n_x) [[0, I], [0, −M_r⁻¹ C_r]].
            B: (n_x, n_u) [[0], [M_r⁻¹ B_r]].
            c: (n_x,) [0; −M_r⁻¹ g_r] (zero for a horizontal robot).
        """
        X = np.asarray(X, dtype=float)
        ny = self.n_y
        q = self.assemble(X[:ny])
        ydot = X[ny:]
        base = self.terms_at_q(q, ydot)
        h_of = self._h_r_function(q, base)
        g_r = h_of(np.zeros(ny))
        # Polarization of the quadratic part Q(v, v) = h_r(v) - g_r:  ½ ∂h_r/∂ẏ · e_i = Q(ẏ, e_i).
        quad = lambda w: h_of(w) - g_r  # noqa: E731
        C_r = np.empty((ny, ny))
        q_y = quad(ydot)
        for i in range(ny):
            e = np.zeros(ny)
            e[i] = 1.0
            C_r[:, i] = 0.5 * (quad(ydot + e) - q_y - quad(e))
        Minv = np.linalg.inv(base.M_r)
        A = np.zeros((2 * ny, 2 * ny))
        A[:ny, ny:] = np.eye(ny)
        A[ny:, ny:] = -Minv @ C_r
        B = np.vstack([np.zeros((ny, self.n_u)), Minv @ base.B_r])
        c = np.concatenate([np.zeros(ny), -Minv @ g_r])
        return A, B, c

    def _h_r_function(self, q: np.ndarray, base: ReducedTerms):
        """ẏ ↦ h_r(q, ẏ) at fixed q (reuses T, M of ``base``)."""
        r = self.robot
        T, M, pinv_z = base.T, base.M, base.pinv_z

        def h_r(ydot: np.ndarray) -> np.ndarray:
            v = T @ ydot
            gamma = r.closure_acceleration_bias(q, v)
            ell = np.zeros(r.model.nv)
            ell[r.z_idx] = -pinv_z @ gamma
            h = pin.nonLinearEffects(r.model, r.data, q, v)
            return T.T @ (h + M @ ell)

        return h_r

    # -------------------------------------------------------------- Jacobian linearization
    def linearize(self, X: np.ndarray, u: np.ndarray, eps: float = 1e-6):
        """Jacobian linearization about (X̄, ū): ``Ẋ ≈ A X + B u + c`` (central differences).

        Returns:
            A: (n_x, n_x) ∂F/∂X, B: (n_x, n_u) ∂F/∂u = [0; g], c: (n_x,) F(X̄, ū) − A X̄ − B ū.
        """
        X = np.asarray(X, dtype=float)
        u = np.asarray(u, dtype=float)
        n_x = self.n_x
        A = np.empty((n_x, n_x))
        for i in range(n_x):
            d = np.zeros(n_x)
            d[i] = eps
            A[:, i] = (self.state_derivative(X + d, u) - self.state_derivative(X - d, u)) / (2 * eps)
        terms = self.terms(X)
        B = np.vstack([np.zeros((self.n_y, self.n_u)), terms.g])
        F = np.concatenate([X[self.n_y:], terms.acceleration(u)])
        return A, B, F - A @ X - B @ u


def discretize_zoh(A: np.ndarray, B: np.ndarray, c: np.ndarray | None, Ts: float):
    """Zero-order-hold discretization of ``Ẋ = A X + B u + c``, eq. (4).

    Uses the matrix exponential of the augmented matrix [[A, B, c], [0, 0, 0]] · Ts.

    Args:
        A: (n, n), B: (n, m), c: (n,) or None; Ts: sample time in s (> 0).

    Returns:
        (A_d, B_d, c_d): X(k+1) = A_d X(k) + B_d u(k) + c_d.
    """
    Ts = positive("Ts", Ts, " s")
    n, m = B.shape
    aug = np.zeros((n + m + 1, n + m + 1))
    aug[:n, :n] = A
    aug[:n, n:n + m] = B
    if c is not None:
        aug[:n, n + m] = c
    E = expm(aug * Ts)
    return E[:n, :n], E[:n, n:n + m], E[:n, n + m]


def rk4_step(deriv, X: np.ndarray, u: np.ndarray, Ts: float, substeps: int = 1) -> np.ndarray:
    """Integrate Ẋ = deriv(X, u) over Ts with u held, by ``substeps`` classical RK4 steps."""
    h = Ts / substeps
    X = np.asarray(X, dtype=float)
    for _ in range(substeps):
        k1 = deriv(X, u)
        k2 = deriv(X + 0.5 * h * k1, u)
        k3 = deriv(X + 0.5 * h * k2, u)
        k4 = deriv(X + h * k3, u)
        X = X + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
    return X


def kinetic_energy(model: ReducedModel, X: np.ndarray) -> float:
    """Kinetic energy ½ ẏᵀ M_r ẏ in J at state X."""
    X = finite_vector("X", X, model.n_x)
    terms = model.terms(X)
    yd = X[model.n_y:]
    return 0.5 * float(yd @ terms.M_r @ yd)
