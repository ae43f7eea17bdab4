"""Closed-chain robot: model file + loop closures + output coordinates.

The robot file is read by :mod:`parallel_gpc.model.description` and built by
:mod:`parallel_gpc.model.builder`; this module assembles the closures and gives the closure
kinematics and the velocity map in the output coordinates y.

Coordinates. The output y is either joint coordinates (1-DOF joints) or the position (and
orientation) of a named frame (:mod:`parallel_gpc.model.outputs`). Assembly solves the
*assembly equations* Ψ(q) = 0 for the dependent velocity coordinates z (``dependent_v``):

* joint outputs: Ψ = Φ (the closures), y fixed in q, z = the other coordinates of v;
* task-space outputs: Ψ = [Φ(q); h(q) − y], z = all of v.

Their Jacobian K = ∂Ψ/∂z gives the velocity map q̇ = T ẏ: joint outputs T = [I; −K⁺ Φ_y],
task-space outputs T = K⁺ [0; I] (rank-revealing SVD). With multi-DOF joints (spherical,
universal, free-flyer) nq ≠ nv: Newton steps and the warm-start predictor move q by
``pin.integrate``; T, K and all velocities live in v.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from ..errors import AssemblyError, InvalidParameterError, RobotFormatError, SingularPoseError, UnreachablePoseError
from ..validation import finite_vector
from .builder import build_model
from .checks import check_actuation, check_parametrization
from .description import (  # noqa: F401  (re-exported for the robot's users)
    CLOSURE_ROWS as _CLOSURE_ROWS,
    DEFAULT_ROBOT,
    Closure,
    RobotDescription,
    embedded_robots,
    load_description,
    urdf_dir,
)
from .linalg import fast_index, svd_thin
from .outputs import TaskOutput

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
#: K smallest/largest singular value below which the legs count as singular.
SINGULAR_RCOND = 1e-8
#: relative singular-value cut of the rank-revealing Newton step (as ``lstsq(rcond=1e-10)``).
_NEWTON_RCOND = 1e-10


@dataclass
class ClosureKinematics:
    """Closure quantities at one configuration.

    Attributes:
        residual: (m,) Φ(q), position (m) and orientation (rad) mismatch of the closure frames.
        jacobian: (m, nv) Φ_q.
    """

    residual: np.ndarray
    jacobian: np.ndarray


class ParallelRobot:
    """A parallel robot: Pinocchio model of the open tree, its loop closures and its output y.

    Args:
        description: what the robot file says.
        mass_scale: multiplies every body's mass and inertia (model mismatch studies).
        gravity: (3,) gravity vector in m/s² (default: Pinocchio's, -9.81 along z).

    Attributes:
        model: the ``pinocchio.Model`` of the open tree (immutable description).
        data: a ``pinocchio.Data`` workspace owned by this object.
        n_y: number of output coordinates (platform DOF).
        n_u: number of drives.
        n_z: number of dependent velocity coordinates (nv − n_y for joint outputs, nv else).
        y_idx: indices in v of the output joints (empty for task-space outputs).
        z_idx: indices in v of the dependent coordinates; ``dependent_v`` is the same as a
            slice when possible (hot paths).
        drive_idx: indices in v of the drives (S = selection of these rows); ``drive_v`` ditto.
        closure_frames: [(frame a id, frame b id, Closure)] of every closure.
        task_output: the :class:`TaskOutput` map, or None for joint outputs.
        bias_symmetric: True when Φ̇_q(a) b = Φ̇_q(b) a for the assembly rows (point closures,
            position outputs, nq == nv: the rows are gradients of positions).
        redundancy: number of drives beyond the rank of the actuation map B_r at home (0: not
            redundant).
        q_home: assembled home configuration.
    """

    def __init__(self, description: RobotDescription, mass_scale: float = 1.0, gravity=None):
        model, closures = build_model(description)
        self.description = dataclasses.replace(description, closures=closures)
        if not (mass_scale > 0 and math.isfinite(mass_scale)):
            raise InvalidParameterError(f"mass_scale = {mass_scale!r} must be finite and > 0")
        for j in range(1, model.njoints):
            inertia = model.inertias[j]
            model.inertias[j] = pin.Inertia(inertia.mass * mass_scale, inertia.lever, inertia.inertia * mass_scale)
        if gravity is not None:
            model.gravity.linear = finite_vector("gravity", gravity, 3)
        self.model = model
        self.data = model.createData()
        self.mass_scale = float(mass_scale)
        self.redundancy = 0
        self._flat = model.nq == model.nv
        self.drive_idx = np.array([self._joint_index(n, "drive")[1] for n in description.drive_joints], dtype=int)
        self._drive_q = np.array([self._joint_index(n, "drive")[0] for n in description.drive_joints], dtype=int)
        self.closure_frames = [(self._frame_id(c.frames[0], c), self._frame_id(c.frames[1], c), c) for c in closures]
        self.n_constraints = sum(_CLOSURE_ROWS[c.kind] for c in closures)
        self.output_frame_id = self._frame_id(description.output_frame, None) if description.output_frame else None
        self._setup_outputs(description)
        self._setup_fast_paths()
        if self.n_constraints + (self.n_y if self.task_output else 0) < self.n_z:
            raise RobotFormatError(
                f"{len(closures)} closures give {self.n_constraints} constraint rows, fewer than "
                f"the {self.n_z} dependent coordinates: the legs are not determined by the platform pose"
            )
        self.torque_limit = np.array(description.torque_limit) if description.torque_limit is not None else None
        self._branch_q = np.array([self._joint_index(n, "branch joint")[0] for n in description.branch_joints],
                                  dtype=int)
        self._bs = fast_index(self._branch_q)
        self._branch = None
        self._home(description)
        self._branch = self.branch_signature(self.q_home)
        check_parametrization(self)
        self.redundancy = check_actuation(self)

    # ------------------------------------------------------------------ construction
    def _setup_outputs(self, description: RobotDescription) -> None:
        nv = self.model.nv
        if description.output_kind == "joints":
            idx = [self._joint_index(n, "output joint") for n in description.output_joints]
            self.y_idx = np.array([i[1] for i in idx], dtype=int)
            self._y_q = fast_index(np.array([i[0] for i in idx], dtype=int))
            self.z_idx = np.array([i for i in range(nv) if i not in set(self.y_idx.tolist())], dtype=int)
            self.task_output = None
            kinds = [self.model.joints[self.model.getJointId(n)].shortname() for n in description.output_joints]
            self._is_angle = np.array(["JointModelP" not in k for k in kinds])
        else:
            if self.output_frame_id is None:  # pragma: no cover - the description guarantees a frame
                raise RobotFormatError("a task-space output needs an output frame")
            self.task_output = TaskOutput(self.output_frame_id, description.output_axes)
            self.y_idx = np.zeros(0, dtype=int)
            self.z_idx = np.arange(nv)
            self._is_angle = self.task_output.is_angle
        self.n_y = description.n_y
        self.n_u = len(self.drive_idx)
        self.n_z = len(self.z_idx)

    def _setup_fast_paths(self) -> None:
        """Index tables and caches of the hot paths (closure evaluation, velocity map)."""
        self._frames_flat = [f for fa, fb, _ in self.closure_frames for f in (fa, fb)]
        self._point_only = all(c.kind == "point" for _, _, c in self.closure_frames)
        rotation_out = self.task_output is not None and self.task_output.has_rotation
        self.bias_symmetric = self._point_only and self._flat and not rotation_out
        rows = [6 * k + i for k, (_, _, c) in enumerate(self.closure_frames) for i in range(_CLOSURE_ROWS[c.kind])]
        self._jac_rows = np.array(rows, dtype=int)  # rows of the stacked 6-D frame differences kept
        self._ys = fast_index(self.y_idx)
        self.dependent_v = fast_index(self.z_idx)
        self.drive_v = fast_index(self.drive_idx)
        self._T0 = np.zeros((self.model.nv, self.n_y))
        self._T0[self.y_idx, np.arange(len(self.y_idx))] = 1.0
        self._target = np.zeros(self.n_constraints + (self.n_y if self.task_output else 0))
        self._ck_cache = None  # (q, residual, jacobian) of the last Jacobian evaluation
        self._vm_cache = None  # (q, T, pinv_z) of the last velocity map

    def _home(self, description: RobotDescription) -> None:
        """Assemble the home configuration ``q_home`` at ``home_pose``."""
        q0 = pin.neutral(self.model)
        for name, value in description.q_guess.items():
            if description.joint_types.get(name) == "FIXED":
                continue  # locked at this value by the builder
            iq, _ = self._joint_index(name, "q_guess joint", nq=len(value) if isinstance(value, tuple) else 1)
            q0[iq:iq + (len(value) if isinstance(value, tuple) else 1)] = value
        if self.task_output is not None:  # the closures alone first: the output's reference is there
            try:
                q0 = self._newton(None, q0)
            except UnreachablePoseError as exc:
                raise AssemblyError(self._assembly_failure(q0, exc, None)) from None
            pin.framesForwardKinematics(self.model, self.data, q0)
            self.task_output.set_reference(self.data)
            home = description.home_pose if description.home_pose is not None else self.task_output.value(self.data)
        else:
            home = description.home_pose if description.home_pose is not None else q0[self._y_q].copy()
            q0[self._y_q] = finite_vector("home pose", home, self.n_y)
        self.home_pose = finite_vector("home pose", home, self.n_y)
        try:
            self.q_home = self._newton(self.home_pose, q0)
        except UnreachablePoseError as exc:
            raise AssemblyError(self._assembly_failure(q0, exc, self.home_pose)) from None

    def _assembly_failure(self, q0: np.ndarray, exc: Exception, pose) -> str:
        """Message for closures that cannot be assembled at the home pose: the worst closures."""
        q = q0.copy()
        for _ in range(30):  # least-squares Newton: where the closures get closest
            res, jac = self._eval(q)
            err = self._error(res, pose)
            q = self._step(q, np.linalg.lstsq(jac[:len(err), self.z_idx], err, rcond=1e-10)[0])
        res = self.closure_residual(q)
        parts, row = [], 0
        for _, _, c in self.closure_frames:
            rows = _CLOSURE_ROWS[c.kind]
            parts.append((float(np.linalg.norm(res[row:row + rows])), c))
            row += rows
        bad = [f"{c.name!r} {list(c.frames)} misses by {r:.3g} m" for r, c in sorted(parts, key=lambda t: -t[0])
               if r > 1e-9]
        where = "" if pose is None else f" at the home pose {np.round(pose, 6).tolist()}"
        return (f"the closures of {self.name!r} cannot be assembled{where}: {'; '.join(bad) or str(exc)} "
                f"(check the closure frames, home.pose and home.q_guess in the sidecar)")

    @classmethod
    def load(cls, name_or_path: str | Path = DEFAULT_ROBOT, sidecar: str | Path | None = None,
             **kwargs) -> "ParallelRobot":
        """Load an embedded robot by name or a robot file by path (URDF/MJCF or sidecar).

        Args:
            name_or_path: embedded robot name, or path of a model file or sidecar.
            sidecar: explicit sidecar path (default: found next to the model file by stem).
            **kwargs: ``mass_scale``, ``gravity``.
        """
        return cls(load_description(name_or_path, sidecar), **kwargs)

    def with_mass_scale(self, mass_scale: float) -> "ParallelRobot":
        """A copy whose body masses and inertias are scaled by ``mass_scale`` (plant mismatch)."""
        return ParallelRobot(self.description, mass_scale=mass_scale * self.mass_scale,
                             gravity=np.array(self.model.gravity.linear))

    def _joint_index(self, name: str, role: str, nq: int = 1) -> tuple[int, int]:
        """(idx_q, idx_v) of joint ``name``, which must have ``nq`` configuration coordinates."""
        if not self.model.existJointName(name):
            joints = list(self.model.names)[1:]
            raise RobotFormatError(f"{role} {name!r} is not a joint of the model; joints are {joints}")
        jm = self.model.joints[self.model.getJointId(name)]
        if jm.nq != nq or (nq == 1 and jm.nv != 1):
            raise RobotFormatError(f"{role} {name!r} is a {jm.shortname()} with nq = {jm.nq}, nv = {jm.nv}; "
                                   f"expected {'a 1-DOF revolute or prismatic joint' if nq == 1 else f'nq = {nq}'}")
        return int(jm.idx_q), int(jm.idx_v)

    def _frame_id(self, name: str, closure: Closure | None) -> int:
        if not self.model.existFrame(name):
            role = f"closure {closure.name!r} names frame" if closure else "output frame"
            raise RobotFormatError(f"{role} {name!r}, which is not in the model "
                                   f"(frames: {[f.name for f in self.model.frames][1:]})")
        return int(self.model.getFrameId(name))

    @property
    def name(self) -> str:
        return self.description.name

    @property
    def drive_selection(self) -> np.ndarray:
        """(nv, n_u) Sᵀ: maps drive torques (N·m) to generalized forces."""
        S = np.zeros((self.model.nv, self.n_u))
        S[self.drive_idx, np.arange(self.n_u)] = 1.0
        return S

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
        P = np.array([oMf[f].translation for f in frames]).reshape(-1, 3)
        if self._point_only:
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
        J = np.array([pin.getFrameJacobian(model, data, f, _LWA) for f in frames]).reshape(-1, 6, model.nv)
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

    def closure_kinematics(self, q: np.ndarray) -> ClosureKinematics:
        """Φ(q) and Φ_q at configuration q (updates ``self.data`` unless q was just evaluated)."""
        res, jac = self._eval(np.asarray(q, dtype=float))
        m = self.n_constraints
        return ClosureKinematics(res[:m].copy(), jac[:m].copy())

    def closure_jacobian_derivative(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(m, nv) Φ̇_q = dΦ_q/dt at (q, q̇ = v); the closure acceleration bias is γ = Φ̇_q v.

        Φ̇_q is linear in v. Updates ``self.data``.
        """
        pin.computeJointJacobiansTimeVariation(self.model, self.data, q, v)
        return self._closure_dJ()

    def _closure_dJ(self) -> np.ndarray:
        model, data = self.model, self.data
        dJ = np.array([pin.getFrameJacobianTimeVariation(model, data, f, _LWA)
                       for f in self._frames_flat]).reshape(-1, 6, model.nv)
        if self._point_only:
            return (dJ[0::2, :3] - dJ[1::2, :3]).reshape(-1, model.nv)
        return (dJ[0::2] - dJ[1::2]).reshape(-1, model.nv)[self._jac_rows]

    def constraint_jacobian_derivative(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Ψ̇_q at (q, v): the assembly rows' Jacobian derivative, closures then (task-space) outputs.

        The acceleration offset of the reduced model is ℓ_z = −K⁺ Ψ̇_q v (linear in v). Updates
        ``self.data``.
        """
        pin.computeJointJacobiansTimeVariation(self.model, self.data, q, v)
        dPhi = self._closure_dJ()
        if self.task_output is None:
            return dPhi
        return np.vstack([dPhi, self.task_output.jacobian_derivative(self.model, self.data, v)])

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

    # ------------------------------------------------------------------ assembly
    def branch_signature(self, q: np.ndarray) -> np.ndarray:
        """Signs of sin(q) of the branch joints (the elbow configuration)."""
        return np.sign(np.sin(np.asarray(q)[self._branch_q]))

    def _lstsq_z(self, jac: np.ndarray, res: np.ndarray) -> np.ndarray:
        """Minimum-norm least-squares δz with K δz ≈ res (SVD, singular values below
        ``1e-10·s_max`` dropped: the same step as ``numpy.linalg.lstsq(rcond=1e-10)``)."""
        U, s, Vt = svd_thin(jac[:, self.dependent_v])
        r = int(np.count_nonzero(s > _NEWTON_RCOND * s[0])) if s[0] > 0 else 0
        if r == s.shape[0]:
            return Vt.T @ ((U.T @ res) / s)
        return Vt[:r].T @ ((U[:, :r].T @ res) / s[:r])

    def _newton(self, pose, q_guess: np.ndarray, tol: float = 1e-12, max_iter: int = 30) -> np.ndarray:
        """Solve Ψ(q) = 0 with output ``pose`` (None: the closures only) from q_guess."""
        q = np.array(q_guess, dtype=float)
        if self.task_output is None:
            q[self._y_q] = pose
        label = "closures" if pose is None else f"platform pose {np.round(pose, 6).tolist()}"
        for _ in range(max_iter):
            res, jac = self._eval(q)
            err_vec = self._error(res, pose)
            err = np.abs(err_vec).max()
            if err <= tol:
                break
            if not err < 1e6:  # NaN/inf pose or a diverging iteration
                raise UnreachablePoseError(f"{label} cannot be assembled: closure residual {err:.3g}")
            q = self._step(q, self._lstsq_z(jac[:len(err_vec)], err_vec))
        else:
            err = np.max(np.abs(self._error(self._eval(q)[0], pose)))
            if err > 1e-9:
                raise UnreachablePoseError(
                    f"{label} cannot be assembled: residual {err:.3g} after {max_iter} Newton steps "
                    f"(outside the workspace of {self.name!r})"
                )
        return q

    def assemble_warm(self, pose: np.ndarray, q_guess: np.ndarray, pinv_hint: np.ndarray | None = None,
                      near: bool = False, tol: float = 1e-12, max_iter: int = 8):
        """Warm-started hot path of :meth:`assemble` + :meth:`velocity_map`: (q, T, K⁺) or None.

        Newton from ``q_guess`` (expected within a few steps of the solution), the branch check,
        and the velocity map at the converged q from the Jacobian of the last Newton
        evaluation (one kinematics pass less). ``pinv_hint`` (K⁺ at a nearby configuration)
        makes the first Newton step cheap: the least-squares step is solved by one step of
        iterative refinement preconditioned with it instead of an SVD (same step to second
        order in the distance; convergence is checked as always). Returns None when anything
        is unusual (no convergence in ``max_iter`` steps, another branch, a singular K): the
        caller then takes the validated path (:meth:`assemble`), which reports the error.
        ``near`` (the guess is within ~0.1 mm of an assembled configuration on the home branch)
        skips the branch check when no Newton step was needed: the elbows cannot cross their
        stretched/folded angle without a step.

        Args:
            pose: (n_y,) output y (m, rad).
            q_guess: (nq,) start configuration (not modified).
            pinv_hint: (n_z, rows) K⁺ at a nearby configuration, or None.

        Returns:
            (q (nq,), T (nv, n_y), K⁺ (n_z, rows)) — T and K⁺ must not be modified — or None.
        """
        q = np.array(q_guess, dtype=float)
        task = self.task_output is not None
        if not task:
            q[self._ys] = pose
        zs = self.dependent_v
        tol2 = tol * tol
        for it in range(max_iter):
            res, jac = self._eval(q)
            if task:
                res = self._error(res, pose)
            err2 = res @ res  # ‖Ψ‖₂ ≤ tol implies ‖Ψ‖∞ ≤ tol
            if err2 <= tol2:
                break
            if not err2 < 1e-4:
                return None
            if it == 0 and pinv_hint is not None:
                step = pinv_hint @ res
                step += pinv_hint @ (res - jac[:, zs] @ step)
                q = self._step(q, step)
            else:
                q = self._step(q, self._lstsq_z(jac, res))
        else:
            return None
        if self._branch_q.size and not (near and it == 0) and not (np.sin(q[self._bs]) * self._branch).min() > 0:
            return None
        out = self._map_from(jac)
        if out is None:
            return None
        self._vm_cache = (self._ck_cache[0], *out)
        return q, *out

    def _map_from(self, jac: np.ndarray):
        """(T, K⁺) from the assembly Jacobian, or None if K has rank < n_z."""
        U, s, Vt = svd_thin(jac[:, self.dependent_v])
        n_z = self.n_z
        if not s[n_z - 1] > SINGULAR_RCOND * s[0]:
            return None
        pinv_z = (Vt[:n_z].T / s[:n_z]) @ U[:, :n_z].T
        if self.task_output is None:
            T = self._T0.copy()
            T[self.dependent_v] = -(pinv_z @ jac[:, self._ys])
        else:
            T = np.ascontiguousarray(pinv_z[:, self.n_constraints:])
        return T, pinv_z

    def _on_branch(self, q: np.ndarray) -> bool:
        return bool(np.all(np.sin(q[self._branch_q]) * self._branch > 0)) if self._branch_q.size else True

    def assemble(self, pose, q_guess: np.ndarray | None = None) -> np.ndarray:
        """Full configuration q for an output y, on the home branch.

        Args:
            pose: (n_y,) output y (m, rad).
            q_guess: (nq,) warm start (e.g. the previous configuration); default: continuation
                from the home configuration.

        Returns:
            (nq,) q with ‖Ψ(q)‖∞ ≤ 1e-12 (1e-9 at worst): closures closed, output equal to ``pose``.

        Raises:
            UnreachablePoseError: if the pose cannot be assembled on the home branch.
        """
        pose = finite_vector("platform pose", pose, self.n_y)
        if q_guess is not None:
            try:
                q = self._newton(pose, q_guess)
                if self._on_branch(q):
                    return q
            except AssemblyError:
                pass
        return self._continuation(pose)

    def _continuation(self, pose: np.ndarray) -> np.ndarray:
        dist = np.abs(pose - self.home_pose)
        ang = self._is_angle
        steps = int(min(200, max(1, math.ceil(max(dist[~ang].max(initial=0) / 0.05, dist[ang].max(initial=0) / 0.1)))))
        q = self.q_home.copy()
        for s in range(1, steps + 1):
            mid = self.home_pose + (pose - self.home_pose) * s / steps
            try:
                q = self._newton(mid, q)
            except UnreachablePoseError as exc:
                raise UnreachablePoseError(
                    f"platform pose {np.round(pose, 6).tolist()} cannot be assembled on the home branch of "
                    f"{self.name!r}: continuation from home stops at {np.round(mid, 4).tolist()} "
                    f"({exc})"
                ) from None
        if not np.array_equal(self.branch_signature(q), self._branch):
            raise UnreachablePoseError(
                f"platform pose {np.round(pose, 6).tolist()} is reachable only on another assembly branch "
                f"(a leg passes through its singular stretched/folded configuration on the way)"
            )
        return q

    # ------------------------------------------------------------------ kinematics
    def inverse_kinematics(self, pose) -> np.ndarray:
        """(n_u,) drive coordinates (rad or m) that place the platform at ``pose``."""
        return self.assemble(pose)[self._drive_q].copy()

    def forward_kinematics(self, drives, q_guess: np.ndarray | None = None, tol: float = 1e-12,
                           max_iter: int = 50) -> np.ndarray:
        """(n_y,) output for drive coordinates (rad or m), by Newton from ``q_guess`` (home).

        With redundant drives the drive values must be consistent (e.g. from
        :meth:`inverse_kinematics`); the least-squares solution is returned otherwise.
        """
        drives = finite_vector("drive coordinates", drives, self.n_u)
        q = (self.q_home if q_guess is None else np.asarray(q_guess, dtype=float)).copy()
        q[self._drive_q] = drives
        free = np.array([i for i in range(self.model.nv) if i not in set(self.drive_idx.tolist())])
        for _ in range(max_iter):
            ck = self.closure_kinematics(q)
            if np.max(np.abs(ck.residual)) <= tol:
                return self.platform_pose(q)
            step, *_ = np.linalg.lstsq(ck.jacobian[:, free], ck.residual, rcond=1e-10)
            dv = np.zeros(self.model.nv)
            dv[free] = -step * min(1.0, 0.2 / max(np.max(np.abs(step)), 1e-300))  # damped: stay on branch
            q = self.integrate(q, dv)
        raise AssemblyError(
            f"forward kinematics did not converge for drives {np.round(drives, 6).tolist()}: "
            f"closure residual {np.max(np.abs(self.closure_residual(q))):.3g}"
        )

    def velocity_map(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """T (q̇ = T ẏ) and the rank-revealing pseudo-inverse K⁺ at q.

        K⁺ uses the n_z leading singular values of K (its zero rows, e.g. the z rows of planar
        point closures, drop out).

        Returns:
            T: (nv, n_y); pinv_z: (n_z, rows of K).

        Raises:
            SingularPoseError: if K loses rank (a leg is stretched or folded, or the output
                stops parametrizing the mechanism).
        """
        T, pinv_z = self.velocity_map_nocopy(np.asarray(q, dtype=float))
        return T.copy(), pinv_z.copy()

    def velocity_map_nocopy(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`velocity_map` without copies (cached on q; callers must not modify the arrays)."""
        key = q.tobytes()
        cache = self._vm_cache
        if cache is not None and cache[0] == key:
            return cache[1], cache[2]
        _, jac = self._eval(q)
        out = self._map_from(jac)
        if out is None:
            s = np.linalg.svd(jac[:, self.z_idx], compute_uv=False)
            raise SingularPoseError(
                f"legs singular at platform pose {np.round(self.platform_pose(q), 6).tolist()}: "
                f"cond(Φ_z) = {s[0] / max(s[self.n_z - 1], 1e-300):.3g} (limit {1 / SINGULAR_RCOND:.0e})"
            )
        self._vm_cache = (key, *out)
        return out

    def singularity(self, q: np.ndarray) -> dict:
        """Conditioning at q: ``cond_phi_z`` (assembly Jacobian K = Φ_z, or [Φ_q; H] for task
        outputs: legs) and ``cond_B_r`` (reduced input matrix B_r = Tᵀ Sᵀ, actuation); large
        numbers mean near-singular."""
        _, jac = self._eval(np.asarray(q, dtype=float))
        s = np.linalg.svd(jac[:, self.z_idx], compute_uv=False)[: self.n_z]
        cond_z = float(s[0] / s[-1]) if s[-1] > 0 else math.inf
        if cond_z * SINGULAR_RCOND >= 1:
            return {"cond_phi_z": cond_z, "cond_B_r": math.inf}
        T, _ = self.velocity_map(q)
        sb = np.linalg.svd(T.T @ self.drive_selection, compute_uv=False)
        cond_b = float(sb[0] / sb[-1]) if sb[-1] > 0 else math.inf
        return {"cond_phi_z": cond_z, "cond_B_r": cond_b}

    def check_pose(self, pose, max_cond: float = 1e4) -> np.ndarray:
        """Assemble ``pose`` and raise :class:`SingularPoseError` if it is near-singular."""
        q = self.assemble(pose)
        cond = self.singularity(q)
        worst = max(cond.values())
        if worst > max_cond:
            raise SingularPoseError(
                f"platform pose {np.round(np.asarray(pose), 6).tolist()} is near-singular: "
                f"cond(Φ_z) = {cond['cond_phi_z']:.3g}, cond(B_r) = {cond['cond_B_r']:.3g} (limit {max_cond:.3g})"
            )
        return q

    def __repr__(self) -> str:
        red = f", redundancy={self.redundancy}" if self.redundancy else ""
        return (f"ParallelRobot({self.name!r}, dof={self.n_y}, drives={self.n_u}{red}, "
                f"closures={len(self.description.closures)}, mass_scale={self.mass_scale})")
