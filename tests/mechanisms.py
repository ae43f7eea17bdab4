"""Small test mechanisms written to a folder: a planar 5-bar (URDF and MJCF) and a spatial
3-RPS (one spherical joint, or three revolute joints through one point), plus the oracles
shared by the model tests (Pinocchio's constraintDynamics, finite differences)."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

# ---------------------------------------------------------------- planar 5-bar in the x-z plane
#: base pivots (x, m), link lengths (m), masses (kg) and the home end-effector (x, z) (m).
FIVEBAR_BASE = (-0.2, 0.2)
L_PROX, L_DIST = 0.3, 0.35
M_PROX, M_DIST = 1.0, 0.8
FIVEBAR_HOME = (0.02, 0.5)


def _two_link_ik(base_x: float, target, elbow: float) -> tuple[float, float]:
    """Angles (a, e) about +y of a 2R chain from (base_x, 0) to target (x, z), links along z at 0."""
    dx, dz = target[0] - base_x, target[1]
    r = math.hypot(dx, dz)
    c = (r * r - L_PROX ** 2 - L_DIST ** 2) / (2 * L_PROX * L_DIST)
    e = elbow * math.acos(c)
    # rotation about y by t maps (0, 0, L) to (L sin t, 0, L cos t)
    a = math.atan2(dx, dz) - math.atan2(L_DIST * math.sin(e), L_PROX + L_DIST * math.cos(e))
    return a, e


def fivebar_q_guess(target=FIVEBAR_HOME) -> dict:
    a1, e1 = _two_link_ik(FIVEBAR_BASE[0], target, -1.0)
    a2, e2 = _two_link_ik(FIVEBAR_BASE[1], target, 1.0)
    return {"a1": a1, "e1": e1, "a2": a2, "e2": e2}


def _rod_inertia(mass: float, length: float) -> str:
    i = mass * length ** 2 / 12.0
    return f'ixx="{i:.9g}" ixy="0" ixz="0" iyy="{i:.9g}" iyz="0" izz="{1e-4 * mass:.9g}"'


def fivebar_urdf() -> str:
    legs = []
    for k, bx in zip((1, 2), FIVEBAR_BASE):
        legs.append(f"""
  <joint name="a{k}" type="revolute"><parent link="base"/><child link="prox{k}"/>
    <origin xyz="{bx} 0 0"/><axis xyz="0 1 0"/><limit lower="-6" upper="6" effort="10" velocity="10"/></joint>
  <link name="prox{k}"><inertial><origin xyz="0 0 {L_PROX / 2}"/><mass value="{M_PROX}"/>
    <inertia {_rod_inertia(M_PROX, L_PROX)}/></inertial></link>
  <joint name="e{k}" type="revolute"><parent link="prox{k}"/><child link="dist{k}"/>
    <origin xyz="0 0 {L_PROX}"/><axis xyz="0 1 0"/><limit lower="-6" upper="6" effort="10" velocity="10"/></joint>
  <link name="dist{k}"><inertial><origin xyz="0 0 {L_DIST / 2}"/><mass value="{M_DIST}"/>
    <inertia {_rod_inertia(M_DIST, L_DIST)}/></inertial></link>
  <joint name="tip{k}_joint" type="fixed"><parent link="dist{k}"/><child link="{'ee' if k == 1 else 'tip2'}"/>
    <origin xyz="0 0 {L_DIST}"/></joint>
  <link name="{'ee' if k == 1 else 'tip2'}"/>""")
    return f'<?xml version="1.0"?>\n<robot name="fivebar">\n  <link name="base"/>{"".join(legs)}\n</robot>\n'


def fivebar_sidecar(drives=("a1", "a2"), axes=("x", "z"), extra: str = "", closures: bool = True) -> str:
    q = fivebar_q_guess()
    text = (f'name = "fivebar"\n{extra}'
            f'[output]\nframe = "ee"\nkind = "position"\naxes = {list(axes)!r}\n'
            f'[home]\nbranch_joints = ["e1", "e2"]\n[home.q_guess]\n'
            + "".join(f"{k} = {v!r}\n" for k, v in q.items())
            + f"[drives]\njoints = {list(drives)!r}\ntorque_limit = 20.0\n")
    if closures:
        text += '[[closures]]\nname = "close"\nkind = "point"\nframes = ["ee", "tip2"]\n'
    return text.replace("'", '"')


def _quat_y(angle: float) -> str:
    """MJCF quaternion (w x y z) of a rotation about +y."""
    return f"{math.cos(angle / 2):.15g} 0 {math.sin(angle / 2):.15g} 0"


def fivebar_mjcf() -> str:
    """The same 5-bar as MJCF, drawn assembled at the home pose (MuJoCo's loops hold at qpos0, so
    the joint angles are measured from home), both legs under one root body, the loop as an
    equality connect."""
    q = fivebar_q_guess()
    ip, idd = M_PROX * L_PROX ** 2 / 12.0, M_DIST * L_DIST ** 2 / 12.0
    legs = []
    for k, bx in zip((1, 2), FIVEBAR_BASE):
        site = f'<site name="ee" pos="0 0 {L_DIST}"/>' if k == 1 else ""
        legs.append(f"""
      <body name="prox{k}" pos="{bx} 0 0" quat="{_quat_y(q[f"a{k}"])}">
        <joint name="a{k}" type="hinge" axis="0 1 0"/>
        <inertial pos="0 0 {L_PROX / 2}" mass="{M_PROX}" diaginertia="{ip:.9g} {ip:.9g} {1e-4 * M_PROX:.9g}"/>
        <body name="dist{k}" pos="0 0 {L_PROX}" quat="{_quat_y(q[f"e{k}"])}">
          <joint name="e{k}" type="hinge" axis="0 1 0"/>
          <inertial pos="0 0 {L_DIST / 2}" mass="{M_DIST}" diaginertia="{idd:.9g} {idd:.9g} {1e-4 * M_DIST:.9g}"/>
          {site}
        </body>
      </body>""")
    return (f'<mujoco model="fivebar">\n  <worldbody>\n    <body name="base">{"".join(legs)}\n    </body>\n'
            f'  </worldbody>\n  <equality>\n    <connect name="close" body1="dist1" body2="dist2" '
            f'anchor="0 0 {L_DIST}"/>\n  </equality>\n</mujoco>\n')


def fivebar_mjcf_sidecar() -> str:
    return ('name = "fivebar_mjcf"\n[output]\nframe = "ee"\nkind = "position"\naxes = ["x", "z"]\n'
            '[drives]\njoints = ["a1", "a2"]\n')


# ---------------------------------------------------------------- spatial 3-RPS
RB, RP, H = 0.3, 0.2, 0.5  # base / platform radii, home height (m)
M_LOWER, M_UPPER, M_PLAT = 0.5, 0.4, 2.0


def _xyz_rpy(M: pin.SE3) -> str:
    t, r = M.translation, pin.rpy.matrixToRpy(M.rotation)
    return f'xyz="{t[0]:.12g} {t[1]:.12g} {t[2]:.12g}" rpy="{r[0]:.12g} {r[1]:.12g} {r[2]:.12g}"'


def rps_urdf(spherical: bool, universal_base: bool = False) -> str:
    """3-RPS: revolute base joints (tangent axes), prismatic legs, platform on leg 1's spherical
    joint (one placeholder joint ``s1``, or revolute ``s1x``-``s1y``-``s1z`` through one point);
    legs 2 and 3 close on the platform by point closures (ideal spherical joints)."""
    tilt = -math.atan2(RB - RP, H)
    length = math.hypot(RB - RP, H)
    parts = ['<?xml version="1.0"?>\n<robot name="rps">\n  <link name="base"/>']
    s1_world = None
    for k in range(3):
        alpha = 2 * math.pi * k / 3
        base = pin.SE3(pin.rpy.rpyToMatrix(0, 0, alpha), np.array([RB * math.cos(alpha), RB * math.sin(alpha), 0]))
        parts.append(f"""
  <joint name="r{k + 1}" type="revolute"><parent link="base"/><child link="lower{k + 1}"/>
    <origin {_xyz_rpy(base)}/><axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="0" velocity="9"/></joint>
  <link name="lower{k + 1}"><inertial><origin xyz="0 0 0.1"/><mass value="{M_LOWER}"/>
    <inertia ixx="0.003" ixy="0" ixz="0" iyy="0.003" iyz="0" izz="0.0002"/></inertial></link>
  <joint name="p{k + 1}" type="prismatic"><parent link="lower{k + 1}"/><child link="upper{k + 1}"/>
    <origin xyz="0 0 0"/><axis xyz="0 0 1"/><limit lower="0" upper="1" effort="50" velocity="1"/></joint>
  <link name="upper{k + 1}"><inertial><origin xyz="0 0 -0.1"/><mass value="{M_UPPER}"/>
    <inertia ixx="0.002" ixy="0" ixz="0" iyy="0.002" iyz="0" izz="0.0001"/></inertial></link>
  <joint name="tip{k + 1}_joint" type="fixed"><parent link="upper{k + 1}"/><child link="tip{k + 1}"/>
    <origin xyz="0 0 0"/></joint>
  <link name="tip{k + 1}"/>""")
        if k == 0:
            s1_world = base * pin.SE3(pin.rpy.rpyToMatrix(0, tilt, 0), np.zeros(3)) * pin.SE3(np.eye(3), np.array([0, 0, length]))
    if spherical:
        parts.append("""
  <joint name="s1" type="revolute"><parent link="tip1"/><child link="plat"/><origin xyz="0 0 0"/>
    <axis xyz="1 0 0"/><limit lower="-3" upper="3" effort="0" velocity="9"/></joint>""")
    else:
        parts.append("""
  <joint name="s1x" type="revolute"><parent link="tip1"/><child link="g1"/><axis xyz="1 0 0"/>
    <limit lower="-3" upper="3" effort="0" velocity="9"/></joint><link name="g1"/>
  <joint name="s1y" type="revolute"><parent link="g1"/><child link="g2"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3" effort="0" velocity="9"/></joint><link name="g2"/>
  <joint name="s1z" type="revolute"><parent link="g2"/><child link="plat"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="0" velocity="9"/></joint>""")
    centre = s1_world.inverse() * pin.SE3(np.eye(3), np.array([0, 0, H]))  # platform centre in s1's frame
    parts.append(f"""
  <link name="plat"><inertial><origin {_xyz_rpy(centre)}/><mass value="{M_PLAT}"/>
    <inertia ixx="0.02" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.04"/></inertial></link>
  <joint name="platform_joint" type="fixed"><parent link="plat"/><child link="platform"/><origin {_xyz_rpy(centre)}/></joint>
  <link name="platform"/>""")
    for k in (1, 2):
        alpha = 2 * math.pi * k / 3
        parts.append(f"""
  <joint name="attach{k + 1}_joint" type="fixed"><parent link="platform"/><child link="attach{k + 1}"/>
    <origin xyz="{RP * math.cos(alpha):.12g} {RP * math.sin(alpha):.12g} 0"/></joint>
  <link name="attach{k + 1}"/>""")
    parts.append("\n</robot>\n")
    return "".join(parts)


def rps_sidecar(spherical: bool, axes=("z", "rx", "ry"), joint_types: dict | None = None,
                drives=("p1", "p2", "p3")) -> str:
    """Gepetto-style YAML sidecar of :func:`rps_urdf`."""
    tilt = -math.atan2(RB - RP, H)
    length = math.hypot(RB - RP, H)
    types = dict(joint_types or {})
    guess = {f"r{k}": [tilt, 0.0] if types.get(f"r{k}") == "UJOINT" else tilt for k in (1, 2, 3)}
    guess |= {f"p{k}": length for k in (1, 2, 3)}
    if spherical:
        types["s1"] = "SPHERICAL"
    return ("closed_loop: [[tip2, attach2], [tip3, attach3]]\ntype: [3D, 3D]\n"
            f"name_mot: {list(drives)}\njoint_name: {list(types)}\njoint_type: {list(types.values())}\n"
            f"output: {{frame: platform, kind: pose, axes: {list(axes)}}}\n"
            f"home: {{q_guess: {guess}}}\n").replace("'", "")


def _mj_quat(R: np.ndarray) -> str:
    x, y, z, w = pin.Quaternion(R).coeffs()
    return f"{w:.15g} {x:.15g} {y:.15g} {z:.15g}"


def rps_mjcf() -> str:
    """The 3-RPS of :func:`rps_urdf` as MJCF, drawn assembled at home (joint values measured
    from home): hinge-slide legs, a ``ball`` joint carrying the platform on leg 1, the other
    legs closed on the platform by equality connects."""
    tilt = -math.atan2(RB - RP, H)
    length = math.hypot(RB - RP, H)
    legs = []
    for k in range(3):
        alpha = 2 * math.pi * k / 3
        R = pin.rpy.rpyToMatrix(0, 0, alpha) @ pin.rpy.rpyToMatrix(0, tilt, 0)
        platform = ""
        if k == 0:
            platform = f"""
          <body name="platform_body" quat="{_mj_quat(R.T)}">
            <joint name="s1" type="ball"/>
            <inertial pos="{-RP} 0 0" mass="{M_PLAT}" diaginertia="0.02 0.02 0.04"/>
            <site name="platform" pos="{-RP} 0 0"/>
          </body>"""
        legs.append(f"""
      <body name="lower{k + 1}" pos="{RB * math.cos(alpha):.15g} {RB * math.sin(alpha):.15g} 0" quat="{_mj_quat(R)}">
        <joint name="r{k + 1}" type="hinge" axis="0 1 0"/>
        <inertial pos="0 0 0.1" mass="{M_LOWER}" diaginertia="0.003 0.003 0.0002"/>
        <body name="upper{k + 1}" pos="0 0 {length:.15g}">
          <joint name="p{k + 1}" type="slide" axis="0 0 1"/>
          <inertial pos="0 0 -0.1" mass="{M_UPPER}" diaginertia="0.002 0.002 0.0001"/>{platform}
        </body>
      </body>""")
    return ('<mujoco model="rps">\n  <worldbody>\n    <body name="base">' + "".join(legs)
            + '\n    </body>\n  </worldbody>\n  <equality>\n'
            + '    <connect body1="upper2" body2="platform_body" anchor="0 0 0"/>\n'
            + '    <connect body1="upper3" body2="platform_body" anchor="0 0 0"/>\n  </equality>\n</mujoco>\n')


def rps_mjcf_sidecar() -> str:
    return ('name = "rps_mjcf"\n[output]\nframe = "platform"\nkind = "pose"\naxes = ["z", "rx", "ry"]\n'
            '[drives]\njoints = ["p1", "p2", "p3"]\n')


def write(tmp_path, stem: str, model: str, sidecar: str, model_suffix: str = ".urdf",
          sidecar_suffix: str = ".toml"):
    """Write ``stem`` + suffixes to ``tmp_path``; returns the model file's path."""
    path = tmp_path / f"{stem}{model_suffix}"
    path.write_text(model)
    (tmp_path / f"{stem}{sidecar_suffix}").write_text(sidecar)
    return path


