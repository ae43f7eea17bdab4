"""Kalman filter on the controller's discrete reduced model, fed by drive encoders.

State z = [y, ẏ, d] (3 n_y): the output, its rate, and a velocity disturbance d (m/s or rad/s
per sample) added to the model's affine term — the disturbance the incremental forms estimate
today by d ← d + α (X − X̂(k|k−1)), here estimated with the state by one filter, so offset-free
tracking comes from one estimator. The model is the controller's, discretized at the estimate
(ZOH of the factorization, :meth:`~parallel_gpc.model.ReducedModel.discrete`):

    z(k+1) = [[A_d, E], [0, I]] z(k) + [B_d; 0] u(k) + [c_d; 0] + w,   E = [0; I]

with process noise w: white acceleration of standard deviation ``accel_std`` over a sample on
[y, ẏ] and a random walk of σ_d per sample on d. The measurement is the pose
from forward kinematics of the encoder readings, y_m = y + v, with covariance
(Jᵀ Σ⁻¹ J)⁻¹ (J the drive Jacobian, Σ the readings' quantization and noise variance);
drive rates, when measured, add ẏ_m = ẏ + v' through the same Jacobian. The correction runs in
the compiled core (``_native.kalman_correct``) when the model does; :meth:`StateEstimator.update`
holds its NumPy reference.

The disturbance model is set by its bandwidth ω_d (rad/s), not by σ_d: with readings much finer
than the acceleration noise over a sample (encoders: Δ ≪ accel_std Ts²), the disturbance
estimate follows a step of d as e^{−ω_d t} — the slowest pole of the steady-state filter is
e^{−ω_d Ts} — when

    σ_d = ω_d Ts² accel_std

(the random walk of d seen through the velocity increments, whose noise is Ts accel_std: a
scalar Kalman gain σ_d / (Ts accel_std) per sample). So the filter rejects a load or a mass
mismatch equally fast at any Ts. The default, :data:`DISTURBANCE_BANDWIDTH`, is 10 rad/s
(time constant 0.1 s, a fifth of the shortest move of the built-in references); a fixed σ_d of
2e-5 m/s per sample, the earlier default, was 2.5 rad/s at Ts = 2 ms but 0.1 rad/s at 10 ms
(a 10 s time constant: the encoder loop of ``parallel-gpc demo`` ended ~1 mm off).
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidParameterError, SensorError
from ..model.linalg import spd_solve
from ..model.native import native_module
from ..validation import finite_vector, positive
from .sensors import Measurement, Sensors

#: default bandwidth ω_d of the disturbance estimate (rad/s): it follows a step of d as e^{−ω_d t}
DISTURBANCE_BANDWIDTH = 10.0


class StateEstimator:
    """Kalman filter of [y, ẏ, d] from drive readings (see the module docstring).

    Args:
        model: the controller's :class:`~parallel_gpc.model.ReducedModel` (its robot gives
            the forward kinematics).
        Ts: sample time (s).
        sensors: what is measured (:class:`Sensors`, kind ``"encoders"``).
        X0: (2 n_y,) initial estimate [y, ẏ] (m, rad, m/s, rad/s), e.g. the start pose at rest.
        accel_std: process noise, standard deviation of the unmodelled acceleration (m/s², rad/s²).
        disturbance_bandwidth: ω_d > 0 (rad/s), how fast the estimate of d follows a change of the
            disturbance (see the module docstring): d's random walk is σ_d = ω_d Ts² accel_std per
            sample (m/s, rad/s).
        initial_std: standard deviations of the initial [y, ẏ, d] errors.

    Attributes:
        z: (3 n_y,) current estimate [y, ẏ, d]. P: (3 n_y, 3 n_y) its covariance.
        disturbance_std: σ_d, the random-walk standard deviation of d per sample (m/s, rad/s).
        q: (nq,) configuration of the last forward kinematics (the warm start of the next).
    """

    def __init__(self, model, Ts: float, sensors: Sensors, X0, accel_std: float = 2.0,
                 disturbance_bandwidth: float = DISTURBANCE_BANDWIDTH, initial_std=(1e-3, 1e-2, 1e-3)):
        if not isinstance(sensors, Sensors) or sensors.kind != "encoders":
            raise InvalidParameterError(f"StateEstimator needs encoder Sensors, got {sensors!r}")
        self.model = model
        self.robot = model.robot
        self.Ts = positive("Ts", Ts, " s")
        self.sensors = sensors
        n = self.n_y = model.n_y
        X0 = finite_vector("X0", X0, 2 * n)
        self.resolution = sensors.resolution(self.robot)
        self._reading_weight = 1.0 / sensors.reading_std(self.robot)  # (n_u,): Σ^(-1/2) of the readings
        self._rates = sensors.measures_rates(self.robot)
        self._rate_std = np.full(self.robot.n_u, max(sensors.rate_noise, 1e-12))
        self._rate_weight = 1.0 / self._rate_std
        # the correction in the compiled core (native/src/kalman.cpp) when the model uses it; update's
        # NumPy lines are its reference (and run where it refuses a matrix that is not positive definite)
        compiled = native_module() if getattr(model, "native", False) else None
        self._compiled_correct = getattr(compiled, "kalman_correct", None)
        accel_std = positive("accel_std", accel_std)
        bandwidth = positive("disturbance_bandwidth", disturbance_bandwidth, " rad/s")
        Ts = self.Ts
        self.disturbance_std = bandwidth * Ts * Ts * accel_std
        G = np.array([0.5 * Ts * Ts, Ts]) * accel_std
        Q = np.zeros((3 * n, 3 * n))
        eye = np.eye(n)
        Q[:2 * n, :2 * n] = np.kron(np.outer(G, G), eye)
        Q[2 * n:, 2 * n:] = self.disturbance_std**2 * eye
        self.Q = Q
        self._eyes = {m: np.eye(m) for m in (n, 2 * n)}  # the measured blocks: y, or y and ẏ
        self._F = np.eye(3 * n)  # the transition [[A_d, E], [0, I]], A_d filled in at each prediction
        self._F[n:2 * n, 2 * n:] = eye
        self.z = np.concatenate([X0, np.zeros(n)])
        self.P = np.diag(np.repeat(np.asarray(initial_std, dtype=float) ** 2, n))
        self.q = self.robot.assemble(X0[:n])
        self._u = None  # input of the pending prediction

    @property
    def state(self) -> np.ndarray:
        """(2 n_y,) estimated [y, ẏ]."""
        return self.z[:2 * self.n_y].copy()

    @property
    def disturbance(self) -> np.ndarray:
        """(2 n_y,) the disturbance in the controller's convention (added to c_d): [0, d]."""
        return np.concatenate([np.zeros(self.n_y), self.z[2 * self.n_y:]])

    def _transition(self, u: np.ndarray):
        """(z⁻, A_d) of one sample from the current estimate with input u."""
        n = self.n_y
        X = self.z[:2 * n]
        Ad, Bd, cd = self.model.discrete(X, self.Ts)
        x_next = Ad @ X + Bd @ u + cd
        x_next[n:] += self.z[2 * n:]
        return np.concatenate([x_next, self.z[2 * n:]]), Ad

    def predict(self, u) -> np.ndarray:
        """Advance the estimate over one sample with u held (N·m, N): z(k+1|k), P(k+1|k).

        Returns:
            (2 n_y,) the predicted [y, ẏ].
        """
        u = finite_vector("drive torques u", u, self.model.n_u)
        self.z, Ad = self._transition(u)
        F = self._F
        F[:2 * self.n_y, :2 * self.n_y] = Ad
        self.P = F @ self.P @ F.T + self.Q
        return self.state

    def ahead(self, u) -> np.ndarray:
        """(2 n_y,) x̂(k+1|k): the state one sample ahead under u, without changing the estimate
        (one-sample computation delay: u(k+1) computed during sample k from it)."""
        u = finite_vector("drive torques u", u, self.model.n_u)
        return self._transition(u)[0][:2 * self.n_y]

    def update(self, measurement: Measurement) -> np.ndarray:
        """Correct the estimate with one sample of readings: z(k|k), P(k|k).

        Returns:
            (2 n_y,) the estimated [y, ẏ].

        Raises:
            SensorError: readings that are NaN, out of range or that no pose explains (naming
                the drive), or a measurement without drive positions.
        """
        if measurement.drives is None:
            raise SensorError("the measurement has no drive positions; encoder sensors need measure() to return "
                              "Measurement(drives=...)")
        n = self.n_y
        sol = self.robot.forward_solution(measurement.drives, self.q, self.resolution)
        self.q = sol.q
        innovation = sol.pose - self.z[:n]
        rates = self._rates and measurement.rates is not None
        if rates:  # ẏ from the drive rates through the same Jacobian
            ydot = self.robot.forward_velocity(sol, measurement.rates, self._rate_std)
            innovation = np.concatenate([innovation, ydot - self.z[n:2 * n]])
        if self._compiled_correct is not None:
            z, P = np.empty_like(self.z), np.empty_like(self.P)
            if self._compiled_correct(sol.jacobian, self._reading_weight, self._rate_weight, innovation, self.z,
                                      self.P, z, P):
                self.z, self.P = z, P
                return self.state
        Jw = sol.jacobian * self._reading_weight[:, None]
        info = Jw.T @ Jw  # Jᵀ Σ⁻¹ J: the information of the measured pose, R = info⁻¹
        if rates:  # and of ẏ (the rate noise through J)
            Jr = sol.jacobian * self._rate_weight[:, None]
            info = np.block([[info, np.zeros((n, n))], [np.zeros((n, n)), Jr.T @ Jr]])
        m = len(innovation)  # measured: y (H = [I 0 0]), and ẏ (H = [0 I 0]) when the drive rates are
        P = self.P
        R = spd_solve(info, self._eyes[m])
        # H selects the first m components: P Hᵀ = P[:, :m], H P Hᵀ = P[:m, :m], K H = [K 0]; S and P
        # symmetric: K = P Hᵀ S⁻¹ = (S⁻¹ H P)ᵀ
        K = spd_solve(P[:m, :m] + R, P[:m]).T
        self.z = self.z + K @ innovation
        # Joseph form (stays symmetric positive) (I − K H) P (I − K H)ᵀ + K R Kᵀ as B − (B Hᵀ − K R) Kᵀ
        # with B = (I − K H) P: three small products instead of four products of 3 n_y × 3 n_y
        B = P - K @ P[:m]
        self.P = B - (B[:, :m] - K @ R) @ K.T
        return self.state
