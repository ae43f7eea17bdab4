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
drive rates, when measured, add ẏ_m = ẏ + v' through the same Jacobian.

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
        self._reading_std = sensors.reading_std(self.robot)
        self._rates = sensors.measures_rates(self.robot)
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
        self._eye = np.eye(3 * n)
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
        """(z⁻, F) of one sample from the current estimate with input u."""
        n = self.n_y
        X = self.z[:2 * n]
        Ad, Bd, cd = self.model.discrete(X, self.Ts)
        x_next = Ad @ X + Bd @ u + cd
        x_next[n:] += self.z[2 * n:]
        F = np.zeros((3 * n, 3 * n))
        F[:2 * n, :2 * n] = Ad
        F[n:2 * n, 2 * n:] = np.eye(n)
        F[2 * n:, 2 * n:] = np.eye(n)
        return np.concatenate([x_next, self.z[2 * n:]]), F

    def predict(self, u) -> np.ndarray:
        """Advance the estimate over one sample with u held (N·m, N): z(k+1|k), P(k+1|k).

        Returns:
            (2 n_y,) the predicted [y, ẏ].
        """
        u = finite_vector("drive torques u", u, self.model.n_u)
        self.z, F = self._transition(u)
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
        Jw = sol.jacobian / self._reading_std[:, None]
        R = np.linalg.inv(Jw.T @ Jw)
        innovation = sol.pose - self.z[:n]
        m = n  # measured: y (H = [I 0 0]), and ẏ (H = [0 I 0]) when the drive rates are
        if self._rates and measurement.rates is not None:
            std = np.full(self.robot.n_u, max(self.sensors.rate_noise, 1e-12))
            ydot = self.robot.forward_velocity(sol, measurement.rates, std)
            Jr = sol.jacobian / std[:, None]
            R = np.block([[R, np.zeros((n, n))], [np.zeros((n, n)), np.linalg.inv(Jr.T @ Jr)]])
            innovation = np.concatenate([innovation, ydot - self.z[n:2 * n]])
            m = 2 * n
        # H selects the first m components: P Hᵀ = P[:, :m], H P Hᵀ = P[:m, :m], K H = [K 0]
        PHt = self.P[:, :m]
        K = np.linalg.solve(self.P[:m, :m] + R, PHt.T).T
        self.z = self.z + K @ innovation
        IKH = self._eye.copy()
        IKH[:, :m] -= K
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T  # Joseph form: stays symmetric positive
        return self.state