# ---------------------------------------------------------------- oracles
_CONTACT = {"point": pin.ContactType.CONTACT_3D, "weld": pin.ContactType.CONTACT_6D}


def closure_constraint_models(robot):
    """RigidConstraintModels of the robot's closures (LOCAL, between the closure frames)."""
    model = robot.model
    cms = []
    for fa, fb, c in robot.closure_frames:
        a, b = model.frames[fa], model.frames[fb]
        cms.append(pin.RigidConstraintModel(_CONTACT[c.kind], model, a.parentJoint, a.placement,
                                            b.parentJoint, b.placement, pin.ReferenceFrame.LOCAL))
    return cms


def constraint_dynamics(model, q, v, tau, cms) -> np.ndarray:
    """(nv,) q̈ from ``pin.constraintDynamics`` (tight proximal settings)."""
    data = model.createData()
    cm_vec, cd_vec = pin.StdVec_RigidConstraintModel(), pin.StdVec_RigidConstraintData()
    for cm in cms:
        cm_vec.append(cm)
        cd_vec.append(cm.createData())
    pin.initConstraintDynamics(model, data, cm_vec, cd_vec)
    return pin.constraintDynamics(model, data, q, v, tau, cm_vec, cd_vec, pin.ProximalSettings(1e-14, 1e-12, 200))


