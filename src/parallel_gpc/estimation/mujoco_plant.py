"""MuJoCo as a foreign plant: an independent physics engine behind the plant interface.

:class:`MujocoPlant` steps an MJCF model — exported from the robot
(:func:`~parallel_gpc.model.mjcf_export.export_mjcf`) or the user's own, whose joints carry the
robot's joint names — for one sample per :meth:`~MujocoPlant.apply`, and reads the drive
encoders (or the state) through :meth:`~MujocoPlant.measure`. Needs the optional extra
``parallel-gpc[mujoco]``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InvalidParameterError, NonFiniteError, RobotFormatError
from ..model import export_mjcf, saturation_limit
from ..validation import finite_vector, positive
from .sensors import Measurement, Sensors, encoder_readings

#: the one-line hint when MuJoCo is missing
INSTALL_HINT = "MuJoCo is not installed: pip install 'parallel-gpc[mujoco]' (or pip install mujoco)"


def import_mujoco():
    """The ``mujoco`` module, or InvalidParameterError with the install hint."""
    try:
        import mujoco
    except ImportError:
        raise InvalidParameterError(INSTALL_HINT) from None
    return mujoco


class MujocoPlant:
    """An MJCF model stepped by MuJoCo, with the plant interface of
    :class:`~parallel_gpc.estimation.MachinePlant`.

    Args:
        robot: the controller's robot (its joint names map MuJoCo's joints).
        Ts: sample time (s); each :meth:`apply` runs round(Ts / timestep) MuJoCo steps.
        X0: (2 n_y,) initial state [y, ẏ]: assembled with the robot's kinematics.
        sensors: what :meth:`measure` returns (default: encoders).
        mjcf: path of the user's MJCF (or its text), or None to export ``robot``.
        timestep: MuJoCo step of the exported model (s); default Ts / 20.
        torque_limit: drive saturation (N·m, N) of the exported motors: a number, (n_u,) values or a
            :class:`~parallel_gpc.limits.Limits` (torque only), or None.
        seed: seed of the reading noise.

    Attributes:
        mj_model, mj_data: MuJoCo's model and data. xml: the MJCF text.
    """

    def __init__(self, robot, Ts: float, X0, sensors: Sensors = Sensors(), mjcf=None, timestep: float | None = None,
                 torque_limit=None, seed: int = 0):
        mujoco = import_mujoco()
        self._mujoco = mujoco
        self.robot = robot
        self.Ts = positive("Ts", Ts, " s")
        self.sensors = sensors
        n_y = robot.n_y
        X0 = finite_vector("X0", X0, 2 * n_y)
        if mjcf is None:
            timestep = self.Ts / 20 if timestep is None else positive("timestep", timestep, " s")
            self.xml = export_mjcf(robot, timestep, torque_limit=saturation_limit(torque_limit, robot.n_u))
        else:
            path = Path(mjcf) if not str(mjcf).lstrip().startswith("<") else None
            self.xml = path.read_text() if path is not None else str(mjcf)
        self.mj_model = mujoco.MjModel.from_xml_string(self.xml)
        self.mj_data = mujoco.MjData(self.mj_model)
        self.substeps = max(1, int(round(self.Ts / self.mj_model.opt.timestep)))
        self._map_joints()
        self._resolution = sensors.resolution(robot)
        self._rates = sensors.measures_rates(robot)
        self._rng = np.random.default_rng(seed)
        q = robot.assemble(X0[:n_y])
        T, _ = robot.velocity_map(q)
        self.mj_data.qpos[self._qadr] = q[self._pin_q]
        self.mj_data.qvel[self._dadr] = (T @ X0[n_y:])[self._pin_v]
        mujoco.mj_forward(self.mj_model, self.mj_data)
        self.saturated = 0

    def _map_joints(self) -> None:
        """Index maps between Pinocchio's q, v and MuJoCo's qpos, qvel (1-DOF joints by name)."""
        mujoco, m, model = self._mujoco, self.mj_model, self.robot.model
        pin_q, pin_v, qadr, dadr = [], [], [], []
        for j in range(1, model.njoints):
            name = model.names[j]
            jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
            if jid < 0:
                raise RobotFormatError(f"the MJCF has no joint {name!r} of robot {self.robot.name!r}")
            if model.joints[j].nq != 1 or int(m.jnt_type[jid]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
                raise RobotFormatError(f"joint {name!r}: the MuJoCo plant maps 1-DOF hinge and slide joints only")
            pin_q.append(model.joints[j].idx_q)
            pin_v.append(model.joints[j].idx_v)
            qadr.append(m.jnt_qposadr[jid])
            dadr.append(m.jnt_dofadr[jid])
        self._pin_q, self._pin_v = np.array(pin_q), np.array(pin_v)
        self._qadr, self._dadr = np.array(qadr), np.array(dadr)
        act = []
        for name in self.robot.description.drive_joints:
            jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
            ids = [a for a in range(m.nu) if m.actuator_trnid[a, 0] == jid]
            if not ids:
                raise RobotFormatError(f"the MJCF has no actuator on drive joint {name!r}")
            act.append(ids[0])
        self._act = np.array(act)

    @property
    def q(self) -> np.ndarray:
        """(nq,) the configuration in Pinocchio's coordinates."""
        q = self.robot.q_home.copy()
        q[self._pin_q] = self.mj_data.qpos[self._qadr]
        return q

    @property
    def v(self) -> np.ndarray:
        """(nv,) the velocity in Pinocchio's coordinates."""
        v = np.zeros(self.robot.model.nv)
        v[self._pin_v] = self.mj_data.qvel[self._dadr]
        return v

    def true_state(self) -> np.ndarray:
        """(2 n_y,) [y, ẏ] of the simulated machine."""
        q, v = self.q, self.v
        return np.concatenate([self.robot.platform_pose(q), self.robot.output_velocity(q, v)])

    def measure(self) -> Measurement:
        if self.sensors.kind == "full":
            return Measurement(state=self.true_state())
        r = self.robot
        drives = encoder_readings(self.sensors, self._resolution, self.q[r.drive_q_indices], self._rng)
        rates = None
        if self._rates:
            rates = self.v[r.drive_idx] + self._rng.normal(0.0, self.sensors.rate_noise, r.n_u)
        return Measurement(drives=drives, rates=rates)

    def apply(self, u) -> None:
        """Hold drive efforts u (N·m, N) for one sample (MuJoCo clips to the motors' ctrlrange)."""
        u = finite_vector("drive torques u", u, self.robot.n_u)
        m, d = self.mj_model, self.mj_data
        d.ctrl[self._act] = u
        lim = m.actuator_ctrllimited[self._act].astype(bool)
        if np.any(lim):
            lo, hi = m.actuator_ctrlrange[self._act].T
            self.saturated += bool(np.any(lim & ((u < lo) | (u > hi))))
        for _ in range(self.substeps):
            self._mujoco.mj_step(m, d)
        if not (np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel))):
            raise NonFiniteError(f"the MuJoCo model diverged within one sample Ts = {self.Ts:g} s under u = "
                                 f"{u.tolist()}")

    def accelerations(self, q, v, u) -> np.ndarray:
        """(nv,) MuJoCo's constrained accelerations q̈ (Pinocchio's coordinates) at (q, v, u);
        the plant's own state is restored."""
        m, d = self.mj_model, self.mj_data
        saved = (d.qpos.copy(), d.qvel.copy(), d.ctrl.copy(), d.time)
        d.qpos[self._qadr] = np.asarray(q)[self._pin_q]
        d.qvel[self._dadr] = np.asarray(v)[self._pin_v]
        d.ctrl[self._act] = u
        self._mujoco.mj_forward(m, d)
        a = np.zeros(self.robot.model.nv)
        a[self._pin_v] = d.qacc[self._dadr]
        d.qpos[:], d.qvel[:], d.ctrl[:], d.time = saved
        self._mujoco.mj_forward(m, d)
        return a
