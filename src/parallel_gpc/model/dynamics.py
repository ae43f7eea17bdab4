"""Reduced ODE of the closed-chain robot, state space, factorization, ZOH (eq. (1)–(4)).

Full model (Pinocchio): ``M q̈ + h = Sᵀ u + Φ_qᵀ λ`` with closures Φ(q) = 0. With the platform
coordinates y independent and the leg coordinates z dependent,

* ``q̇ = T ẏ``, ``T = [I; −Φ_z⁺ Φ_y]`` and ``q̈ = T ÿ + ℓ`` with ``ℓ_z = −Φ_z⁺ γ``;
* ``M_r = Tᵀ M T``, ``h_r = Tᵀ (h + M ℓ)``, ``B_r = Tᵀ Sᵀ``;
* eq. (1): ``ÿ = f + g u``, ``f = −M_r⁻¹ h_r``, ``g = M_r⁻¹ B_r``.

Φ_z⁺ comes from :meth:`ParallelRobot.velocity_map` (rank-revealing SVD: planar point closures
have zero z rows, so no plain inverse of a rank-deficient block is taken). For a task-space
output y = h(q) the same formulas hold with z = all of v and Φ replaced by the assembly rows
Ψ = [Φ; h − y]: ``T = K⁺ [0; I]``, ``ℓ = −K⁺ Ψ̇_q v`` with K = [Φ_q; H]
(:meth:`ParallelRobot.constraint_jacobian_derivative`). With multi-DOF joints (nq ≠ nv) q moves
by ``pin.integrate``; T, ℓ, M live in v.

State X = [y, ẏ] (m, rad, m/s, rad/s); output y = C X with C = [I 0].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from .discretization import discretize_zoh, expm, expm_derivative_action, rk4_step, zoh_split
from .linalg import spd_solve
from .native import native_module
from .native_update import compiled_model_update, model_update_status, use_native
from .robot import ParallelRobot
from ..errors import InvalidParameterError
from ..validation import finite_vector, positive

# discretize_zoh, expm and rk4_step live in .discretization; re-exported (tests and users import them from here).
__all__ = ["ReducedTerms", "ReducedModel", "kinetic_energy", "discretize_zoh", "expm", "rk4_step", "JACOBIAN_STEP",
           "TANGENT_STEP"]

#: relative step of the central differences in :meth:`ReducedModel.stage_jacobians_differences` (of the
#: whole stage map, the oracle): truncation O(h²) ≈ 1e-10, rounding ≈ 1e-11 relative.
JACOBIAN_STEP = 1e-5
#: relative step of the forward differences of the factor rows along the closures' tangent in
#: :meth:`ReducedModel.stage_jacobians`, about √ε: truncation O(h) and rounding ε/h both ≈ 1e-8
#: relative in ∂Z/∂y, which enters ∂Φ/∂X scaled by Ts (measured: within 3e-9 of the central
#: differences of Φ, relative to ‖∂Φ/∂X‖, on planar_4rrr, delta_3rus and hexapod_6ups).
TANGENT_STEP = 2e-8


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


def _check_start(start: int, K: int) -> None:
    """The first linearized stage of K (stage_jacobians, simulate_linearized) is one of 0..K.

    Raises:
        InvalidParameterError: it is not.
    """
    if not 0 <= start <= K:
        raise InvalidParameterError(f"start = {start!r} is not a stage of the {K} given; valid: 0..{K}")


class ReducedModel:
    """Reduced ODE ``ÿ = f(y, ẏ) + g(y) u`` of a :class:`ParallelRobot`.

    Holds warm starts for assembly (the last configuration with its velocity map and closure
    curvature, which predict the legs at a nearby pose to second order, and the states of the
    last pre-simulation): evaluating at a platform pose near a previous one costs one kinematics
    pass, or two with one Newton step. Results do not depend on them (Newton always converges to
    ‖Φ‖ ≤ 1e-12 on the home branch).

    The factorization, its ZOH discretization and the pre-simulation (:meth:`discrete`,
    :meth:`factorize`, :meth:`simulate_factorized`) run in the compiled core
    (:mod:`parallel_gpc.model.native_update`) when it is available; this class is their Python
    reference (the two agree to rounding, tested) and the compiled path calls back into it for
    anything unusual, so errors are the same.

    Args:
        robot: the robot (its model may carry a mass scale or another gravity).
        native: None (default) = use the compiled model update when it is available, False = the
            pure-Python reference, True = require the compiled one (InvalidParameterError if it
            is not available).

    Attributes:
        native: True when the compiled model update is used; ``native_reason`` says why or why not.
    """

    def __init__(self, robot: ParallelRobot, native: bool | None = None):
        self.robot = robot
        self.native = use_native(native)
        self.native_reason = model_update_status(native)
        self._compiled = None  # the _native.ModelUpdate, built at first use (plants only need terms)
        self.n_y = robot.n_y
        self.n_u = robot.n_u
        self.n_x = 2 * robot.n_y
        self.C = np.hstack([np.eye(self.n_y), np.zeros((self.n_y, self.n_y))])
        self._q_last = robot.q_home.copy()
        self._warm = None  # (q, y, T, Φ_z⁺, W, ẏ) at the last evaluation: the Newton predictor
        self._sim_warm = []  # the same at each state of the last pre-simulation
        self._S = robot.drive_selection
        nv, ny, nu = robot.model.nv, self.n_y, self.n_u
        self._zero_v = np.zeros(nv)
        # [M T | −K | Sᵀ | −g] of the reduced solve; the Sᵀ columns never change
        self._rhs = np.zeros((nv, 2 * ny + nu + 1))
        self._rhs[:, 2 * ny:2 * ny + nu] = self._S
        self._A0 = np.zeros((2 * ny, 2 * ny))
        self._A0[:ny, ny:] = np.eye(ny)

    @property
    def _native(self):
        """The compiled model update (built at first use)."""
        if self._compiled is None:
            self._compiled = compiled_model_update(self.robot)
        return self._compiled

    @property
    def compiled_update(self):
        """The compiled model update (``_native.ModelUpdate``) this model's pre-simulations run in, or
        None on the Python reference path: a compiled caller passes it to fuse a pre-simulation with
        its own work (the nonlinear form's Riccati step, :mod:`parallel_gpc.gpc.riccati`)."""
        return self._native if self.native else None

    def prepare(self) -> None:
        """Build now what the first pre-simulation would build (the compiled model update), so that the first
        control step costs what every step costs; a controller calls it at construction. Nothing on the Python
        reference path; calling it again does nothing."""
        if self.native:
            self._native  # noqa: B018 (the property builds it)

    # -------------------------------------------------------------- kinematics
    def _kinematics(self, y: np.ndarray, base=None):
        """(q, T, Φ_z⁺) at platform pose y: warm-started assembly and velocity map.

        The Newton start is a known nearby configuration (``base`` = (q, y, T, Φ_z⁺, W, ẏ), default
        the last evaluation) moved along the constraint manifold to second order:
        z ≈ z₀ + T_z δy + ½ d²z, the curvature term from Φ̇_q of the last factorization when δy
        is along its velocity. The start only changes the number of Newton steps, not the
        converged q. A base at y itself gives its own (q, T, Φ_z⁺) (the same numbers).
        """
        r = self.robot
        near = base is not None
        if near and np.array_equal(y, base[1]):  # the base's own pose: its assembly
            q, T, pinv_z = base[0], base[2], base[3]
            self._q_last = q
            self._warm = (q, y.copy(), T, pinv_z, None, None)
            return q, T, pinv_z
        if base is None:
            base = self._warm
        if base is None:
            guess, pinv_b = self._q_last, None
        else:
            q_b, y_b, T_b, pinv_b, W_b, yd_b = base
            dy = y - y_b
            step = T_b @ dy
            if near:  # an explicitly given base is ~0.1 mm away: first order is enough
                near = bool(dy @ dy < 1e-8)
            elif W_b is not None:  # z'' along δy ≈ −Φ_z⁺ Φ̇_q(T δy) T δy with T δy ≈ α T ẏ
                ss = yd_b @ yd_b
                if ss > 0.0:
                    step[r.dependent_v] -= (0.5 * (dy @ yd_b) / ss) * (W_b @ dy)
            guess = r.integrate(q_b, step)
        out = r.assemble_warm(y, guess, pinv_b, near)
        if out is None:  # validated path: Newton from the last q, continuation from home, clear errors
            q = r.assemble(y, self._q_last)
            T, pinv_z = r.velocity_map_nocopy(q)
        else:
            q, T, pinv_z = out
        self._q_last = q
        self._warm = (q, y.copy(), T, pinv_z, None, None)
        return q, T, pinv_z

    # -------------------------------------------------------------- reduced terms
    def terms_at_q(self, q: np.ndarray, ydot: np.ndarray) -> ReducedTerms:
        """Reduced terms at an assembled configuration q and platform velocity ẏ."""
        q = np.asarray(q, dtype=float)
        T, pinv_z = self.robot.velocity_map_nocopy(q)
        return self._terms(q, T, pinv_z, np.asarray(ydot, dtype=float))

    def _terms(self, q, T, pinv_z, ydot) -> ReducedTerms:
        r = self.robot
        model, data = r.model, r.data
        v = T @ ydot
        dPhi = r.constraint_jacobian_derivative(q, v)
        gamma = dPhi @ v
        warm = self._warm
        if warm is not None and warm[0] is q:  # curvature for the next Newton start
            self._warm = (q, warm[1], T, pinv_z, pinv_z @ (dPhi @ T), ydot)
        ell = np.zeros(model.nv)
        ell[r.dependent_v] = -(pinv_z @ gamma)
        _, _, M = pin.computeRNEADerivatives(model, data, q, v, self._zero_v)  # M full, data.tau = h
        M = np.array(M)
        h = data.tau + M @ ell
        MT = M @ T
        return ReducedTerms(
            q=q, v=v, T=T.copy(), ell=ell, M=M,
            M_r=T.T @ MT, h_r=T.T @ h, B_r=T[r.drive_v].T.copy(), pinv_z=pinv_z.copy(),
        )

    def assemble(self, y: np.ndarray) -> np.ndarray:
        """Full configuration at platform pose y, warm-started from the last one."""
        return self._kinematics(np.asarray(y, dtype=float))[0]

    def terms(self, X: np.ndarray) -> ReducedTerms:
        """Reduced terms at state X = [y, ẏ]."""
        X = np.asarray(X, dtype=float)
        q, T, pinv_z = self._kinematics(X[: self.n_y])
        return self._terms(q, T, pinv_z, X[self.n_y:])

    # -------------------------------------------------------------- eq. (1), (2)
    def acceleration(self, X: np.ndarray, u: np.ndarray) -> np.ndarray:
        """(n_y,) ÿ = f + g u at state X for drive torques u (N·m), eq. (1)."""
        return self.terms(X).acceleration(np.asarray(u, dtype=float))

    def state_derivative(self, X: np.ndarray, u: np.ndarray) -> np.ndarray:
        """(n_x,) Ẋ = F(X) + G(X) u, eq. (2)."""
        X = np.asarray(X, dtype=float)
        return np.concatenate([X[self.n_y:], self.acceleration(X, u)])

    # -------------------------------------------------------------- eq. (3)
    def _bias_rows(self, q: np.ndarray, T: np.ndarray, pinv_z: np.ndarray, ydot: np.ndarray):
        """The ẏ-dependent part of the factorization (3) at q (assembled, or on the closures' tangent
        for the Jacobian's differences) with its T and Φ_z⁺, linear in ẏ.

        Returns:
            (W (n_z, n_y), M (nv, nv), K (nv, n_y)): W = Φ_z⁺ Φ̇_q(T ẏ) T (the Newton predictor's
            curvature), the full mass matrix (a view of Pinocchio's data: use before the next
            RNEA call), and K = M_z W − ½ ∂h/∂v T with Tᵀ K = −C_r(y, ẏ) (W averaged with
            Φ_z⁺ [Φ̇_q(T e_i) v]_i when the closure bias is not symmetric).
        """
        r = self.robot
        model, data = r.model, r.data
        v = T @ ydot
        dPhi = r.constraint_jacobian_derivative(q, v)
        # ℓ_z(ẏ) = −Φ_z⁺ γ(T ẏ) with γ(v) = Φ̇_q(v) v bilinear in v:
        # ∂ℓ_z/∂ẏ = −Φ_z⁺ (Φ̇_q(v) T + [Φ̇_q(T e_i) v]_i); both terms are equal for point
        # closures (Φ_q is the gradient of a position: symmetric second derivatives).
        W = pinv_z @ (dPhi @ T)
        Wb = W
        if not r.bias_symmetric:
            W2 = np.column_stack([r.constraint_jacobian_derivative(q, T[:, i]) @ v for i in range(self.n_y)])
            Wb = 0.5 * (W + pinv_z @ W2)
        _, D, M = pin.computeRNEADerivatives(model, data, q, v, self._zero_v)  # D = ∂h/∂v, M full
        # −C_r = −½ Tᵀ ∂(h + M ℓ)/∂v T = Tᵀ (M_z W − ½ D T)
        DT = r.universal_joints.bias_derivative(model, q, v, T) if r.universal_joints else D @ T
        return W, M, M[:, r.dependent_v] @ Wb - 0.5 * DT

    def _factor_rows(self, X: np.ndarray, base=None) -> np.ndarray:
        """(n_y, n_y + n_u + 1) Z = M_r⁻¹ [−C_r | B_r | −g_r]: the ẏ-rows [A₂₂ | B₂ | c₂] of the
        factorization (3) at X (see :meth:`factorize`)."""
        if self.native and base is None:
            return self._native.factor_rows(X)
        ny = self.n_y
        q, T, pinv_z = self._kinematics(X[:ny], base)
        Z, W = self._factor_at(q, T, pinv_z, X[ny:])
        self._warm = (q, self._warm[1], T, pinv_z, W, X[ny:].copy())
        return Z

    def _factor_at(self, q: np.ndarray, T: np.ndarray, pinv_z: np.ndarray, ydot: np.ndarray):
        """(Z, W) of :meth:`_factor_rows` at a configuration q with its (T, Φ_z⁺) and ẏ (W: see
        :meth:`_bias_rows`); q need not be assembled (the Jacobian's differences along the tangent)."""
        model, data = self.robot.model, self.robot.data
        ny = self.n_y
        W, M, K = self._bias_rows(q, T, pinv_z, ydot)
        rhs = self._rhs  # [M T | K | Sᵀ | −g]: one product with Tᵀ gives [M_r | −C_r | B_r | −g_r]
        np.matmul(M, T, out=rhs[:, :ny])
        rhs[:, ny:2 * ny] = K
        # (not np.negative(x, out=x): on a strided view it is wrong in numpy 2.4.6)
        rhs[:, -1] = -pin.computeGeneralizedGravity(model, data, q)
        red = T.T @ rhs
        return spd_solve(red[:, :ny], red[:, ny:]), W

    def _factor_derivatives(self, X: np.ndarray, step: float, base=None):
        """Z = :meth:`_factor_rows` at X and its derivatives ∂Z/∂X_k (the reference of the compiled
        ``stage_jacobians``).

        ∂Z/∂ẏ_j is exact: Z's first block −M_r⁻¹ C_r(y, ẏ) is linear in ẏ, so its derivative is the
        same block at ẏ = e_j (K of :meth:`_bias_rows` at e_j, one more solve with M_r), at the
        same q; the other blocks do not depend on ẏ. ∂Z/∂y_j is a forward difference of Z along
        the closures' tangent: Z at q + T e_j h_j (h_j = ``step``·max(1, |y_j|)), not assembled,
        minus Z at X. Z(q) is smooth off the closures too and the line q + T e_j h has the
        assembled curve's first derivative (it leaves the curve by ½ z'' h²): O(h) like the forward
        difference on the curve, without a Newton step. There T and Φ_z⁺ are taken to first order,
        T + h Ṫ_j and Φ_z⁺ + h (Φ_z⁺)˙_j (``velocity_map_rate`` of the robot, from Φ̇_q(T e_j)): an
        O(h) change of the difference like the step's own, instead of a kinematics pass and a
        factorization of the assembly Jacobian at q + T e_j h. One model update per direction (a
        central difference costs two: measured, the forward one at h ≈ √ε (:data:`TANGENT_STEP`)
        moves ∂Φ/∂X by ≤ 3e-9 of its norm).

        Args:
            X: (n_x,) state. step: relative step. base: the warm start of a pre-simulation at X
                (its assembly is reused), or None.

        Returns:
            (Z (n_y, n_y + n_u + 1), dZ (n_x, n_y, n_y + n_u + 1)).
        """
        model, data = self.robot.model, self.robot.data
        r = self.robot
        ny, nu = self.n_y, self.n_u
        nc = ny + nu + 1
        y, yd = X[:ny], X[ny:]
        q, T, pinv_z = self._kinematics(y, base)
        W, M, K = self._bias_rows(q, T, pinv_z, yd)
        self._warm = (q, self._warm[1], T, pinv_z, W, yd.copy())
        rhs = np.empty((M.shape[0], ny + nc + ny * ny))
        rhs[:, :ny] = M @ T
        rhs[:, ny:2 * ny] = K
        rhs[:, 2 * ny:ny + nc - 1] = self._S
        for j in range(ny):  # K is linear in ẏ: K(e_j) = ∂K/∂ẏ_j
            rhs[:, ny + nc + j * ny:ny + nc + (j + 1) * ny] = self._bias_rows(q, T, pinv_z, np.eye(ny)[j])[2]
        rhs[:, ny + nc - 1] = -pin.computeGeneralizedGravity(model, data, q)
        red = T.T @ rhs
        sol = spd_solve(red[:, :ny], red[:, ny:])
        Z = sol[:, :nc]
        dZ = np.zeros((2 * ny, ny, nc))
        dZ[ny:, :, :ny] = sol[:, nc:].reshape(ny, ny, ny).transpose(1, 0, 2)
        for j in range(ny):
            h = step * max(1.0, abs(y[j]))
            dT, dP = r.velocity_map_rate(q, T, pinv_z, r.constraint_jacobian_derivative(q, T[:, j]))
            dZ[j] = (self._factor_at(r.integrate(q, T[:, j] * h), T + h * dT, pinv_z + h * dP, yd)[0] - Z) / h
        return Z, dZ

    def factorize(self, X: np.ndarray):
        """State-dependent factorization ``Ẋ = A(X) X + B(X) u + c(X)``, eq. (3).

        h_r is quadratic in ẏ plus a gravity part: h_r = C_r(y, ẏ) ẏ + g_r(y) with
        C_r = ½ ∂h_r/∂ẏ (exact for a quadratic form). The gravity part is the affine term c.
        ∂h_r/∂ẏ = Tᵀ (∂h/∂v + M ∂ℓ/∂v) T comes from Pinocchio's RNEA derivatives and the
        closure Jacobian derivative Φ̇_q (γ = Φ̇_q q̇ is bilinear in q̇).

        Returns:
            A: (n_x, n_x) [[0, I], [0, −M_r⁻¹ C_r]].
            B: (n_x, n_u) [[0], [M_r⁻¹ B_r]].
            c: (n_x,) [0; −M_r⁻¹ g_r] (zero for a horizontal robot).
        """
        X = np.asarray(X, dtype=float)
        ny, nu = self.n_y, self.n_u
        Z = self._factor_rows(X)
        A = self._A0.copy()
        A[ny:, ny:] = Z[:, :ny]
        B = np.zeros((2 * ny, nu))
        B[ny:] = Z[:, ny:ny + nu]
        c = np.zeros(2 * ny)
        c[ny:] = Z[:, -1]
        return A, B, c

    def discrete(self, X: np.ndarray, Ts: float):
        """ZOH discretization (4) of the factorization (3) at X: (A_d, B_d, c_d).

        The same numbers as ``discretize_zoh(*factorize(X), Ts)``, built without the
        intermediate matrices.
        """
        X = np.asarray(X, dtype=float)
        if self.native:
            return zoh_split(self._native.discrete(X, Ts), self.n_x, self.n_u)
        return zoh_split(expm(self._zoh_augmented(X, Ts)), self.n_x, self.n_u)

    def stage_jacobians(self, X_seq: np.ndarray, u_seq: np.ndarray, Ts: float, step: float = TANGENT_STEP,
                        start: int = 0):
        """∂Φ/∂X of the stage map Φ(X, u) = E(X)·[X; u; 1] = A_d(X) X + B_d(X) u + c_d(X)
        (:meth:`discrete`, the pre-simulation's map (10)) at each stage of a trajectory.

        ∂Φ/∂X_k = E[:, k] + (∂E/∂X_k)·[X; u; 1], E the top rows of exp(Ts·[[0, I, 0], [0, Z(X)]])
        (Z = M_r⁻¹ [−C_r | B_r | −g_r]); the second term is the Fréchet derivative of the
        exponential along Ts·∂Z/∂X_k applied to one vector
        (:func:`~parallel_gpc.model.discretization.expm_derivative_action`). ∂Z/∂ẏ is exact (Z is
        linear in ẏ), ∂Z/∂y a forward difference of Z along the closures' tangent with step
        h = ``step``·max(1, |y|) (:meth:`_factor_derivatives`): n_y model updates without
        assembly per stage (the states' own assemblies come from the last pre-simulation when it
        visited them, in the compiled core their factorizations too) instead of the 2·n_x
        assembled updates and exponentials of differences of Φ
        (:meth:`stage_jacobians_differences`, the test oracle; they agree to ~3e-9 relative). The
        compiled core runs all stages in one call (``_native.stage_jacobians``), on
        ``PARALLEL_GPC_THREADS`` threads when every stage is a state of the last pre-simulation (the
        stages are then independent: the same numbers bit for bit as on one thread,
        :func:`~parallel_gpc.model.native_update.compiled_threads`); this method's loop is its reference.

        Args:
            X_seq: (≥ K, n_x) states X(0..K−1) (m, rad, m/s, rad/s); u_seq: (K, n_u) inputs (N·m);
            Ts: sample time (s); step: relative forward-difference step of the y-derivatives of Z;
            start: the first stage (0..K): the stages before it are skipped (a fixed initial state
                needs no ∂Φ/∂X at stage 0).

        Returns:
            (K − start, n_x, n_x) Jacobians of the stages start..K−1.
        """
        X_seq, u_seq = np.asarray(X_seq, dtype=float), np.asarray(u_seq, dtype=float)
        K, n, ny = len(u_seq), self.n_x, self.n_y
        _check_start(start, K)
        compiled = native_module() if self.native else None
        if compiled is not None and hasattr(compiled, "stage_jacobians"):
            return compiled.stage_jacobians(self._native, np.ascontiguousarray(X_seq[:K]), np.ascontiguousarray(u_seq),
                                            Ts, step, start).reshape(K - start, n, n)
        J = np.empty((K - start, n, n))
        M_top = np.zeros((n, n + self.n_u + 1))
        M_top[:ny, ny:n] = np.eye(ny) * Ts
        D_top = np.zeros((n, n, n + self.n_u + 1))
        sim = self._sim_warm  # the last pre-simulation's assemblies: usually at these very states
        for i in range(start, K):
            x = X_seq[i]
            base = sim[i] if i < len(sim) and np.array_equal(sim[i][1], x[:ny]) else None
            Z, dZ = self._factor_derivatives(x, step, base)
            M_top[ny:, ny:] = Z * Ts
            D_top[:, ny:, ny:] = dZ * Ts
            E, dE = expm_derivative_action(M_top, D_top, np.concatenate([x, u_seq[i], [1.0]]))
            J[i - start] = E[:, :n] + dE
        return J

    def stage_jacobians_differences(self, X_seq: np.ndarray, u_seq: np.ndarray, Ts: float,
                                    step: float = JACOBIAN_STEP) -> np.ndarray:
        """(K, n_x, n_x) ∂Φ/∂X by central differences of the whole stage map Φ (2·n_x :meth:`discrete`
        per stage, step h_k = ``step``·max(1, |X_k|): truncation O(h²) ≈ 1e-10, rounding ≈ 1e-11
        relative): the oracle of :meth:`stage_jacobians` (same arguments)."""
        X_seq, u_seq = np.asarray(X_seq, dtype=float), np.asarray(u_seq, dtype=float)
        K, n = len(u_seq), self.n_x
        J = np.empty((K, n, n))
        for i in range(K):
            x, u = X_seq[i], u_seq[i]
            for k in range(n):
                h = step * max(1.0, abs(x[k]))
                xp, xm = x.copy(), x.copy()
                xp[k] += h
                xm[k] -= h
                Ap, Bp, cp = self.discrete(xp, Ts)
                Am, Bm, cm = self.discrete(xm, Ts)
                J[i, :, k] = (Ap @ xp + Bp @ u + cp - (Am @ xm + Bm @ u + cm)) / (xp[k] - xm[k])
        return J

    def _zoh_augmented(self, X: np.ndarray, Ts: float) -> np.ndarray:
        """The (n_x + n_u + 1)² matrix [[A, B, c], [0, 0, 0]]·Ts of the factorization at X."""
        ny = self.n_y
        n = self.n_x + self.n_u + 1
        aug = np.zeros((n, n))
        aug[:ny, ny:2 * ny] = np.eye(ny) * Ts
        aug[ny:2 * ny, ny:] = self._factor_rows(X) * Ts
        return aug

    def simulate_factorized(self, X0: np.ndarray, u_seq: np.ndarray, Ts: float, offset=None):
        """Pre-simulate the state-dependent ZOH model along an input sequence, eq. (10):

        .. math:: X(i+1) = A_d(X(i))\\,X(i) + B_d(X(i))\\,u(i) + c_d(X(i)) + d, \\quad i = 0..K-1

        with (A_d, B_d, c_d) the factorization (3) at X(i) discretized by ZOH (4) — the same
        numbers as ``discretize_zoh(*factorize(X(i)), Ts)``, built without intermediate matrices
        and warm-started from the previous pre-simulation (the receding horizon revisits nearly
        the same states one index later).

        Args:
            X0: (n_x,) initial state; u_seq: (K, n_u) inputs (N·m); Ts: sample time (s);
            offset: (n_x,) constant d added to every step (a disturbance estimate), or None.

        Returns:
            (A_seq (K, n_x, n_x), B_seq (K, n_x, n_u), c_seq (K, n_x) without the offset,
            X_seq (K + 1, n_x) with X_seq[0] = X0).
        """
        Ts = positive("Ts", Ts, " s")
        X0 = np.asarray(X0, dtype=float)
        u_seq = np.asarray(u_seq, dtype=float)
        K = u_seq.shape[0]
        ny, nu, nx = self.n_y, self.n_u, self.n_x
        if self.native:
            Es, Xs = self._native.simulate(X0, u_seq, Ts, None if offset is None else np.asarray(offset, dtype=float))
            return (*zoh_split(Es, nx, nu), Xs)
        n_aug = nx + nu + 1
        aug = np.zeros((K, n_aug, n_aug))
        aug[:, :ny, ny:nx] = np.eye(ny) * Ts
        Xs = np.empty((K + 1, nx))
        Xs[0] = X0
        Es = np.empty((K, nx, n_aug))  # the x-rows of each exp(aug·Ts)
        xu = np.empty(n_aug)
        xu[-1] = 1.0
        d = None if offset is None else np.asarray(offset, dtype=float)
        # Warm starts: the previous simulation visited nearly the same states one index later
        # (the last control step's pre-simulation, receding horizon) or at the same index (a
        # rollout of the same step: the NMPC line search); use the nearer when it is closer than
        # the previous step.
        prev = self._sim_warm
        warms = []
        for i in range(K):
            x = Xs[i]
            base, nearest = None, 1e-8
            for cand in prev[i:i + 2]:
                dy = x[:ny] - cand[1]
                if (d2 := dy @ dy) < nearest:
                    base, nearest = cand, d2
            Z = self._factor_rows(x, base)
            warms.append(self._warm)
            np.multiply(Z, Ts, out=aug[i, ny:nx, ny:])
            E = expm(aug[i])
            Es[i] = E[:nx]
            xu[:nx] = x
            xu[nx:nx + nu] = u_seq[i]
            np.matmul(Es[i], xu, out=Xs[i + 1])
            if d is not None:
                Xs[i + 1] += d
        self._sim_warm = warms
        return (*zoh_split(Es, nx, nu), Xs)

    # -------------------------------------------------------------- Jacobian linearization
    def simulate_linearized(self, X0: np.ndarray, u_seq: np.ndarray, Ts: float, offset=None,
                            step: float = TANGENT_STEP, start: int = 0):
        """:meth:`simulate_factorized` and :meth:`stage_jacobians` of its states in one call (the
        nonlinear MPC iterations' rollout of a plan they will linearize, gpc/nmpc.py).

        The compiled core (``_native.simulate_linearized``) runs the rollout on the calling thread and
        the Jacobians of the stages it has finished on ``PARALLEL_GPC_THREADS`` − 1 more threads
        meanwhile (the same numbers bit for bit as the two calls: a stage's Jacobian depends on its
        state, input and warm start alone); on one thread, on the Python path and where the compiled
        core predates it, the two calls one after the other (this method's reference).

        Args:
            X0: (n_x,) initial state (m, rad, m/s, rad/s); u_seq: (K, n_u) inputs (N·m); Ts: sample
                time (s); offset: (n_x,) constant d added to every step, or None; step: relative
                forward-difference step of the y-derivatives of Z; start: the first stage linearized (0..K).

        Returns:
            (A_seq (K, n_x, n_x), B_seq (K, n_x, n_u), c_seq (K, n_x) without the offset,
            X_seq (K + 1, n_x) with X_seq[0] = X0, JX (K − start, n_x, n_x) ∂Φ/∂X at stages start..K−1).

        Raises:
            the errors of :meth:`simulate_factorized` (the rollout's first), else of :meth:`stage_jacobians`.
        """
        compiled = native_module() if self.native else None
        if compiled is None or not hasattr(compiled, "simulate_linearized"):
            A_seq, B_seq, c_seq, X_seq = self.simulate_factorized(X0, u_seq, Ts, offset)
            return A_seq, B_seq, c_seq, X_seq, self.stage_jacobians(X_seq, u_seq, Ts, step, start)
        Ts = positive("Ts", Ts, " s")
        u_seq = np.ascontiguousarray(u_seq, dtype=float)
        K, nx, nu = u_seq.shape[0], self.n_x, self.n_u
        _check_start(start, K)
        Es, Xs, JX = compiled.simulate_linearized(self._native, np.asarray(X0, dtype=float), u_seq, Ts,
                                                  None if offset is None else np.asarray(offset, dtype=float),
                                                  step, start)
        return (*zoh_split(Es, nx, nu), Xs, JX)

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


def kinetic_energy(model: ReducedModel, X: np.ndarray) -> float:
    """Kinetic energy ½ ẏᵀ M_r ẏ in J at state X."""
    X = finite_vector("X", X, model.n_x)
    terms = model.terms(X)
    yd = X[model.n_y:]
    return 0.5 * float(yd @ terms.M_r @ yd)