def output_acceleration(robot, q, v, a, eps: float = 1e-5) -> np.ndarray:
    """(n_y,) ÿ = d²/dt² y(q ⊕ (t v + ½ t² a)) at t = 0, by central differences of forward kinematics."""
    y = [robot.platform_pose(robot.integrate(q, t * v + 0.5 * t * t * a)) for t in (-eps, 0.0, eps)]
    return (y[0] - 2 * y[1] + y[2]) / eps ** 2


def random_output_states(robot, rng, n: int, spread: float = 0.03, speed: float = 0.3):
    """n reachable states X = [y, ẏ] near home: y = home ± spread (m or rad), |ẏ| ≤ speed."""
    return [np.concatenate([robot.home_pose + rng.uniform(-spread, spread, robot.n_y),
                            rng.uniform(-speed, speed, robot.n_y)]) for _ in range(n)]


def output_acceleration_of(robot, q, v, ddq) -> np.ndarray:
    """(n_y,) ÿ of a full motion (q, v, q̈) from Pinocchio's frame accelerations: the classical
    linear acceleration of the output frame, and θ̈ = Jlog₃ ω̇ + Hlog₃(R_rel, ω) ω for the
    rotation vector (ω, ω̇ in the frame); joint outputs are rows of q̈."""
    if robot.task_output is None:
        return ddq[robot.y_idx]
    model, data, fid = robot.model, robot.model.createData(), robot.output_frame_id
    pin.forwardKinematics(model, data, q, v, ddq)
    pin.updateFramePlacements(model, data)
    lin = pin.getFrameClassicalAcceleration(model, data, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED).linear
    w = pin.getFrameVelocity(model, data, fid, pin.ReferenceFrame.LOCAL).angular
    dw = pin.getFrameAcceleration(model, data, fid, pin.ReferenceFrame.LOCAL).angular
    R_rel = robot.task_output.R_ref.T @ data.oMf[fid].rotation
    ang = pin.Jlog3(R_rel) @ dw + pin.Hlog3(R_rel, w) @ w
    return np.concatenate([lin, ang])[robot.task_output.rows]


