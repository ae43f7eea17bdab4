"""Closure and output kinematics of a :class:`~parallel_gpc.model.robot.ParallelRobot`.

One kinematics pass gives the assembly rows Ψ(q) (closures Φ, then the task-space output
h(q)) and their Jacobian; the Jacobian derivatives give the acceleration offsets. Mixed into
``ParallelRobot``, whose constructor sets the index tables used here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from .description import CLOSURE_ROWS as _CLOSURE_ROWS

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


@dataclass
class ClosureKinematics:
    """Closure quantities at one configuration.

    Attributes:
        residual: (m,) Φ(q), position (m) and orientation (rad) mismatch of the closure frames.
        jacobian: (m, nv) Φ_q.
    """

    residual: np.ndarray
    jacobian: np.ndarray


class ClosureMixin:
    """Φ, Φ_q, Φ̇_q, γ and the output map y = h(q) of a closed-chain robot (see ParallelRobot)."""

    def integrate(self, q: np.ndarray, dv: np.ndarray) -> np.ndarray:
        """(nq,) configuration q ⊕ dv for a (nv,) velocity step (a new array)."""
        return q + dv if self._flat else pin.integrate(self.model, q, dv)

    def _step(self, q: np.ndarray, dz: np.ndarray) -> np.ndarray:
        """q moved by −dz along the dependent coordinates (in place when nq == nv)."""
        if self._flat:
            q[self.dependent_v] -= dz
            return q
        dv = np.zeros(self.model.nv)
        dv[self.dependent_v] = -dz
        return pin.integrate(self.model, q, dv)

    # ------------------------------------------------------------------ closures
    def _eval(self, q: np.ndarray, jacobian: bool = True):
        """Ψ(q) + [0; y] and (if ``jacobian``) ∂Ψ/∂v at q: one kinematics pass, all frames at once.

        For joint outputs these are Φ and Φ_q; task-space outputs append the rows h(q) and H.
        The last evaluation with the Jacobian is cached on q (the final Newton iterate is the
        configuration whose velocity map is asked for next). Callers must not modify them.
        """
        key = q.tobytes()
        cache = self._ck_cache
        if cache is not None and cache[0] == key:
            return cache[1], cache[2]
        model, data = self.model, self.data
        if jacobian:
            pin.computeJointJacobians(model, data, q)
        else:
            pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        oMf = data.oMf
        frames = self._frames_flat
        if not frames:  # no closure (the output alone fixes the configuration)
            res = np.zeros(0)
        elif self._point_only:
            P = np.array([oMf[f].translation for f in frames])
            res = (P[0::2] - P[1::2]).reshape(-1)
        else:
            res = np.empty(self.n_constraints)
            row = 0
            for fa, fb, c in self.closure_frames:
                oMa, oMb = oMf[fa], oMf[fb]
                res[row:row + 3] = oMa.translation - oMb.translation
                if c.kind == "weld":
                    res[row + 3:row + 6] = oMa.rotation @ pin.log3(oMa.rotation.T @ oMb.rotation) * -1.0
                row += _CLOSURE_ROWS[c.kind]
        task = self.task_output
        if task is not None:
            res = np.concatenate([res, task.value(data)])
        if not jacobian:
            return res, None
        if not frames:
            jac = np.zeros((0, model.nv))
        else:
            J = np.array([pin.getFrameJacobian(model, data, f, _LWA) for f in frames])
            if self._point_only:
                jac = (J[0::2, :3] - J[1::2, :3]).reshape(-1, model.nv)
            else:
                jac = (J[0::2] - J[1::2]).reshape(-1, model.nv)[self._jac_rows]
        if task is not None:
            jac = np.vstack([jac, task.jacobian(model, data)])
        self._ck_cache = (key, res, jac)
        return res, jac

    def _error(self, res: np.ndarray, pose) -> np.ndarray:
        """Ψ(q) from :meth:`_eval`'s rows: the output rows minus the target pose (task space)."""
        if self.task_output is None:
            return res
        if pose is None:  # closures only
            return res[:self.n_constraints]
        target = self._target
        target[self.n_constraints:] = pose
        return res - target

    def closure_log_error(self, q: np.ndarray) -> ClosureKinematics:
        """Closure mismatch with weld rows e = log₃(R_aᵀ R_b) and their exact Jacobian
        J_log₃(R_aᵀ R_b) R_bᵀ (J_b − J_a): Newton on these converges from far (a weld drawn
        turned by up to π), unlike the hot path's rows (:meth:`closure_kinematics`), whose
        Jacobian is exact at assembly only. Position rows as there.

        Returns:
            residual (m,) in m and rad, jacobian (m, nv).
        """
        model, data = self.model, self.data
        pin.computeJointJacobians(model, data, np.asarray(q, dtype=float))
        pin.updateFramePlacements(model, data)
        res, jac = [], []
        for fa, fb, c in self.closure_frames:
            oMa, oMb = data.oMf[fa], data.oMf[fb]
            J = pin.getFrameJacobian(model, data, fa, _LWA) - pin.getFrameJacobian(model, data, fb, _LWA)
            res.append(oMa.translation - oMb.translation)
            jac.append(J[:3])
            if c.kind == "weld":
                R = oMa.rotation.T @ oMb.rotation
                res.append(pin.log3(R))
                jac.append(-pin.Jlog3(R) @ oMb.rotation.T @ J[3:])
        return ClosureKinematics(np.concatenate(res), np.vstack(jac))

    def closure_kinematics(self, q: np.ndarray) -> ClosureKinematics:
        """Φ(q) and Φ_q at configuration q (updates ``self.data`` unless q was just evaluated)."""
        res, jac = self._eval(np.asarray(q, dtype=float))
        m = self.n_constraints
        return ClosureKinematics(res[:m].copy(), jac[:m].copy())

    def closure_jacobian_derivative(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(m, nv) Φ̇_q = dΦ_q/dt at (q, q̇ = v); the closure acceleration bias is γ = Φ̇_q v.

        Φ̇_q is linear in v. Updates ``self.data``.
        """
        model, data = self.model, self.data
        pin.computeJointJacobiansTimeVariation(model, data, q, v)
        universal = self.universal_joints
        if universal:  # Pinocchio's J̇ has a spurious term for universal joints (see model.universal)
            pin.updateFramePlacements(model, data)
        if not self._frames_flat:
            return np.zeros((0, model.nv))
        if universal:
            dJ = np.array([universal.frame_jacobian_rate(model, data, f, v) for f in self._frames_flat])
        else:
            dJ = np.array([pin.getFrameJacobianTimeVariation(model, data, f, _LWA) for f in self._frames_flat])
        if self._point_only:
            return (dJ[0::2, :3] - dJ[1::2, :3]).reshape(-1, model.nv)
        return (dJ[0::2] - dJ[1::2]).reshape(-1, model.nv)[self._jac_rows]

    def constraint_jacobian_derivative(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Ψ̇_q at (q, v): the assembly rows' Jacobian derivative, closures then (task-space) outputs.

        The acceleration offset of the reduced model is ℓ_z = −K⁺ Ψ̇_q v (linear in v). Updates
        ``self.data``. For joint outputs the constructor binds this name to
        :meth:`closure_jacobian_derivative` (one call less in the control step).
        """
        dPhi = self.closure_jacobian_derivative(q, v)
        if self.task_output is None:
            return dPhi
        return np.vstack([dPhi, self.task_output.jacobian_derivative(self.model, self.data, v, self.universal_joints)])

    def closure_residual(self, q: np.ndarray) -> np.ndarray:
        """(m,) Φ(q): closure mismatch in m (and rad for welds)."""
        return self.closure_kinematics(q).residual

    def closure_acceleration_bias(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(m,) γ = Φ̇_q q̇, the closure acceleration at zero q̈ (m/s², rad/s²)."""
        model, data = self.model, self.data
        pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
        gamma = np.empty(self.n_constraints)
        row = 0
        for fa, fb, c in self.closure_frames:
            aa = pin.getFrameClassicalAcceleration(model, data, fa, _LWA)
            ab = pin.getFrameClassicalAcceleration(model, data, fb, _LWA)
            gamma[row:row + 3] = aa.linear - ab.linear
            if c.kind == "weld":
                gamma[row + 3:row + 6] = aa.angular - ab.angular
            row += _CLOSURE_ROWS[c.kind]
        return gamma

    # ------------------------------------------------------------------ outputs
    def platform_pose(self, q: np.ndarray) -> np.ndarray:
        """(n_y,) output y of configuration q (m, rad)."""
        q = np.asarray(q, dtype=float)
        if self.task_output is None:
            return q[self._y_q].copy()
        pin.framesForwardKinematics(self.model, self.data, q)
        return self.task_output.value(self.data).copy()

    def output_jacobian(self, q: np.ndarray) -> np.ndarray:
        """(n_y, nv) H = ∂y/∂v at q (ẏ = H v; a generalized force f on y acts as Hᵀ f)."""
        if self.task_output is None:
            H = np.zeros((self.n_y, self.model.nv))
            H[np.arange(self.n_y), self.y_idx] = 1.0
            return H
        pin.computeJointJacobians(self.model, self.data, np.asarray(q, dtype=float))
        pin.updateFramePlacements(self.model, self.data)
        return self.task_output.jacobian(self.model, self.data)

    def output_velocity(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(n_y,) ẏ = H v (m/s, rad/s)."""
        if self.task_output is None:
            return np.asarray(v, dtype=float)[self.y_idx].copy()
        return self.output_jacobian(q) @ v

    def platform_placement(self, q: np.ndarray) -> pin.SE3:
        """World placement of the output frame at q."""
        pin.framesForwardKinematics(self.model, self.data, q)
        return self.data.oMf[self.output_frame_id].copy()
