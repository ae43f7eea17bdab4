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
import warnings
from pathlib import Path

import numpy as np
import pinocchio as pin

from ..errors import (AssemblyError, ParallelGPCError, ParallelGPCWarning, RobotFormatError, UnderactuatedError,
                      UnreachablePoseError)
from ..limits import Limits
from ..validation import finite_vector, positive, rounded
from .assembly import SINGULAR_RCOND, AssemblyMixin  # noqa: F401  (SINGULAR_RCOND re-exported)
from .builder import build_model, drawn_configuration, joint_unit
from .checks import check_actuation, check_parametrization
from .closures import ClosureKinematics, ClosureMixin  # noqa: F401  (re-exported)
from .console import quiet_build
from .file_checks import check_model_file, check_model_inertias
from .idle import describe_locks, idle_locks, with_locks
from .description import (  # noqa: F401  (re-exported for the robot's users)
    CLOSURE_ROWS as _CLOSURE_ROWS,
    DEFAULT_ROBOT,
    Closure,
    RobotDescription,
    embedded_robots,
    idle_advice,
    load_description,
    urdf_dir,
)
from .linalg import fast_index
from .output_space import OutputSpace, drive_unit_of
from .outputs import TaskOutput
from .universal import UniversalJoints


class ParallelRobot(ClosureMixin, AssemblyMixin):
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
        universal_joints: :class:`~parallel_gpc.model.universal.UniversalJoints`, the corrected
            J̇ and ∂h/∂v of the model's universal joints (falsy without them).
        q_home: assembled home configuration.
    """

    def __init__(self, description: RobotDescription, mass_scale: float = 1.0, gravity=None):
        if not isinstance(description, RobotDescription):
            raise RobotFormatError(f"ParallelRobot takes a RobotDescription, got {type(description).__name__}; "
                                   "load a robot by name or path with ParallelRobot.load(...)")
        mass_scale = positive("mass_scale", mass_scale)
        try:
            self._construct(description, mass_scale, gravity)
        except (UnderactuatedError, AssemblyError):
            locks = self._idle_locks(description)
            if not locks:
                raise
            warnings.warn(describe_locks(self, locks), ParallelGPCWarning, stacklevel=2)
            self._construct(with_locks(description, locks), mass_scale, gravity)

    def _idle_locks(self, description: RobotDescription) -> list[tuple[str, float]]:
        """The joints to lock, one per idle motion (:mod:`.idle`), after a construction that failed
        as under-actuated or unassembled; empty when locking is off or nothing is idle."""
        if description.idle_spins != "lock" or description.locked_joints or not hasattr(self, "n_z") \
                or getattr(self, "_stalled", None):  # the closures do not assemble: nothing to lock
            return []
        q = getattr(self, "q_home", None)
        if q is None:
            try:
                q = self._project_closures(self._start_configuration(description)[0])
            except AssemblyError:
                return []
        return idle_locks(self, q)

    def _construct(self, description: RobotDescription, mass_scale: float, gravity) -> None:
        """Build the model of ``description``, assemble home and check it (the constructor's work)."""
        self.q_home = self._stalled = None
        mesh_files, unresolved, references = check_model_file(description)
        model, closures = quiet_build(build_model, description)
        check_model_inertias(model, description.urdf_path)
        if not closures:
            raise RobotFormatError(
                f"{description.model_format.upper()} {str(description.urdf_path)!r} with sidecar "
                f"{str(description.sidecar_path)!r} has no loop closure: parallel-gpc models closed-chain robots; "
                "close the loops in the sidecar (closures / closed_loop) or, in an MJCF file, with "
                "<equality><connect/weld>")
        self.description = dataclasses.replace(description, closures=closures, mesh_files=mesh_files,
                                               unresolved_meshes=unresolved, mesh_references=references)
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
            raise UnderactuatedError(
                f"{len(closures)} closures give {self.n_constraints} constraint rows, fewer than "
                f"the {self.n_z} dependent coordinates: at least {self.n_z - self.n_constraints} joint motion(s) are "
                "not determined by the output (a free-flyer root, an unactuated joint, or an idle rotation such as a "
                f"rod spinning between two ball joints); {idle_advice(description)}; or use a universal joint "
                "(UJOINT_AB) at one end of such a rod, or add outputs"
            )
        self.torque_limit = np.array(description.torque_limit) if description.torque_limit is not None else None
        self._branch_q = np.array([self._joint_index(n, "branch joint")[0] for n in description.branch_joints],
                                  dtype=int)
        self._bs = fast_index(self._branch_q)
        self._branch = None
        self._home(description)
        self._check_branch_joints()
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
            self._is_angle = np.array([joint_unit(self.model, n) == "rad" for n in description.output_joints])
        else:
            if self.output_frame_id is None:  # pragma: no cover - the description guarantees a frame
                raise RobotFormatError("a task-space output needs an output frame")
            self.task_output = TaskOutput(self.output_frame_id, description.output_axes)
            self.y_idx = np.zeros(0, dtype=int)
            self.z_idx = np.arange(nv)
            self._is_angle = self.task_output.is_angle
        self.n_y = description.n_y
        units = tuple("rad" if a else "m" for a in self._is_angle)
        if description.output_units is not None and tuple(description.output_units) != units:
            raise RobotFormatError(f"[output] units = {list(description.output_units)} do not match the outputs "
                                   f"{list(description.output_labels)}, which are in {list(units)}")
        self.n_u = len(self.drive_idx)
        self.n_z = len(self.z_idx)

    def _setup_fast_paths(self) -> None:
        """Index tables and caches of the hot paths (closure evaluation, velocity map)."""
        self._frames_flat = [f for fa, fb, _ in self.closure_frames for f in (fa, fb)]
        self.universal_joints = UniversalJoints(self.model)  # Pinocchio's J̇, ∂h/∂v corrected for them
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
        if self.task_output is None:  # the assembly rows are the closures: skip a call in the hot path
            self.constraint_jacobian_derivative = self.closure_jacobian_derivative
        self._ck_cache = None  # (q, residual, jacobian) of the last Jacobian evaluation
        self._vm_cache = None  # (q, T, pinv_z) of the last velocity map
        self._forward_compiled = None  # compiled forward kinematics (forward_solution builds it on first use)

    def _home(self, description: RobotDescription) -> None:
        """Assemble the home configuration ``q_home`` at ``home_pose``.

        The start is the configuration the model file is drawn at (MJCF ``qpos0``, URDF q = 0)
        with the ``home.q_guess`` values (rough joint values at home): Newton runs from there to
        the home pose. Without q_guess, the drawing is projected onto the closures (the nearest
        assembled configuration, a no-op for a file drawn assembled), which fixes the branch:
        home (default: the output there) is reached from it by continuation and must stay on
        its branch.
        """
        q0, guessed = self._start_configuration(description)
        drawn, stalled = False, None
        if not guessed:
            try:
                q0, drawn = self._project_closures(q0), True
            except UnreachablePoseError as exc:
                stalled = str(exc)  # the globalized solve's finding, said if home cannot be assembled either
        self._stalled = stalled
        if self.task_output is not None:  # the closures alone first: the output's reference is there
            if not drawn:
                try:
                    q0 = self._newton(None, q0)
                except UnreachablePoseError as exc:
                    raise AssemblyError(stalled or self._assembly_failure(q0, exc, None)) from None
            pin.framesForwardKinematics(self.model, self.data, q0)
            self.task_output.set_reference(self.data)
            y0 = self.task_output.value(self.data)
        else:
            y0 = q0[self._y_q].copy()
        home = description.home_pose if description.home_pose is not None else y0
        self.home_pose = finite_vector("home pose", home, self.n_y)
        if drawn:
            self.q_home = self._home_from_drawing(y0, q0)
            return
        if self.task_output is None:
            q0[self._y_q] = self.home_pose
        try:
            self.q_home = self._newton(self.home_pose, q0)
        except UnreachablePoseError as exc:
            raise AssemblyError(stalled or self._assembly_failure(q0, exc, self.home_pose)) from None

    def _start_configuration(self, description: RobotDescription) -> tuple[np.ndarray, bool]:
        """((nq,) the drawn configuration with the ``home.q_guess`` values, whether any was given)."""
        q0 = drawn_configuration(self.model)
        guessed = False
        for name, value in description.q_guess.items():
            if description.joint_types.get(name) == "FIXED":
                continue  # locked at this value by the builder
            iq, _ = self._joint_index(name, "q_guess joint", nq=len(value) if isinstance(value, tuple) else 1)
            q0[iq:iq + (len(value) if isinstance(value, tuple) else 1)] = value
            guessed = True
        return q0, guessed

    def _assembly_failure(self, q0: np.ndarray, exc: Exception, pose) -> str:
        """Message for closures that cannot be assembled at the home pose: the worst closures."""
        q = q0.copy()
        for _ in range(30):  # least-squares Newton: where the closures get closest
            res, jac = self._eval(q)
            err = self._error(res, pose)
            q = self._step(q, np.linalg.lstsq(jac[:len(err), self.z_idx], err, rcond=1e-10)[0])
        bad = self._closure_misses(self.closure_residual(q))
        where = "" if pose is None else f" at the home pose {rounded(pose, 6)}"
        return (f"the closures of {self.name!r} cannot be assembled{where}: "
                f"{'missing ' + '; '.join(bad) if bad else str(exc)} "
                f"(check the closure frames, home.pose and home.q_guess in the sidecar)")

    @classmethod
    def load(cls, name_or_path: str | Path = DEFAULT_ROBOT, sidecar: str | Path | None = None,
             package_path=None, **kwargs) -> "ParallelRobot":
        """Load an embedded robot by name or a robot file by path (URDF/MJCF or sidecar).

        Args:
            name_or_path: embedded robot name, or path of a model file or sidecar.
            sidecar: explicit sidecar path (default: found next to the model file by stem).
            package_path: folder(s) of the packages named by ``package://`` mesh URIs (searched
                before ``PARALLEL_GPC_PACKAGE_PATH`` and ``ROS_PACKAGE_PATH``); meshes only
                matter for the view.
            **kwargs: ``mass_scale``, ``gravity``.
        """
        return cls(load_description(name_or_path, sidecar, package_path), **kwargs)

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
    def limits(self) -> Limits:
        """The robot file's own input :class:`~parallel_gpc.limits.Limits` (its drive torque limits,
        (n_u,) N·m or N; ``Limits()`` when the file gives none)."""
        return Limits(torque=self.torque_limit).for_drives(self.n_u)

    @property
    def state_limits(self) -> Limits:
        """The state limits of the sidecar's ``[limits]`` table (drive strokes, workspace box,
        velocities; hard or soft) as a :class:`~parallel_gpc.limits.Limits` sized to the drives
        and outputs; ``Limits()`` when the file declares none. ``drive_position = "urdf"`` takes
        the drives' ranges of the model file, a table ``{drive_joint = [lo, hi]}`` sets those drives
        (the others free); ``joint_ranges = "urdf"`` takes every passive one-DOF joint's finite range of
        the model file (:meth:`joint_ranges`), a table ``joint_position = {joint = [lo, hi]}`` sets
        (or replaces) those joints' ranges.

        Raises:
            RobotFormatError: a value the Limits type refuses (naming the sidecar).
        """
        table = dict(self.description.limits)
        if not table:
            return Limits()
        dp = table.get("drive_position")
        if dp == "urdf":
            table["drive_position"] = np.c_[self.drive_range]
        elif isinstance(dp, dict):
            pairs = np.tile([-np.inf, np.inf], (self.n_u, 1))
            for name, pair in dp.items():
                pairs[list(self.description.drive_joints).index(name)] = pair
            table["drive_position"] = pairs
        ranges = self.joint_ranges() if table.pop("joint_ranges", None) == "urdf" else {}
        if isinstance(table.get("joint_position"), dict):
            valid = self.passive_joints
            unknown = sorted(set(table["joint_position"]) - set(valid))
            if unknown:
                raise RobotFormatError(f"sidecar {str(self.description.sidecar_path)!r}: [limits] joint_position names "
                                       f"{unknown}, which are not passive one-DOF joints; valid: {list(valid)}")
            ranges.update(table["joint_position"])
        if ranges:
            table["joint_position"] = ranges
        if "soft" in table:
            table["soft"] = tuple(table["soft"])
        try:
            return Limits(**table).for_drives(self.n_u, self.n_y)
        except ParallelGPCError as exc:
            raise RobotFormatError(f"sidecar {str(self.description.sidecar_path)!r}: [limits]: {exc}") from None

    @property
    def output_angular(self) -> np.ndarray:
        """(n_y,) bool: True where the output coordinate is an angle in rad (a revolute output
        joint or a rotation-vector component), False where it is a length in m."""
        return self._is_angle.copy()

    @property
    def drive_unit(self) -> str:
        """Unit of the drive efforts u: ``"N·m"`` (revolute drives), ``"N"`` (prismatic drives) or
        ``"N·m | N"`` when the robot has both kinds."""
        return drive_unit_of(self.drive_angular)

    @property
    def output_space(self) -> OutputSpace:
        """Names and units of the outputs and the drives' unit (:class:`OutputSpace`), for tables and figures."""
        return OutputSpace.of(self)

    @property
    def drive_selection(self) -> np.ndarray:
        """(nv, n_u) Sᵀ: maps drive torques (N·m) to generalized forces."""
        S = np.zeros((self.model.nv, self.n_u))
        S[self.drive_idx, np.arange(self.n_u)] = 1.0
        return S

    @property
    def drive_q_indices(self) -> np.ndarray:
        """(n_u,) indices in q of the drive coordinates (the encoders' positions), in the order of u."""
        return self._drive_q.copy()

    @property
    def drive_angular(self) -> np.ndarray:
        """(n_u,) bool: True for a revolute drive (position in rad), False for a prismatic one (m)."""
        return np.array([unit == "rad" for unit in self.drive_position_units])

    @property
    def drive_position_units(self) -> tuple[str, ...]:
        """Unit of each drive position: ``"rad"`` or ``"m"``."""
        return tuple(joint_unit(self.model, n) for n in self.description.drive_joints)

    @property
    def passive_joints(self) -> dict[str, tuple[int, int]]:
        """The passive one-DOF (revolute or prismatic) joints: ``{name: (idx_q, idx_v)}`` in model
        order (every joint with nq = nv = 1 that is not a drive; a universal joint is two of them)."""
        model, drives = self.model, set(self.description.drive_joints)
        return {str(model.names[j]): (int(model.joints[j].idx_q), int(model.joints[j].idx_v))
                for j in range(1, model.njoints)
                if model.joints[j].nq == 1 and model.joints[j].nv == 1 and str(model.names[j]) not in drives}

    def joint_ranges(self) -> dict[str, tuple[float, float]]:
        """The model file's ``<limit lower upper>`` range (rad or m) of every passive one-DOF joint
        whose range is finite: ``{name: (lo, hi)}``."""
        lo, hi = self.model.lowerPositionLimit, self.model.upperPositionLimit
        return {name: (float(lo[iq]), float(hi[iq])) for name, (iq, _) in self.passive_joints.items()
                if np.isfinite(lo[iq]) and np.isfinite(hi[iq]) and lo[iq] < hi[iq]}

    @property
    def drive_range(self) -> tuple[np.ndarray, np.ndarray]:
        """((n_u,), (n_u,)) lower and upper position limits of the drives (rad or m) from the model file."""
        return (np.array(self.model.lowerPositionLimit[self._drive_q]),
                np.array(self.model.upperPositionLimit[self._drive_q]))

    @property
    def output_q_indices(self) -> list[int]:
        """Indices in q of the output joints (empty for frame outputs)."""
        return np.arange(self.model.nq)[self._y_q].tolist()

    @property
    def closure_jacobian_rows(self) -> list[int]:
        """Rows of the stacked 6-D frame differences that the closures keep (the rows of Φ_q)."""
        return self._jac_rows.tolist()

    @property
    def branch_q_indices(self) -> list[int]:
        """Indices in q of the branch joints (sidecar ``home.branch_joints``)."""
        return self._branch_q.tolist()

    @property
    def home_branch(self) -> np.ndarray:
        """(n_branch,) signs of sin(q) of the branch joints at home: the assembly branch kept."""
        return np.asarray(self._branch, dtype=float).copy()

    def __repr__(self) -> str:
        red = f", redundancy={self.redundancy}" if self.redundancy else ""
        return (f"ParallelRobot({self.name!r}, dof={self.n_y}, drives={self.n_u}{red}, "
                f"closures={len(self.description.closures)}, mass_scale={self.mass_scale})")
