"""Assembly and velocity map of a :class:`~parallel_gpc.model.robot.ParallelRobot`.

Newton on the assembly equations Ψ(q) = 0 (rank-revealing steps, continuation from home on
the home branch), its warm-started hot path, forward/inverse kinematics, and the velocity map
q̇ = T ẏ with the pseudo-inverse K⁺ of the assembly Jacobian. Mixed into ``ParallelRobot``.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from ..errors import AssemblyError, RobotFormatError, SingularPoseError, UnreachablePoseError
from ..validation import finite_vector, rounded
from .checks import NEAR_SINGULAR_COND, numerical_rank
from .forward import rates_to_velocity, resolution_array, solve_forward
from .linalg import svd_thin
from .native import native_enabled
from .native_update import compiled_forward, use_native
from .sidecar import CLOSURE_ROWS

#: K smallest/largest singular value below which the legs count as singular.
SINGULAR_RCOND = 1e-8
#: relative singular-value cut of the rank-revealing Newton step (as ``lstsq(rcond=1e-10)``).
_NEWTON_RCOND = 1e-10
#: smallest |sin q| of a branch joint at home: below it the joint is stretched or folded
#: (within 0.057° of 0 or π) and the sign of sin q does not tell the assembly branch.
BRANCH_MIN_SIN = 1e-3


#: starts of the globalized solve of :meth:`AssemblyMixin._global_projection` (the drawing first).
GLOBAL_STARTS = 5


class _PathStop(Exception):
    """A continuation stops at output ``mid`` (n_y,) for ``reason`` (internal to this module)."""

    def __init__(self, mid: np.ndarray, reason: str):
        super().__init__(reason)
        self.mid, self.reason = mid, reason


class AssemblyMixin:
    """Assembly, kinematics and velocity map of a closed-chain robot (see ParallelRobot)."""

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
        label = "closures" if pose is None else f"platform pose {rounded(pose, 6)}"
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

    def _project_closures(self, q_start: np.ndarray, tol: float = 1e-12, max_iter: int = 100) -> np.ndarray:
        """The assembled configuration nearest ``q_start``: Newton on the closures Φ(q) = 0 over
        all coordinates with minimum-norm steps of at most 0.5 (rad or m) per coordinate (the
        outputs move too). When Newton stalls, a globalized solve
        (:meth:`_global_projection`) looks further before giving up.

        Raises:
            UnreachablePoseError: neither converges; the message gives the smallest residual the
                globalized solve reached and the closures that miss there.
        """
        try:
            return self._newton_projection(q_start, tol, max_iter)
        except UnreachablePoseError as exc:
            newton_error = exc
        return self._newton_projection(self._global_projection(q_start, newton_error), tol, max_iter)

    def _global_projection(self, q_start: np.ndarray, newton_error: Exception):
        """Levenberg–Marquardt (``scipy.optimize.least_squares``) on the closure residual of
        :meth:`closure_log_error` over all joints, from ``q_start`` and :data:`GLOBAL_STARTS` − 1
        starts perturbed by ±0.3 rad or m (a fixed seed): the (nq,) configuration of the first start
        that closes the loops to 1e-10.

        Raises:
            UnreachablePoseError: no start does; the message gives the smallest residual reached,
                the Jacobian rank there and the closures that miss most.
        """
        from scipy.optimize import least_squares

        model = self.model
        q_start = np.array(q_start, dtype=float)
        rng = np.random.default_rng(0)

        def at(dv):
            return self.integrate(q_start, dv)

        def residual(dv):
            return self.closure_log_error(at(dv)).residual

        def jacobian(dv):
            J = self.closure_log_error(at(dv)).jacobian
            return J if self._flat else J @ pin.dIntegrate(model, q_start, dv, pin.ArgumentPosition.ARG1)

        rows = self.closure_log_error(q_start).residual.size
        best = None
        for k in range(GLOBAL_STARTS):
            dv0 = np.zeros(model.nv) if k == 0 else rng.uniform(-0.3, 0.3, model.nv)
            sol = least_squares(residual, dv0, jac=jacobian, method="lm" if rows >= model.nv else "trf",
                                xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=500)
            err = float(np.max(np.abs(sol.fun), initial=0.0))
            if err <= 1e-10:
                return at(sol.x)
            if best is None or err < best[0]:
                best = (err, at(sol.x))
        err, q = best
        at_best = self.closure_log_error(q)
        worst = "; ".join(self._closure_misses(at_best.residual)[:4])
        rank = numerical_rank(np.linalg.svd(at_best.jacobian, compute_uv=False))
        raise UnreachablePoseError(
            f"the closures of {self.name!r} cannot be assembled: {newton_error}, and a globalized least-squares solve (Levenberg–Marquardt over all "
            f"{model.nv} joint coordinates from the drawing and {GLOBAL_STARTS - 1} perturbed starts) gets no "
            f"closer than a residual of {err:.3g} (m, rad; Jacobian rank {rank} of {rows} rows there), missing "
            f"{worst}: no configuration near the drawing closes the {len(self.closure_frames)} closure(s) together, so "
            "they are likely inconsistent (a 6-D weld where the mechanism only lets the frames meet as points, "
            "or frames drawn with a relative rotation the joints cannot absorb); check the closure kinds and "
            "frames, or give home.q_guess near an assembled configuration")

    def _closure_misses(self, residual: np.ndarray) -> list[str]:
        """The closures that miss by more than 1e-9, worst first: ``'name' [frame a, frame b] by 0.1 m``
        (``and 0.2 rad`` for a weld).

        Args:
            residual: (m,) closure rows, in the order of ``closure_frames``: 3 positions (m) per
                closure, then 3 rotations (rad) for a weld.
        """
        parts, row = [], 0
        for _, _, c in self.closure_frames:
            n = CLOSURE_ROWS[c.kind]
            parts.append((float(np.linalg.norm(residual[row:row + 3])),
                          float(np.linalg.norm(residual[row + 3:row + n])), c))
            row += n
        return [f"{c.name!r} {list(c.frames)} by {p:.3g} m" + (f" and {r:.3g} rad" if c.kind == "weld" else "")
                for p, r, c in sorted(parts, key=lambda t: -max(t[0], t[1])) if max(p, r) > 1e-9]

    def _newton_projection(self, q_start: np.ndarray, tol: float, max_iter: int) -> np.ndarray:
        """:meth:`_project_closures`' Newton iteration alone."""
        q = np.array(q_start, dtype=float)
        for _ in range(max_iter):
            ck = self.closure_log_error(q)
            err = float(np.max(np.abs(ck.residual), initial=0.0))
            if err <= tol:
                return q
            if not err < 1e6:
                break
            U, s, Vt = svd_thin(ck.jacobian)
            r = int(np.count_nonzero(s > _NEWTON_RCOND * s[0])) if s.size and s[0] > 0 else 0
            step = Vt[:r].T @ ((U[:, :r].T @ ck.residual) / s[:r])
            q = self.integrate(q, -step * min(1.0, 0.5 / max(float(np.max(np.abs(step))), 1e-300)))  # damped
        raise UnreachablePoseError(f"Newton from the configuration the file is drawn at stalls at a residual of "
                                   f"{err:.3g} after {max_iter} steps")

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
            q[self._y_q] = pose  # q indices (y_idx are v indices: they differ after a multi-DOF joint)
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

    def _follow(self, y_from: np.ndarray, q_from: np.ndarray, y_to: np.ndarray, watch_singular: bool = False):
        """Continuation: Newton along the straight path y_from → y_to (steps of ≤ 0.05 m and
        0.1 rad) from the assembled ``q_from``; the (nq,) configuration at ``y_to``.

        Args:
            watch_singular: also stop where K loses rank strictly between the ends (the
                assembly may switch branch there).

        Raises:
            _PathStop: where and why the path stops (``mid``, ``reason``).
        """
        dist = np.abs(y_to - y_from)
        ang = self._is_angle
        steps = int(min(200, max(1, math.ceil(max(dist[~ang].max(initial=0) / 0.05, dist[ang].max(initial=0) / 0.1)))))
        q = q_from.copy()
        for s in range(1, steps + 1):
            mid = y_from + (y_to - y_from) * s / steps
            try:
                q = self._newton(mid, q)
            except UnreachablePoseError as exc:
                raise _PathStop(mid, str(exc)) from None
            if watch_singular and s < steps and self._map_from(self._eval(q)[1]) is None:
                raise _PathStop(mid, "the legs are singular there: the assembly can switch branch")
        return q

    def _continuation(self, pose: np.ndarray) -> np.ndarray:
        try:
            q = self._follow(self.home_pose, self.q_home, pose)
        except _PathStop as stop:
            raise UnreachablePoseError(
                f"platform pose {rounded(pose, 6)} cannot be assembled on the home branch of "
                f"{self.name!r}: continuation from home stops at {rounded(stop.mid, 4)} "
                f"({stop.reason})"
            ) from None
        if not np.array_equal(self.branch_signature(q), self._branch):
            raise UnreachablePoseError(
                f"platform pose {rounded(pose, 6)} is reachable only on another assembly branch "
                f"(a leg passes through its singular stretched/folded configuration on the way)"
            )
        return q

    def _home_from_drawing(self, y_draw: np.ndarray, q_draw: np.ndarray) -> np.ndarray:
        """(nq,) home configuration reached from the assembled drawing (output ``y_draw``,
        configuration ``q_draw``) by continuation to ``home_pose``, on the drawn branch.

        Raises:
            AssemblyError: the straight path stops (outside the workspace) or crosses a
                singular configuration, or the branch joints' signs at home differ from the drawing's.
        """
        home = self.home_pose
        ends = (f"home pose {rounded(home, 6)} of {self.name!r} and the configuration the file is drawn "
                f"at (output {rounded(y_draw, 6)})")
        hint = ("give home.q_guess (rough joint values at home) to choose the configuration, or a home pose "
                "reachable from the drawing on its branch")
        try:
            q = self._follow(y_draw, q_draw, home, watch_singular=True)
        except _PathStop as stop:
            raise AssemblyError(f"{ends} are not joined on one assembly branch: the straight path stops at "
                                f"{rounded(stop.mid, 4)} ({stop.reason}); {hint}") from None
        drawn, at_home = self.branch_signature(q_draw), self.branch_signature(q)
        if np.any(drawn * at_home < 0):
            names = self.description.branch_joints
            raise AssemblyError(f"{ends}: home lands on another branch than the drawing: the signs of sin(q) of the "
                                f"branch joints {list(names)} are {at_home.astype(int).tolist()} at home and "
                                f"{drawn.astype(int).tolist()} in the drawing; {hint}")
        return q

    def _check_branch_joints(self) -> None:
        """Every branch joint is bent at home: |sin q| ≥ :data:`BRANCH_MIN_SIN`.

        Raises:
            RobotFormatError: naming the joint and its angle at home.
        """
        q = self.q_home[self._branch_q]
        for name, angle in zip(self.description.branch_joints, q):
            if abs(math.sin(angle)) < BRANCH_MIN_SIN:
                raise RobotFormatError(
                    f"branch joint {name!r} is at q = {angle:.6g} rad at the home pose of {self.name!r} "
                    f"(|sin q| < {BRANCH_MIN_SIN:g}: stretched or folded), so the sign of sin q cannot tell the "
                    "assembly branch there; list in home.branch_joints only joints that are bent at home")

    # ------------------------------------------------------------------ kinematics
    def inverse_kinematics(self, pose) -> np.ndarray:
        """(n_u,) drive coordinates (rad or m) that place the platform at ``pose``."""
        return self.assemble(pose)[self._drive_q].copy()

    def forward_kinematics(self, drives, q_guess: np.ndarray | None = None, resolution=None,
                           max_residual: float = 50.0) -> np.ndarray:
        """(n_y,) output (m, rad) for drive readings (rad or m): weighted least squares over the
        drives, on the home branch (:func:`~parallel_gpc.model.forward.solve_forward`).

        Args:
            drives: (n_u,) drive positions (rad or m), e.g. encoder readings.
            q_guess: (nq,) warm start (e.g. the last configuration); default home.
            resolution: (n_u,) or scalar resolution of the drive encoders (rad or m), the
                least-squares weights; default the robot's sensors
                (:func:`~parallel_gpc.model.forward.drive_resolution`).
            max_residual: largest accepted residual of a drive at the solution, in counts.

        Raises:
            SensorError: a NaN or out-of-range reading, or readings no pose explains (naming
                the worst drive).
        """
        return self.forward_solution(drives, q_guess, resolution, max_residual).pose

    def forward_solution(self, drives, q_guess: np.ndarray | None = None, resolution=None,
                         max_residual: float = 50.0):
        """:meth:`forward_kinematics` with the configuration, drive Jacobian and residuals
        (a :class:`~parallel_gpc.model.forward.ForwardSolution`)."""
        if q_guess is None:
            q_guess, pose_guess = self.q_home, self.home_pose
        else:
            pose_guess = None
        compiled = None
        if native_enabled():  # the compiled loop unless PARALLEL_GPC_NATIVE=0 (per call) or not built
            compiled = self._forward_compiled
            if compiled is None:  # built once: False when the compiled core lacks it
                compiled = self._forward_compiled = (use_native(None) and compiled_forward(self)) or False
            compiled = compiled or None
        return solve_forward(self, drives, resolution_array(self, resolution), q_guess, pose_guess,
                             max_residual=float(max_residual), compiled=compiled)

    def forward_velocity(self, solution, rates, rate_resolution=None) -> np.ndarray:
        """(n_y,) ẏ (m/s, rad/s) from (n_u,) drive rates (rad/s or m/s) at a
        :meth:`forward_solution`: weighted least squares through its drive Jacobian.

        Args:
            solution: the :class:`~parallel_gpc.model.forward.ForwardSolution` of the same sample.
            rates: (n_u,) drive rates. rate_resolution: (n_u,) or scalar weights σ (default equal).
        """
        rates = finite_vector("drive rates", rates, self.n_u)
        sigma = np.ones(self.n_u) if rate_resolution is None else np.broadcast_to(
            np.asarray(rate_resolution, dtype=float), (self.n_u,))
        return rates_to_velocity(solution.jacobian, rates, sigma)

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
                f"legs singular at platform pose {rounded(self.platform_pose(q), 6)}: "
                f"cond(Φ_z) = {s[0] / max(s[self.n_z - 1], 1e-300):.3g} (limit {1 / SINGULAR_RCOND:.0e})"
            )
        self._vm_cache = (key, *out)
        return out

    def velocity_map_rate(self, q: np.ndarray, T: np.ndarray, pinv_z: np.ndarray, dPsi: np.ndarray):
        """(Ṫ, K̇⁺): the derivative of :meth:`velocity_map`'s (T, K⁺) at q along a motion δ.

        K̇⁺ = −K⁺ K̇ K⁺ + K⁺K⁺ᵀ K̇ᵀ (I − K K⁺), exact while K has full column rank (the second term
        vanishes for a square K); T_z = −K⁺ Ψ_y (joint outputs) or K⁺'s output columns (task outputs).

        Args:
            q: (nq,) configuration; T: (nv, n_y) and pinv_z: (n_z, rows) its velocity map;
            dPsi: (rows, nv) Ψ̇_q(q, δ) (:meth:`constraint_jacobian_derivative` at velocity δ).

        Returns:
            (Ṫ (nv, n_y), K̇⁺ (n_z, rows)) per unit of δ (1/m or 1/rad as δ's units).
        """
        _, jac = self._eval(q)
        K, dK = jac[:, self.dependent_v], dPsi[:, self.dependent_v]
        dP = -pinv_z @ (dK @ pinv_z) + (pinv_z @ pinv_z.T) @ (dK.T - (dK.T @ K) @ pinv_z)
        if self.task_output is not None:
            return dP[:, self.n_constraints:], dP
        dT = np.zeros_like(T)
        dT[self.dependent_v] = -(dP @ jac[:, self._ys] + pinv_z @ dPsi[:, self._ys])
        return dT, dP

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

    def check_pose(self, pose, max_cond: float = NEAR_SINGULAR_COND) -> np.ndarray:
        """Assemble ``pose`` and raise :class:`SingularPoseError` if it is near-singular."""
        q = self.assemble(pose)
        cond = self.singularity(q)
        worst = max(cond.values())
        if worst > max_cond:
            raise SingularPoseError(
                f"platform pose {rounded(np.asarray(pose), 6)} is near-singular: "
                f"cond(Φ_z) = {cond['cond_phi_z']:.3g}, cond(B_r) = {cond['cond_B_r']:.3g} (limit {max_cond:.3g})"
            )
        return q
