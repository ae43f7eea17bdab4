"""MJCF export of a loaded robot: the open tree, the loops as equality constraints, motors on the drives.

The file is for an independent physics engine (MuJoCo) to simulate the machine the controller
drives. Every joint of the Pinocchio model becomes a body (named after the joint) with its
inertia, at the joint placement in its parent body; every closure becomes
``<equality><connect site1 site2/>`` (point) or ``<weld site1 site2/>`` between two sites at
the closure frames (so MuJoCo does not infer the anchors from qpos0); every drive gets a
``<motor>`` of gear 1. Constraints are stiff (``solimp`` 0.9999, ``solref`` time constant 4
timesteps) and the timestep small (Ts / 20 by default), contacts are off.

MuJoCo refuses moving bodies without mass or inertia; the Pinocchio models have massless
intermediate bodies (e.g. the x and y slides of a planar platform), and published URDFs massless
links, so the compiler is told ``boundmass`` and ``boundinertia`` (:func:`inertia_bounds`):
``BOUND_RATIO`` = 1e-5 of the robot's largest body mass and principal moment of inertia. A fixed
1e-9 kg / 1e-12 kg·m² (before) let MuJoCo diverge on a five-bar with a massless distal link (155 mm
RMS on a hold step where our plant tracks to 5.55 mm; with the relative bounds MuJoCo gives 5.55 mm too).
"""

from __future__ import annotations

from xml.sax.saxutils import quoteattr

import numpy as np
import pinocchio as pin

from ..errors import RobotFormatError

#: MuJoCo's lower bounds on body mass and inertia of the exported model, relative to the robot's largest
BOUND_RATIO = 1e-5
#: impedance of the loop constraints (MuJoCo ``solimp``): 0.9999 of the constraint is enforced
SOLIMP = (0.9999, 0.9999, 0.001, 0.5, 2.0)
_AXES = {"X": "1 0 0", "Y": "0 1 0", "Z": "0 0 1"}


def _vec(v) -> str:
    return " ".join(repr(float(x)) for x in v)


def _quat(R: np.ndarray) -> str:
    c = pin.Quaternion(np.asarray(R)).coeffs()  # x, y, z, w
    return _vec([c[3], c[0], c[1], c[2]])


def _joint_xml(model, j: int) -> str:
    short = model.joints[j].shortname()
    name = quoteattr(model.names[j])
    for prefix, kind in (("JointModelR", "hinge"), ("JointModelP", "slide")):
        if short in (prefix + "X", prefix + "Y", prefix + "Z"):
            return f'<joint name={name} type="{kind}" axis="{_AXES[short[-1]]}"/>'
        if short in (prefix + "evoluteUnaligned", prefix + "rismaticUnaligned"):
            return f'<joint name={name} type="{kind}" axis="{_vec(model.joints[j].axis)}"/>'
    raise RobotFormatError(f"MJCF export supports 1-DOF revolute and prismatic joints; joint {model.names[j]!r} "
                           f"is a {short}")


def inertia_bounds(model) -> tuple[float, float]:
    """(boundmass in kg, boundinertia in kg·m²) of a Pinocchio model's export: BOUND_RATIO of its largest body
    mass and of its largest principal moment of inertia (about the body's centre of mass)."""
    bodies = [model.inertias[j] for j in range(1, model.njoints)]
    mass = max((b.mass for b in bodies), default=1.0)
    moment = max((float(np.linalg.eigvalsh(b.inertia)[-1]) for b in bodies), default=1.0)
    return BOUND_RATIO * (mass if mass > 0 else 1.0), BOUND_RATIO * (moment if moment > 0 else 1.0)


def export_mjcf(robot, timestep: float = 1e-4, solref_steps: float = 4.0, torque_limit=None) -> str:
    """MJCF text of ``robot`` (see the module docstring).

    Args:
        robot: a :class:`~parallel_gpc.model.robot.ParallelRobot`.
        timestep: MuJoCo's integration step (s).
        solref_steps: time constant of the constraints' stabilization, in timesteps (≥ 2).
        torque_limit: (n_u,) or scalar motor limit (N·m, N) as ``ctrlrange``, or None (unlimited).

    Returns:
        The MJCF document; joints keep the model's names, bodies are named after their joint,
        sites ``<frame>`` at the closure frames, motors ``motor_<drive joint>``.
    """
    model = robot.model
    nj = model.njoints
    children = {j: [] for j in range(nj)}
    for j in range(1, nj):
        children[model.parents[j]].append(j)
    sites: dict[int, list[tuple[str, pin.SE3]]] = {j: [] for j in range(nj)}
    used = set()
    for fa, fb, _ in robot.closure_frames:
        for f in (fa, fb):
            if f not in used:
                used.add(f)
                frame = model.frames[f]
                sites[frame.parentJoint].append((frame.name, frame.placement))

    def site_lines(j: int, indent: str) -> list[str]:
        return [f'{indent}<site name={quoteattr(n)} pos="{_vec(M.translation)}" quat="{_quat(M.rotation)}"/>'
                for n, M in sites[j]]

    def body(j: int, indent: str) -> list[str]:
        M = model.jointPlacements[j]
        inertia = model.inertias[j]
        I = inertia.inertia
        lines = [f'{indent}<body name={quoteattr(model.names[j])} pos="{_vec(M.translation)}" quat="{_quat(M.rotation)}">',
                 f"{indent}  {_joint_xml(model, j)}"]
        if inertia.mass > 0:
            full = [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]
            lines.append(f'{indent}  <inertial pos="{_vec(inertia.lever)}" mass="{float(inertia.mass)!r}" '
                         f'fullinertia="{_vec(full)}"/>')
        lines += site_lines(j, indent + "  ")
        for c in children[j]:
            lines += body(c, indent + "  ")
        lines.append(f"{indent}</body>")
        return lines

    solref = f"{solref_steps * timestep!r} 1"
    solimp = _vec(SOLIMP)
    eq = []
    for fa, fb, c in robot.closure_frames:
        tag = "connect" if c.kind == "point" else "weld"
        eq.append(f'    <{tag} name={quoteattr(c.name)} site1={quoteattr(model.frames[fa].name)} '
                  f'site2={quoteattr(model.frames[fb].name)} solref="{solref}" solimp="{solimp}"/>')
    limits = None if torque_limit is None else np.broadcast_to(np.asarray(torque_limit, dtype=float), (robot.n_u,))
    motors = []
    for i, name in enumerate(robot.description.drive_joints):
        rng = "" if limits is None else f' ctrllimited="true" ctrlrange="{_vec([-limits[i], limits[i]])}"'
        motors.append(f'    <motor name={quoteattr("motor_" + name)} joint={quoteattr(name)} gear="1"{rng}/>')
    world = []
    world += site_lines(0, "    ")
    for c in children[0]:
        world += body(c, "    ")
    bound_mass, bound_inertia = inertia_bounds(model)
    return "\n".join([
        f"<mujoco model={quoteattr(robot.name)}>",
        f'  <compiler angle="radian" inertiafromgeom="false" boundmass="{bound_mass!r}" '
        f'boundinertia="{bound_inertia!r}" autolimits="true"/>',
        f'  <option timestep="{timestep!r}" integrator="RK4" gravity="{_vec(model.gravity.linear)}" '
        'tolerance="1e-12" iterations="100">',
        '    <flag contact="disable"/>',
        "  </option>",
        "  <worldbody>", *world, "  </worldbody>",
        "  <equality>", *eq, "  </equality>",
        "  <actuator>", *motors, "  </actuator>",
        "</mujoco>", ""])
