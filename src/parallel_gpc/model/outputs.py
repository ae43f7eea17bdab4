"""Task-space output y = h(q): position and orientation of a named frame.

The position is the frame origin in world coordinates (m). The orientation is the rotation
vector θ = log₃(R_refᵀ R) of the frame's rotation R relative to its home orientation R_ref
(rad): zero at home, no gimbal lock for rotations below π from home, isotropic (the same
accuracy about every axis, unlike roll-pitch-yaw), and Pinocchio gives its derivatives exactly
(``Jlog3``, ``Hlog3``). The output keeps a subset of the six axes (x, y, z, rx, ry, rz), e.g.
(x, z) for a planar 5-bar moving in the x-z plane.

Derivatives (ω_loc = frame angular velocity in the frame, J = frame Jacobian LOCAL_WORLD_ALIGNED):

* ṗ = J_lin v, p̈ = J_lin q̈ + J̇_lin v;
* θ̇ = Jlog₃(R_rel) Rᵀ J_ang v, so H_ang = Jlog₃ Rᵀ J_ang and
  Ḣ_ang = Hlog₃(R_rel, ω_loc) Rᵀ J_ang + Jlog₃ (Rᵀ J̇_ang − [ω_loc]× Rᵀ J_ang).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from .description import POSE_AXES
from .universal import UniversalJoints

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
#: below this rotation angle (rad) :func:`hlog3` uses its series (``pin.Hlog3`` is NaN at 0 and
#: loses digits by cancellation below ~0.01 rad).
_HLOG3_SERIES_BELOW = 0.05


def hlog3(R: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(3, 3) d/dt Jlog₃(R) for the angular velocity ``w`` (rad/s, in the rotated frame).

    ``pin.Hlog3(R, w)`` away from the identity; near it the derivative of the series
    Jlog₃ = I + ½[θ]× + [θ]×²/12 − [θ]×⁴/720 + O(θ⁶) along θ̇ = Jlog₃ w (error below 1e-10·|w|
    at 0.05 rad).
    """
    theta = pin.log3(R)
    if theta @ theta >= _HLOG3_SERIES_BELOW ** 2:
        return pin.Hlog3(R, w)
    S, Sd = pin.skew(theta), pin.skew(pin.Jlog3(R) @ w)
    S2 = S @ S
    d4 = Sd @ S2 @ S + S @ Sd @ S2 + S2 @ Sd @ S + S2 @ S @ Sd
    return 0.5 * Sd + (Sd @ S + S @ Sd) / 12.0 - d4 / 720.0


class TaskOutput:
    """y = rows ``axes`` of [p; log₃(R_refᵀ R)] of frame ``frame_id``.

    Args:
        frame_id: Pinocchio frame index.
        axes: subset of ``("x", "y", "z", "rx", "ry", "rz")``.

    Attributes:
        rows: (n_y,) indices of the kept axes in [x, y, z, rx, ry, rz].
        is_angle: (n_y,) True for rotation-vector components (rad).
        R_ref: (3, 3) home orientation (set by :meth:`set_reference`).
    """

    def __init__(self, frame_id: int, axes: tuple[str, ...]):
        self.frame_id = int(frame_id)
        self.rows = np.array([POSE_AXES.index(a) for a in axes], dtype=int)
        self.is_angle = self.rows >= 3
        self.has_rotation = bool(self.is_angle.any())
        self._lin = self.rows[~self.is_angle]
        self._ang = self.rows[self.is_angle] - 3
        self.R_ref = np.eye(3)

    def set_reference(self, data: pin.Data) -> None:
        """Take the frame's current orientation (placements up to date) as R_ref."""
        self.R_ref = np.array(data.oMf[self.frame_id].rotation)

    def value(self, data: pin.Data) -> np.ndarray:
        """(n_y,) y at the configuration whose frame placements are in ``data`` (m, rad)."""
        oMf = data.oMf[self.frame_id]
        if not self.has_rotation:
            return oMf.translation[self._lin]
        theta = pin.log3(self.R_ref.T @ oMf.rotation)
        return np.concatenate([oMf.translation[self._lin], theta[self._ang]])

    def jacobian(self, model: pin.Model, data: pin.Data) -> np.ndarray:
        """(n_y, nv) H = ∂y/∂v (joint Jacobians in ``data`` up to date)."""
        J = pin.getFrameJacobian(model, data, self.frame_id, _LWA)
        if not self.has_rotation:
            return J[self._lin]
        R = data.oMf[self.frame_id].rotation
        Jl = pin.Jlog3(self.R_ref.T @ R)
        return np.vstack([J[self._lin], (Jl @ (R.T @ J[3:]))[self._ang]])

    def jacobian_derivative(self, model: pin.Model, data: pin.Data, v: np.ndarray,
                            universal: UniversalJoints | None = None) -> np.ndarray:
        """(n_y, nv) Ḣ at (q, v) (``computeJointJacobiansTimeVariation(q, v)`` and the frame
        placements done); ``universal`` corrects the frame's J̇ for the model's universal joints."""
        if universal:
            dJ = universal.frame_jacobian_rate(model, data, self.frame_id, v)
        else:
            dJ = pin.getFrameJacobianTimeVariation(model, data, self.frame_id, _LWA)
        if not self.has_rotation:
            return dJ[self._lin]
        J = pin.getFrameJacobian(model, data, self.frame_id, _LWA)
        R = data.oMf[self.frame_id].rotation
        R_rel = self.R_ref.T @ R
        Jang_loc = R.T @ J[3:]
        w = Jang_loc @ v
        dJang_loc = R.T @ dJ[3:] - pin.skew(w) @ Jang_loc
        dH = hlog3(R_rel, w) @ Jang_loc + pin.Jlog3(R_rel) @ dJang_loc
        return np.vstack([dJ[self._lin], dH[self._ang]])
