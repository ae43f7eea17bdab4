"""Closed-chain robot: URDF open tree + loop closures .

The robot file is read by :mod:`parallel_gpc.model.description`; this module builds the
Pinocchio model, assembles the closures and gives the closure kinematics.

Coordinates: q splits into the independent platform coordinates y (the output joints) and the
dependent leg coordinates z. Only 1-DOF joints (revolute, prismatic) are supported, so
``nq == nv`` and q is a plain vector.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
from scipy.linalg import lapack

from ..errors import (
    AssemblyError,
    InvalidParameterError,
    RobotFormatError,
    SingularPoseError,
    UnreachablePoseError,
)
from ..validation import finite_vector

from .description import (  # noqa: F401  (re-exported for the robot's users)
    CLOSURE_ROWS as _CLOSURE_ROWS,
    DEFAULT_ROBOT,
    Closure,
    RobotDescription,
    embedded_robots,
    load_description,
    urdf_dir,
)

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
#: Φ_z smallest/largest singular value below which the legs count as singular.
SINGULAR_RCOND = 1e-8
#: relative singular-value cut of the rank-revealing Newton step (as ``lstsq(rcond=1e-10)``).
_NEWTON_RCOND = 1e-10


def _fast_index(idx: np.ndarray):
    """A slice equal to the integer index array ``idx`` when it is an arithmetic progression
    (basic slicing is several times cheaper than fancy indexing in the hot paths), else ``idx``."""
    idx = np.asarray(idx, dtype=int)
    if idx.size == 0:
        return idx
    if idx.size == 1:
        return slice(int(idx[0]), int(idx[0]) + 1)
    step = int(idx[1] - idx[0])
    if step > 0 and np.all(np.diff(idx) == step):
        return slice(int(idx[0]), int(idx[-1]) + 1, step)
    return idx


def svd_thin(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Thin SVD ``a = U diag(s) Vt`` by LAPACK ``dgesdd`` (same factorization as
    ``numpy.linalg.svd(a, full_matrices=False)``, without its per-call overhead)."""
    U, s, Vt, info = lapack.dgesdd(a, compute_uv=1, full_matrices=0)
    if info != 0:  # pragma: no cover - LAPACK convergence failure: take numpy's path and its error
        return np.linalg.svd(a, full_matrices=False)
    return U, s, Vt



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
    """A parallel robot: Pinocchio model of the open tree plus its loop closures.

    Args:
        description: what the robot file says.
        mass_scale: multiplies every body's mass and inertia (model mismatch studies).
        gravity: (3,) gravity vector in m/s² (default: Pinocchio's, -9.81 along z).

    Attributes:
        model: the ``pinocchio.Model`` of the open tree (immutable description).
        data: a ``pinocchio.Data`` workspace owned by this object.
        n_y: number of output coordinates (platform DOF).
        n_u: number of drives.
        y_idx, z_idx: indices in q (= in v) of the independent and dependent coordinates.
        drive_idx: indices in v of the drives (S = selection of these rows).
        q_home: assembled home configuration.
    """

    def __init__(self, description: RobotDescription, mass_scale: float = 1.0, gravity=None):
        self.description = description
        try:
            model = pin.buildModelFromUrdf(str(description.urdf_path))
        except Exception as exc:  # Pinocchio raises ValueError/RuntimeError with its own text
            raise RobotFormatError(
                f"cannot build a model from URDF {str(description.urdf_path)!r}: {exc}"
            ) from exc
        if model.nq != model.nv:
            bad = [model.names[j] for j in range(1, model.njoints) if model.joints[j].nq != model.joints[j].nv]
            raise RobotFormatError(
                f"joints {bad} have nq != nv; only revolute and prismatic joints are supported"
            )
        if not (mass_scale > 0 and math.isfinite(mass_scale)):
            raise InvalidParameterError(f"mass_scale = {mass_scale!r} must be finite and > 0")
        for j in range(1, model.njoints):
            inertia = model.inertias[j]
            model.inertias[j] = pin.Inertia(
                inertia.mass * mass_scale, inertia.lever, inertia.inertia * mass_scale
            )
        if gravity is not None:
            model.gravity.linear = finite_vector("gravity", gravity, 3)
        self.model = model
        self.data = model.createData()
        self.mass_scale = float(mass_scale)
        self.y_idx = np.array([self._joint_v_index(n, "output joint") for n in description.output_joints])
        self.drive_idx = np.array([self._joint_v_index(n, "drive") for n in description.drive_joints])
        self.z_idx = np.array([i for i in range(model.nv) if i not in set(self.y_idx.tolist())])
        self.n_y = len(self.y_idx)
        self.n_u = len(self.drive_idx)
        self.n_z = len(self.z_idx)
        self.closure_frames = [
            (self._frame_id(c.frames[0], c), self._frame_id(c.frames[1], c), c) for c in description.closures
        ]
        self.n_constraints = sum(_CLOSURE_ROWS[c.kind] for c in description.closures)
        self._setup_fast_paths()
        if self.n_constraints < self.n_z:
            raise RobotFormatError(
                f"{len(description.closures)} closures give {self.n_constraints} constraint rows, fewer than "
                f"the {self.n_z} dependent coordinates: the legs are not determined by the platform pose"
            )
        self.output_frame_id = (
            model.getFrameId(description.output_frame) if description.output_frame else None
        )
        if self.output_frame_id is not None and self.output_frame_id >= model.nframes:
            raise RobotFormatError(f"output frame {description.output_frame!r} is not in the URDF")
        self.torque_limit = (
            np.array(description.torque_limit) if description.torque_limit is not None else None
        )
        self._branch_idx = np.array(
            [self._joint_v_index(n, "branch joint") for n in description.branch_joints], dtype=int
        )
        self._bs = _fast_index(self._branch_idx)
        q0 = pin.neutral(model)
        for name, value in description.q_guess.items():
            q0[self._joint_v_index(name, "q_guess joint")] = value
        home = description.home_pose if description.home_pose is not None else q0[self.y_idx]
        self.home_pose = finite_vector("home pose", home, self.n_y)
        q0[self.y_idx] = self.home_pose
        self._branch = None
        try:
            self.q_home = self._newton(self.home_pose, q0)
        except UnreachablePoseError as exc:
            raise AssemblyError(self._assembly_failure(q0, exc)) from None
        self._branch = self.branch_signature(self.q_home)

    def _assembly_failure(self, q0: np.ndarray, exc: Exception) -> str:
        """Message for closures that cannot be assembled at the home pose: the worst closures."""
        q = q0.copy()
        for _ in range(30):  # least-squares Newton: where the closures get closest
            ck = self.closure_kinematics(q)
            q[self.z_idx] -= np.linalg.lstsq(ck.jacobian[:, self.z_idx], ck.residual, rcond=1e-10)[0]
        res = self.closure_residual(q)
        parts, row = [], 0
        for _, _, c in self.closure_frames:
            rows = _CLOSURE_ROWS[c.kind]
            parts.append((float(np.linalg.norm(res[row:row + rows])), c))
            row += rows
        bad = [f"{c.name!r} {list(c.frames)} misses by {r:.3g} m" for r, c in sorted(parts, key=lambda t: -t[0])
               if r > 1e-9]
        return (f"the closures of {self.name!r} cannot be assembled at the home pose "
                f"{np.round(self.home_pose, 6).tolist()}: {'; '.join(bad) or str(exc)} "
                f"(check the closure frames, home.pose and home.q_guess in the sidecar)")

    def _setup_fast_paths(self) -> None:
        """Index tables and caches of the hot paths (closure evaluation, velocity map)."""
        self._frames_flat = [f for fa, fb, _ in self.closure_frames for f in (fa, fb)]
        self.bias_symmetric = all(c.kind == "point" for _, _, c in self.closure_frames)
        rows = [6 * k + i for k, (_, _, c) in enumerate(self.closure_frames) for i in range(_CLOSURE_ROWS[c.kind])]
        self._jac_rows = np.array(rows, dtype=int)  # rows of the stacked 6-D frame differences kept
        self._ys = _fast_index(self.y_idx)
        self.dependent_v = _fast_index(self.z_idx)
        self.drive_v = _fast_index(self.drive_idx)
        self._T0 = np.zeros((self.model.nv, self.n_y))
        self._T0[self.y_idx, np.arange(self.n_y)] = 1.0
        self._ck_cache = None  # (q, residual, jacobian) of the last Jacobian evaluation
        self._vm_cache = None  # (q, T, pinv_z) of the last velocity map

    # ------------------------------------------------------------------ construction
    @classmethod
    def load(cls, name_or_path: str | Path = DEFAULT_ROBOT, **kwargs) -> "ParallelRobot":
        """Load an embedded robot by name or a robot file by path (URDF or sidecar)."""
        return cls(load_description(name_or_path), **kwargs)

    def with_mass_scale(self, mass_scale: float) -> "ParallelRobot":
        """A copy whose body masses and inertias are scaled by ``mass_scale`` (plant mismatch)."""
        return ParallelRobot(self.description, mass_scale=mass_scale * self.mass_scale,
                             gravity=np.array(self.model.gravity.linear))

    def _joint_v_index(self, name: str, role: str) -> int:
        if not self.model.existJointName(name):
            joints = list(self.model.names)[1:]
            raise RobotFormatError(f"{role} {name!r} is not a joint of the URDF; joints are {joints}")
        return int(self.model.joints[self.model.getJointId(name)].idx_v)

    def _frame_id(self, name: str, closure: Closure) -> int:
        if not self.model.existFrame(name):
            raise RobotFormatError(
                f"closure {closure.name!r} names frame {name!r}, which is not in the URDF "
                f"(frames: {[f.name for f in self.model.frames][1:]})"
            )
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

    # ------------------------------------------------------------------ closures
    def _closure_eval(self, q: np.ndarray, jacobian: bool = True):
        """Φ(q) and (if ``jacobian``) Φ_q at q: one kinematics pass, all frames at once.

        The last evaluation with the Jacobian is cached on q (the final Newton iterate is the
        configuration whose velocity map is asked for next). Returns (residual, jacobian or None);
        callers must not modify them.
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
        P = np.array([oMf[f].translation for f in frames])
        if self.bias_symmetric:
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
        if not jacobian:
            return res, None
        J = np.array([pin.getFrameJacobian(model, data, f, _LWA) for f in frames])
        if self.bias_symmetric:
            jac = (J[0::2, :3] - J[1::2, :3]).reshape(-1, model.nv)
        else:
            jac = (J[0::2] - J[1::2]).reshape(-1, model.nv)[self._jac_rows]
        self._ck_cache = (key, res, jac)
        return res, jac

    def closure_kinematics(self, q: np.ndarray) -> ClosureKinematics:
        """Φ(q) and Φ_q at configuration q (updates ``self.data`` unless q was just evaluated)."""
        res, jac = self._closure_eval(np.asarray(q, dtype=float))
        return ClosureKinematics(res.copy(), jac.copy())

    def closure_jacobian_derivative(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(m, nv) Φ̇_q = dΦ_q/dt at (q, q̇ = v); the closure acceleration bias is γ = Φ̇_q v.

        Φ̇_q is linear in v. Updates ``self.data``.
        """
        model, data = self.model, self.data
        pin.computeJointJacobiansTimeVariation(model, data, q, v)
        dJ = np.array([pin.getFrameJacobianTimeVariation(model, data, f, _LWA) for f in self._frames_flat])
        if self.bias_symmetric:
            return (dJ[0::2, :3] - dJ[1::2, :3]).reshape(-1, model.nv)
        return (dJ[0::2] - dJ[1::2]).reshape(-1, model.nv)[self._jac_rows]

    def constraint_jacobian_derivative(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Φ̇ of the rows solved by assembly (the closures for joint outputs), at (q, v)."""
        return self.closure_jacobian_derivative(q, v)

    def integrate(self, q: np.ndarray, dv: np.ndarray) -> np.ndarray:
        """(nq,) configuration q ⊕ dv (a new array; plain addition when nq == nv)."""
        return q + dv

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

    # ------------------------------------------------------------------ assembly
    def branch_signature(self, q: np.ndarray) -> np.ndarray:
        """Signs of sin(q) of the branch joints (the elbow configuration)."""
        return np.sign(np.sin(q[self._branch_idx]))

    def _lstsq_z(self, jac: np.ndarray, res: np.ndarray) -> np.ndarray:
        """Minimum-norm least-squares δz with Φ_z δz ≈ res (SVD, singular values below
        ``1e-10·s_max`` dropped: the same step as ``numpy.linalg.lstsq(rcond=1e-10)``)."""
        U, s, Vt = svd_thin(jac[:, self.dependent_v])
        r = int(np.count_nonzero(s > _NEWTON_RCOND * s[0])) if s[0] > 0 else 0
        if r == s.shape[0]:
            return Vt.T @ ((U.T @ res) / s)
        return Vt[:r].T @ ((U[:, :r].T @ res) / s[:r])

    def _newton(self, pose: np.ndarray, q_guess: np.ndarray, tol: float = 1e-12,
                max_iter: int = 30) -> np.ndarray:
        """Solve Φ(q) = 0 for z with y = pose fixed, from q_guess (rank-revealing steps)."""
        q = np.array(q_guess, dtype=float)
        q[self._ys] = pose
        zs = self.dependent_v
        for _ in range(max_iter):
            res, jac = self._closure_eval(q)
            err = np.abs(res).max()
            if err <= tol:
                break
            if not err < 1e6:  # NaN/inf pose or a diverging iteration
                raise UnreachablePoseError(
                    f"platform pose {np.round(pose, 6).tolist()} cannot be assembled: closure residual {err:.3g}"
                )
            q[zs] -= self._lstsq_z(jac, res)
        else:
            res, _ = self._closure_eval(q)
            err = np.max(np.abs(res))
            if err > 1e-9:
                raise UnreachablePoseError(
                    f"platform pose {np.round(pose, 6).tolist()} cannot be assembled: closure residual "
                    f"{err:.3g} m after {max_iter} Newton steps (outside the workspace of {self.name!r})"
                )
        return q

    def assemble_warm(self, pose: np.ndarray, q_guess: np.ndarray, pinv_hint: np.ndarray | None = None,
                      near: bool = False, tol: float = 1e-12, max_iter: int = 8):
        """Warm-started hot path of :meth:`assemble` + :meth:`velocity_map`: (q, T, Φ_z⁺).

        Newton from ``q_guess`` (expected within a few steps of the solution), the branch check,
        and the velocity map at the converged q from the Jacobian of the last Newton
        evaluation (one kinematics pass less). ``pinv_hint`` (Φ_z⁺ at a nearby configuration)
        makes the first Newton step cheap: the least-squares step is solved by one step of
        iterative refinement preconditioned with it instead of an SVD (same step to second
        order in the distance; convergence is checked as always). Returns None when anything
        is unusual (no convergence in ``max_iter`` steps, another branch, a singular Φ_z): the
        caller then takes the validated path, which reports the error. ``near`` (the guess is
        within ~0.1 mm of an assembled configuration on the home branch) skips the branch check
        when no Newton step was needed: the elbows cannot cross their stretched/folded angle
        without a step.
        """
        q = np.array(q_guess, dtype=float)
        q[self._ys] = pose
        zs = self.dependent_v
        tol2 = tol * tol
        for it in range(max_iter):
            res, jac = self._closure_eval(q)
            err2 = res @ res  # ‖Φ‖₂ ≤ tol implies ‖Φ‖∞ ≤ tol
            if err2 <= tol2:
                break
            if not err2 < 1e-4:
                return None
            if it == 0 and pinv_hint is not None:
                step = pinv_hint @ res
                step += pinv_hint @ (res - jac[:, zs] @ step)
                q[zs] -= step
            else:
                q[zs] -= self._lstsq_z(jac, res)
        else:
            return None
        if self._branch_idx.size and not (near and it == 0) and not (np.sin(q[self._bs]) * self._branch).min() > 0:
            return None
        U, s, Vt = svd_thin(jac[:, zs])
        n_z = self.n_z
        if not s[n_z - 1] > SINGULAR_RCOND * s[0]:
            return None
        pinv_z = (Vt[:n_z].T / s[:n_z]) @ U[:, :n_z].T
        T = self._T0.copy()
        T[zs] = -(pinv_z @ jac[:, self._ys])
        self._vm_cache = (self._ck_cache[0], T, pinv_z)
        return q, T, pinv_z

    def _on_branch(self, q: np.ndarray) -> bool:
        return bool(np.all(np.sin(q[self._branch_idx]) * self._branch > 0)) if self._branch_idx.size else True

    def assemble(self, pose, q_guess: np.ndarray | None = None) -> np.ndarray:
        """Full configuration q for a platform pose y, on the home branch.

        Args:
            pose: (n_y,) platform pose (m, rad).
            q_guess: (nq,) warm start (e.g. the previous configuration); default: continuation
                from the home configuration.

        Returns:
            (nq,) q with ‖Φ(q)‖∞ ≤ 1e-12 (1e-9 at worst) and y-coordinates equal to ``pose``.

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
        steps = int(min(200, max(1, math.ceil(max(dist[:2].max(initial=0) / 0.05, dist[2:].max(initial=0) / 0.1)))))
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
    def platform_pose(self, q: np.ndarray) -> np.ndarray:
        """(n_y,) platform pose y of configuration q (m, rad)."""
        return np.asarray(q)[self.y_idx].copy()

    def platform_placement(self, q: np.ndarray) -> pin.SE3:
        """World placement of the output frame at q."""
        pin.framesForwardKinematics(self.model, self.data, q)
        return self.data.oMf[self.output_frame_id].copy()

    def inverse_kinematics(self, pose) -> np.ndarray:
        """(n_u,) drive coordinates (rad) that place the platform at ``pose``."""
        return self.assemble(pose)[self.drive_idx].copy()

    def forward_kinematics(self, drives, q_guess: np.ndarray | None = None, tol: float = 1e-12,
                           max_iter: int = 50) -> np.ndarray:
        """(n_y,) platform pose for drive coordinates (rad), by Newton from ``q_guess`` (home).

        With redundant drives the drive values must be consistent (e.g. from
        :meth:`inverse_kinematics`); the least-squares solution is returned otherwise.
        """
        drives = finite_vector("drive coordinates", drives, self.n_u)
        q = (self.q_home if q_guess is None else np.asarray(q_guess, dtype=float)).copy()
        q[self.drive_idx] = drives
        free = np.array([i for i in range(self.model.nv) if i not in set(self.drive_idx.tolist())])
        for _ in range(max_iter):
            ck = self.closure_kinematics(q)
            if np.max(np.abs(ck.residual)) <= tol:
                return self.platform_pose(q)
            step, *_ = np.linalg.lstsq(ck.jacobian[:, free], ck.residual, rcond=1e-10)
            q[free] -= step * min(1.0, 0.2 / max(np.max(np.abs(step)), 1e-300))  # damped: stay on branch
        raise AssemblyError(
            f"forward kinematics did not converge for drives {np.round(drives, 6).tolist()}: "
            f"closure residual {np.max(np.abs(self.closure_residual(q))):.3g}"
        )

    def velocity_map(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """T (q̇ = T ẏ) and the rank-revealing pseudo-inverse Φ_z⁺ at q.

        Φ_z⁺ uses the n_z leading singular values of Φ_z (its zero rows, e.g. the z rows of
        planar point closures, drop out).

        Returns:
            T: (nv, n_y); pinv_z: (n_z, m).

        Raises:
            SingularPoseError: if Φ_z loses rank (a leg is stretched or folded).
        """
        T, pinv_z = self.velocity_map_nocopy(np.asarray(q, dtype=float))
        return T.copy(), pinv_z.copy()

    def velocity_map_nocopy(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`velocity_map` without copies (cached on q; callers must not modify)."""
        key = q.tobytes()
        cache = self._vm_cache
        if cache is not None and cache[0] == key:
            return cache[1], cache[2]
        _, jac = self._closure_eval(q)
        U, s, Vt = svd_thin(jac[:, self.dependent_v])
        n_z = self.n_z
        if s[n_z - 1] <= SINGULAR_RCOND * s[0]:
            raise SingularPoseError(
                f"legs singular at platform pose {np.round(q[self.y_idx], 6).tolist()}: "
                f"cond(Φ_z) = {s[0] / max(s[n_z - 1], 1e-300):.3g} (limit {1 / SINGULAR_RCOND:.0e})"
            )
        pinv_z = (Vt[:n_z].T / s[:n_z]) @ U[:, :n_z].T
        T = self._T0.copy()
        T[self.dependent_v] = -(pinv_z @ jac[:, self._ys])
        self._vm_cache = (key, T, pinv_z)
        return T, pinv_z

    def singularity(self, q: np.ndarray) -> dict:
        """Conditioning at q: ``cond_phi_z`` (dependent-coordinate block, legs) and ``cond_B_r``
        (reduced input matrix B_r = Tᵀ Sᵀ, actuation); large numbers mean near-singular."""
        s = np.linalg.svd(self.closure_kinematics(q).jacobian[:, self.z_idx], compute_uv=False)[: self.n_z]
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
        return (f"ParallelRobot({self.name!r}, dof={self.n_y}, drives={self.n_u}, "
                f"closures={len(self.description.closures)}, mass_scale={self.mass_scale})")
