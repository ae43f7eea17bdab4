"""Plants: nonlinear simulation of the robot, used as the controlled system.

* :class:`ConstrainedPlant` integrates the **full** constrained model with Pinocchio's
  ``constraintDynamics`` (legacy ``RigidConstraintModel`` CONTACT_3D / CONTACT_6D closures with
  Baumgarte stabilization), RK4 over each sample (in Python, or in one call to the compiled core
  ``parallel_gpc._native`` when it is built), then projects q and v back onto the closures.
* :class:`ReducedPlant` integrates the reduced ODE ``ÿ = f + g u`` with RK4 sub-steps.

Both are built with their sample time Ts (``step(u)`` advances one sample; a closed loop checks
once that it equals the controller's), hold the input constant over a sample (zero-order hold),
accept a constant external force on the platform, saturate the drives at the plant's own torque
limit (validated when the plant is built; saturated samples are counted, not hidden), and are
separate objects from the controller's model.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from .discretization import rk4_step
from .dynamics import ReducedModel
from .native_plant import compiled_plant
from .native_update import compiled_model_update, use_native
from .robot import ParallelRobot
from .singular_kkt import SingularMassKKT, singular_mass_matrix
from ..errors import InvalidParameterError, NonFiniteError
from ..limits import Limits, symmetric_limit
from ..validation import all_finite, finite_vector, positive

_CONTACT = {"point": pin.ContactType.CONTACT_3D, "weld": pin.ContactType.CONTACT_6D}
#: ``pin.ProximalSettings(accuracy, mu, max_iter)`` of every constraintDynamics call
_PROXIMAL = (1e-12, 1e-10, 50)
_NO_FORCE = np.zeros(0)


def saturation_limit(torque_limit, n_u: int) -> np.ndarray | None:
    """(n_u,) drive saturation of a plant (N·m), or None.

    Args:
        torque_limit: None, a number or (n_u,) values > 0, or a
            :class:`~parallel_gpc.limits.Limits` (its torque limit; a plant saturates torques only).
        n_u: drive count.

    Raises:
        InvalidParameterError: a Limits with an increment limit, or a value that is not a number.
        ShapeError: not a scalar or (n_u,). InfeasibleLimitsError: a value ≤ 0, NaN or infinite.
    """
    if isinstance(torque_limit, Limits):
        if torque_limit.du is not None:
            raise InvalidParameterError(f"a plant saturates drive torques only; its limits {torque_limit!r} hold a "
                                        "du limit")
        return None if torque_limit.torque is None else torque_limit.for_drives(n_u).torque
    return symmetric_limit("plant torque", torque_limit, n_u)


class _PlantBase:
    """Shared state handling: X = [y, ẏ], sample time, external platform force, drive saturation."""

    def __init__(self, robot: ParallelRobot, Ts: float, torque_limit=None, platform_force=None):
        self.robot = robot
        self.n_y, self.n_u = robot.n_y, robot.n_u
        self.Ts = positive("plant Ts", Ts, " s")
        self.torque_limit = saturation_limit(torque_limit, robot.n_u)
        self.platform_force = np.zeros(robot.n_y) if platform_force is None else finite_vector(
            "platform_force", platform_force, robot.n_y)
        self.saturated = 0

    def input_matrix(self) -> np.ndarray:
        """(n_y, n_u) B_r = Tᵀ Sᵀ at the plant's current configuration: the generalized force on
        the outputs per unit drive torque (its null space only produces internal force)."""
        return self.robot.velocity_map(self.q)[0].T @ self.robot.drive_selection

    def _saturate(self, u) -> np.ndarray:
        u = finite_vector("drive torques u", u, self.n_u)
        if self.torque_limit is None:
            return u
        clipped = np.clip(u, -self.torque_limit, self.torque_limit)
        if np.any(clipped != u):
            self.saturated += 1
        return clipped

    def _check_finite(self, state, u: np.ndarray) -> None:
        """Refuse a state that became NaN/inf within one sample, naming the inputs that drove it."""
        if not all(all_finite(x) for x in state):
            raise NonFiniteError(
                f"the plant diverged within one sample Ts = {self.Ts:g} s (its state is no longer finite) under drive "
                f"torques u = {u.tolist()} N·m and platform_force = {self.platform_force.tolist()}; likely causes: "
                "forces or torques too large for Ts, or a singular closed chain (dependent closures at this "
                "configuration, or moving bodies without mass or inertia whose closed chain has none either)")


class ConstrainedPlant(_PlantBase):
    """Full constrained multibody model integrated with ``pin.constraintDynamics``.

    Args:
        robot: the plant's robot (may differ from the controller's: mass scale, gravity).
        X0: (2 n_y,) initial state [y, ẏ].
        Ts: sample time in s (> 0): each :meth:`step` advances one sample.
        substeps: RK4 steps per sample.
        baumgarte: (Kp in 1/s², Kd in 1/s) closure stabilization gains.
        torque_limit: drive saturation (N·m): a number > 0, (n_u,) values > 0, a
            :class:`~parallel_gpc.limits.Limits` (its torque limit), or None.
        platform_force: (n_y,) constant external generalized force on the platform coordinates
            (N, N, N·m), e.g. a disturbance.
        native: integrate each sample with the compiled core (``parallel_gpc._native.Plant``, the
            same RK4 of the same ``constraintDynamics`` in one call): None uses it when it is
            available (:func:`~parallel_gpc.model.native.native_module`), False never (the
            Python reference), True requires it. With the compiled integrator, the projection
            onto the closures is the compiled model update's (``ModelUpdate.project``, the same
            warm Newton) when the core has it, the robot's (Python) otherwise and in every
            unusual case.

    Attributes:
        compiled: the compiled integrator, or None on the Python path.
        projector: the compiled projection (a ``_native.ModelUpdate`` of the robot), or None.
    """

    def __init__(self, robot: ParallelRobot, X0, *, Ts: float, substeps: int = 2, baumgarte=(100.0, 20.0),
                 torque_limit=None, platform_force=None, native: bool | None = None):
        super().__init__(robot, Ts, torque_limit, platform_force)
        model = robot.model
        self.data = model.createData()
        self.substeps = int(substeps)
        self.cms = pin.StdVec_RigidConstraintModel()
        params = pin.BaumgarteCorrectorParameters(float(baumgarte[0]), float(baumgarte[1]))
        for fa, fb, c in robot.closure_frames:
            Fa, Fb = model.frames[fa], model.frames[fb]
            cm = pin.RigidConstraintModel(_CONTACT[c.kind], model, Fa.parentJoint, Fa.placement,
                                          Fb.parentJoint, Fb.placement, pin.ReferenceFrame.LOCAL)
            cm.setBaumgarteCorrectorParameters(params)
            self.cms.append(cm)
        self.cds = pin.StdVec_RigidConstraintData()
        for cm in self.cms:
            self.cds.append(cm.createData())
        pin.initConstraintDynamics(model, self.data, self.cms, self.cds)
        self.prox = pin.ProximalSettings(*_PROXIMAL)
        X0 = finite_vector("X0", X0, 2 * self.n_y)
        self.q = robot.assemble(X0[: self.n_y])
        #: the KKT solver of a robot whose open-tree mass matrix is singular (massless moving bodies), or None
        self.kkt = SingularMassKKT(robot, self.cms, self.q, self.prox) if singular_mass_matrix(robot, self.q) \
            else None
        if self.kkt is not None and native:
            raise InvalidParameterError("native=True: the compiled plant integrates pin.constraintDynamics, which "
                                        "needs a positive definite open-tree mass matrix; this robot's is singular "
                                        "(massless moving bodies): use native=None or False (the Python KKT solve)")
        self.compiled = None if self.kkt is not None else compiled_plant(robot, baumgarte, _PROXIMAL, native)
        self._forces = self.cds  # where constraint_forces() reads: the last dynamics call's
        self._T, self._pinv = robot.velocity_map_nocopy(self.q)  # K⁺: the next projection's preconditioner
        self.v = self._T @ X0[self.n_y:]
        self._S = robot.drive_selection
        self.projector = None
        if self.compiled is not None and use_native(None):
            self.projector = compiled_model_update(robot)

    @property
    def X(self) -> np.ndarray:
        """(2 n_y,) current state [y, ẏ]."""
        r = self.robot
        return np.concatenate([r.platform_pose(self.q), r.output_velocity(self.q, self.v)])

    def accelerations(self, q, v, u) -> np.ndarray:
        """(nv,) q̈ from ``pin.constraintDynamics`` for drive torques u (N·m)."""
        tau = self._S @ u
        if self.robot.task_output is None:
            tau[self.robot.y_idx] += self.platform_force
        elif np.any(self.platform_force):  # a force f on y acts as Hᵀ f (H T = I)
            tau += self.robot.output_jacobian(q).T @ self.platform_force
        self._forces = self.cds
        if self.kkt is not None:
            self._forces = self.kkt
            return self.kkt.accelerations(q, v, tau)
        return pin.constraintDynamics(self.robot.model, self.data, q, v, tau, self.cms, self.cds, self.prox)

    def constraint_forces(self) -> np.ndarray:
        """(3 k,) linear closure forces (N) of the last dynamics call, stacked (k closures)."""
        if self._forces is None:
            return self.compiled.contact_forces()
        if self._forces is self.kkt:
            return self.kkt.forces.copy()
        return np.concatenate([np.asarray(cd.contact_force.linear) for cd in self.cds])

    def step(self, u) -> np.ndarray:
        """Advance one sample Ts with the drive torques u (N·m) held; returns the new state X."""
        u, Ts = self._saturate(u), self.Ts
        if self.compiled is None:
            q, v = self.q, self.v
            h = Ts / self.substeps
            for _ in range(self.substeps):
                q, v = self._rk4(q, v, u, h)
            self._forces = self.cds if self.kkt is None else self.kkt
        else:
            q, v = self._compiled_sample(u, Ts)
        self._check_finite((q, v), u)
        self._project(q, v)
        return self.X

    def _compiled_sample(self, u: np.ndarray, Ts: float):
        """(q, v) after one sample by the compiled RK4 (the same arithmetic as :meth:`_rk4`)."""
        tau = self._S @ u
        f_task = _NO_FORCE
        if self.robot.task_output is None:
            tau[self.robot.y_idx] += self.platform_force
        elif np.any(self.platform_force):  # H(q)ᵀ f at every stage, in C++
            f_task = self.platform_force
        self._forces = None
        return self.compiled.integrate(self.q, self.v, tau, f_task, Ts, self.substeps)

    def _rk4(self, q, v, u, h):
        """One classical RK4 step of (q̇, v̇) = (v, q̈) on the configuration manifold (q ⊕ h v)."""
        r = self.robot
        a1 = self.accelerations(q, v, u)
        v2 = v + 0.5 * h * a1
        a2 = self.accelerations(r.integrate(q, 0.5 * h * v), v2, u)
        v3 = v + 0.5 * h * a2
        a3 = self.accelerations(r.integrate(q, 0.5 * h * v2), v3, u)
        v4 = v + h * a3
        a4 = self.accelerations(r.integrate(q, h * v3), v4, u)
        q_next = r.integrate(q, (h / 6.0) * (v + 2 * v2 + 2 * v3 + v4))
        return q_next, v + (h / 6.0) * (a1 + 2 * a2 + 2 * a3 + a4)

    def _project(self, q, v) -> None:
        """Project (q, v) onto Φ(q) = 0 and Φ_q v = 0 keeping the platform coordinates.

        Newton from q (warm: its first step preconditioned by K⁺ of the previous projection) with
        the velocity map from its last Jacobian (in C++ when :attr:`projector` is set); the
        validated path (:meth:`ParallelRobot.assemble`) when that does not converge on the home
        branch, which also reports the errors.
        """
        if self.projector is not None:
            out = self.projector.project(q, v, self._pinv)
            if out is not None:
                self.q, self.v, self._T, self._pinv = out
                return
        r = self.robot
        ydot = r.output_velocity(q, v)
        pose = r.platform_pose(q)
        out = None if self.projector is not None else r.assemble_warm(pose, q, self._pinv)
        if out is None:
            self.q = r.assemble(pose, q)
            self._T, self._pinv = r.velocity_map_nocopy(self.q)
        else:
            self.q, self._T, self._pinv = out
        self.v = self._T @ ydot

    def input_matrix(self) -> np.ndarray:
        """(n_y, n_u) B_r = Tᵀ Sᵀ at the current configuration (T kept from the projection)."""
        return self._T.T @ self._S


class ReducedPlant(_PlantBase):
    """Reduced ODE ``ÿ = f + g u`` integrated with RK4 sub-steps (positions stay assembled).

    Args: as :class:`ConstrainedPlant` (no Baumgarte gains: the reduced model has no drift).
    """

    def __init__(self, robot: ParallelRobot, X0, *, Ts: float, substeps: int = 2, torque_limit=None,
                 platform_force=None):
        super().__init__(robot, Ts, torque_limit, platform_force)
        self.model = ReducedModel(robot)
        self.substeps = int(substeps)
        self._X = finite_vector("X0", X0, 2 * self.n_y).copy()
        self.model.assemble(self._X[: self.n_y])

    @property
    def X(self) -> np.ndarray:
        return self._X.copy()

    @property
    def q(self) -> np.ndarray:
        return self.model.assemble(self._X[: self.n_y])

    def derivative(self, X, u) -> np.ndarray:
        terms = self.model.terms(X)
        ydd = np.linalg.solve(terms.M_r, terms.B_r @ u + self.platform_force - terms.h_r)
        return np.concatenate([X[self.n_y:], ydd])

    def step(self, u) -> np.ndarray:
        """Advance one sample Ts with the drive torques u (N·m) held; returns the new state X."""
        u = self._saturate(u)
        X = rk4_step(self.derivative, self._X, u, self.Ts, self.substeps)
        self._check_finite((X,), u)
        self._X = X
        return self.X