def assert_reduced_matches_constraint_dynamics(robot, cms=None, n: int = 8, seed: int = 0) -> None:
    """Reduced ÿ (and q̈ = T ÿ + ℓ) equal ``pin.constraintDynamics`` to 1e-8 relative at random
    reachable states and inputs near home; ÿ_full = H q̈ + Ḣ v is the oracle's output acceleration."""
    from parallel_gpc import ReducedModel

    model = ReducedModel(robot)
    rng = np.random.default_rng(seed)
    cms = closure_constraint_models(robot) if cms is None else cms
    for X in random_output_states(robot, rng, n):
        u = rng.uniform(-5, 5, robot.n_u)
        terms = model.terms(X)
        assert np.max(np.abs(robot.closure_residual(terms.q))) <= 1e-10
        np.testing.assert_allclose(robot.platform_pose(terms.q), X[:robot.n_y], atol=1e-11)
        ydd = terms.acceleration(u)
        ddq = constraint_dynamics(robot.model, terms.q, terms.v, robot.drive_selection @ u, cms)
        assert np.linalg.norm(ddq - (terms.T @ ydd + terms.ell)) <= 1e-8 * np.linalg.norm(ddq)
        y_oracle = output_acceleration_of(robot, terms.q, terms.v, ddq)
        assert np.linalg.norm(y_oracle - ydd) <= 1e-8 * np.linalg.norm(ydd)
