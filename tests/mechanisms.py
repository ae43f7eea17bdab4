"""Small test mechanisms written to a folder: a planar 5-bar (URDF and MJCF) and a spatial
3-RPS (one spherical joint, or three revolute joints through one point), plus the oracles
shared by the model tests (Pinocchio's constraintDynamics, finite differences)."""

from __future__ import annotations

import math
from pathlib import Path

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


def fivebar_q_guess(target=FIVEBAR_HOME, split: bool = False) -> dict:
    """Joint angles (rad) at ``target``; ``split`` adds the hinge ``c`` of :func:`fivebar_urdf`."""
    a1, e1 = _two_link_ik(FIVEBAR_BASE[0], target, -1.0)
    a2, e2 = _two_link_ik(FIVEBAR_BASE[1], target, 1.0)
    q = {"a1": a1, "e1": e1, "a2": a2, "e2": e2}
    if split:  # the outer half of distal link 2 points from the end-effector back to elbow 2
        q["c"] = math.remainder(a2 + e2 + math.pi - a1 - e1, 2 * math.pi)
    return q


def _rod_inertia(mass: float, length: float) -> str:
    i = mass * length ** 2 / 12.0
    return f'ixx="{i:.9g}" ixy="0" ixz="0" iyy="{i:.9g}" iyz="0" izz="{1e-4 * mass:.9g}"'


def _half_distal(mjcf: bool) -> str:
    """Inertial element of half a distal link (URDF or MJCF): mass, centre and inertia of the half rod."""
    m, h = M_DIST / 2, L_DIST / 2
    if mjcf:
        i = m * h ** 2 / 12.0
        return f'<inertial pos="0 0 {h / 2}" mass="{m}" diaginertia="{i:.9g} {i:.9g} {1e-4 * m:.9g}"/>'
    return f'<inertial><origin xyz="0 0 {h / 2}"/><mass value="{m}"/><inertia {_rod_inertia(m, h)}/></inertial>'


def fivebar_urdf(split: bool = False) -> str:
    """Planar 5-bar, legs ``a<k>``-``e<k>``, closed by a point closure ``ee``-``tip2``. ``split``:
    distal link 2 is cut at its middle, its outer half ``dist2b`` hangs on a hinge ``c`` at the
    end-effector and the loop closes by welding the halves (frames ``mid_a``, ``mid_b``, equal
    poses at assembly): the same mechanism, masses and inertias (two half rods make the rod)."""
    legs = []
    for k, bx in zip((1, 2), FIVEBAR_BASE):
        half = split and k == 2
        dist = _half_distal(False) if half else (f'<inertial><origin xyz="0 0 {L_DIST / 2}"/><mass value="{M_DIST}"/>'
                                                 f'\n    <inertia {_rod_inertia(M_DIST, L_DIST)}/></inertial>')
        tip, tip_z = ("mid_a", L_DIST / 2) if half else ("ee" if k == 1 else "tip2", L_DIST)
        legs.append(f"""
  <joint name="a{k}" type="revolute"><parent link="base"/><child link="prox{k}"/>
    <origin xyz="{bx} 0 0"/><axis xyz="0 1 0"/><limit lower="-6" upper="6" effort="10" velocity="10"/></joint>
  <link name="prox{k}"><inertial><origin xyz="0 0 {L_PROX / 2}"/><mass value="{M_PROX}"/>
    <inertia {_rod_inertia(M_PROX, L_PROX)}/></inertial></link>
  <joint name="e{k}" type="revolute"><parent link="prox{k}"/><child link="dist{k}"/>
    <origin xyz="0 0 {L_PROX}"/><axis xyz="0 1 0"/><limit lower="-6" upper="6" effort="10" velocity="10"/></joint>
  <link name="dist{k}">{dist}</link>
  <joint name="tip{k}_joint" type="fixed"><parent link="dist{k}"/><child link="{tip}"/>
    <origin xyz="0 0 {tip_z}"/></joint>
  <link name="{tip}"/>""")
    if split:
        legs.append(f"""
  <joint name="c" type="revolute"><parent link="ee"/><child link="dist2b"/>
    <axis xyz="0 1 0"/><limit lower="-6" upper="6" effort="10" velocity="10"/></joint>
  <link name="dist2b">{_half_distal(False)}</link>
  <joint name="mid_b_joint" type="fixed"><parent link="dist2b"/><child link="mid_b"/>
    <origin xyz="0 0 {L_DIST / 2}" rpy="0 {math.pi!r} 0"/></joint>
  <link name="mid_b"/>""")
    return f'<?xml version="1.0"?>\n<robot name="fivebar">\n  <link name="base"/>{"".join(legs)}\n</robot>\n'


def fivebar_sidecar(drives=("a1", "a2"), axes=("x", "z"), extra: str = "", closures: bool = True,
                    split: bool = False) -> str:
    """TOML sidecar of :func:`fivebar_urdf` (``split``: the weld closure of the split variant)."""
    q = fivebar_q_guess(split=split)
    text = (f'name = "fivebar"\n{extra}'
            f'[output]\nframe = "ee"\nkind = "position"\naxes = {list(axes)!r}\n'
            f'[home]\nbranch_joints = ["e1", "e2"]\n[home.q_guess]\n'
            + "".join(f"{k} = {v!r}\n" for k, v in q.items())
            + f"[drives]\njoints = {list(drives)!r}\ntorque_limit = 20.0\n")
    if closures:
        kind, frames = ("weld", '["mid_a", "mid_b"]') if split else ("point", '["ee", "tip2"]')
        text += f'[[closures]]\nname = "close"\nkind = "{kind}"\nframes = {frames}\n'
    return text.replace("'", '"')


def _quat_y(angle: float) -> str:
    """MJCF quaternion (w x y z) of a rotation about +y."""
    return f"{math.cos(angle / 2):.15g} 0 {math.sin(angle / 2):.15g} 0"


def fivebar_mjcf(split: bool = False, ref: bool = False) -> str:
    """The same 5-bar as MJCF, drawn assembled at the home pose (MuJoCo's loops hold at qpos0, so
    the joint angles are measured from home), both legs under one root body, the loop as an
    equality connect; ``split``: as :func:`fivebar_urdf`, the halves of distal link 2 held by an
    equality weld (relative pose of qpos0). ``ref``: the joints say their angle in the drawing
    (``ref``, rad): qpos0 is the URDF's home configuration and q = 0 has every link upright,
    the legs stretched and the loop open by 0.4 m."""
    q = fivebar_q_guess(split=split)
    refs = {name: f' ref="{value:.15g}"' if ref else "" for name, value in q.items()}
    ip, idd = M_PROX * L_PROX ** 2 / 12.0, M_DIST * L_DIST ** 2 / 12.0
    legs = []
    for k, bx in zip((1, 2), FIVEBAR_BASE):
        site = f'<site name="ee" pos="0 0 {L_DIST}"/>' if k == 1 else ""
        dist = f'<inertial pos="0 0 {L_DIST / 2}" mass="{M_DIST}" diaginertia="{idd:.9g} {idd:.9g} {1e-4 * M_DIST:.9g}"/>'
        if split and k == 1:
            site += f"""
          <body name="dist2b" pos="0 0 {L_DIST}" quat="{_quat_y(q["c"])}">
            <joint name="c" type="hinge" axis="0 1 0"{refs["c"]}/>
            {_half_distal(True)}
          </body>"""
        elif split:
            dist = _half_distal(True)
        legs.append(f"""
      <body name="prox{k}" pos="{bx} 0 0" quat="{_quat_y(q[f"a{k}"])}">
        <joint name="a{k}" type="hinge" axis="0 1 0"{refs[f"a{k}"]}/>
        <inertial pos="0 0 {L_PROX / 2}" mass="{M_PROX}" diaginertia="{ip:.9g} {ip:.9g} {1e-4 * M_PROX:.9g}"/>
        <body name="dist{k}" pos="0 0 {L_PROX}" quat="{_quat_y(q[f"e{k}"])}">
          <joint name="e{k}" type="hinge" axis="0 1 0"{refs[f"e{k}"]}/>
          {dist}
          {site}
        </body>
      </body>""")
    loop = ('<weld name="close" body1="dist2" body2="dist2b"/>' if split
            else f'<connect name="close" body1="dist1" body2="dist2" anchor="0 0 {L_DIST}"/>')
    compiler = '  <compiler angle="radian"/>\n' if ref else ""
    return (f'<mujoco model="fivebar">\n{compiler}  <worldbody>\n    <body name="base">{"".join(legs)}\n    </body>\n'
            f'  </worldbody>\n  <equality>\n    {loop}\n  </equality>\n</mujoco>\n')


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
    parts.append(platform_links("plat", centre, M_PLAT, 'ixx="0.02" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.04"',
                                RP, [(k + 1, 2 * math.pi * k / 3) for k in (1, 2)]))
    return "".join(parts)


def platform_links(body: str, centre: pin.SE3, mass: float, inertia: str, radius: float, attach) -> str:
    """End of a URDF: link ``body`` (its centre of mass and the frame ``platform`` at ``centre``
    in the body's frame), frames ``attach<k>`` at (radius cos a, radius sin a, 0) in ``platform``
    for (k, a) in ``attach`` (m, rad), and ``</robot>``."""
    parts = [f"""
  <link name="{body}"><inertial><origin {_xyz_rpy(centre)}/><mass value="{mass}"/>
    <inertia {inertia}/></inertial></link>
  <joint name="platform_joint" type="fixed"><parent link="{body}"/><child link="platform"/><origin {_xyz_rpy(centre)}/></joint>
  <link name="platform"/>"""]
    for k, a in attach:
        parts.append(f"""
  <joint name="attach{k}_joint" type="fixed"><parent link="platform"/><child link="attach{k}"/>
    <origin xyz="{radius * math.cos(a):.12g} {radius * math.sin(a):.12g} 0"/></joint>
  <link name="attach{k}"/>""")
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


def rps_mjcf(geoms: bool = False) -> str:
    """The 3-RPS of :func:`rps_urdf` as MJCF, drawn assembled at home (joint values measured
    from home): hinge-slide legs, a ``ball`` joint carrying the platform on leg 1, the other
    legs closed on the platform by equality connects. ``geoms``: with ``<geom>`` shapes (leg
    cylinders ``cyl<k>``, ``rod<k>``, a ball ``ball1`` at s1, a box ``plate`` at the platform
    centre) besides the explicit inertias."""
    tilt = -math.atan2(RB - RP, H)
    length = math.hypot(RB - RP, H)
    legs = []
    for k in range(3):
        alpha = 2 * math.pi * k / 3
        R = pin.rpy.rpyToMatrix(0, 0, alpha) @ pin.rpy.rpyToMatrix(0, tilt, 0)
        shapes = dict.fromkeys(("plate", "cyl", "rod"), "")
        if geoms:
            shapes = {"cyl": f'\n        <geom name="cyl{k + 1}" type="cylinder" size="0.025 0.1" pos="0 0 0.1"/>',
                      "rod": f'\n          <geom name="rod{k + 1}" type="cylinder" size="0.015 0.1" pos="0 0 -0.1"/>',
                      "plate": f'\n            <geom name="plate" type="box" size="0.12 0.1 0.01" pos="{-RP} 0 0"/>'
                               '\n            <geom name="ball1" type="sphere" size="0.03"/>'}
        platform = ""
        if k == 0:
            platform = f"""
          <body name="platform_body" quat="{_mj_quat(R.T)}">
            <joint name="s1" type="ball"/>
            <inertial pos="{-RP} 0 0" mass="{M_PLAT}" diaginertia="0.02 0.02 0.04"/>
            <site name="platform" pos="{-RP} 0 0"/>{shapes['plate']}
          </body>"""
        legs.append(f"""
      <body name="lower{k + 1}" pos="{RB * math.cos(alpha):.15g} {RB * math.sin(alpha):.15g} 0" quat="{_mj_quat(R)}">
        <joint name="r{k + 1}" type="hinge" axis="0 1 0"/>
        <inertial pos="0 0 0.1" mass="{M_LOWER}" diaginertia="0.003 0.003 0.0002"/>{shapes['cyl']}
        <body name="upper{k + 1}" pos="0 0 {length:.15g}">
          <joint name="p{k + 1}" type="slide" axis="0 0 1"/>
          <inertial pos="0 0 -0.1" mass="{M_UPPER}" diaginertia="0.002 0.002 0.0001"/>{shapes['rod']}{platform}
        </body>
      </body>""")
    return ('<mujoco model="rps">\n  <worldbody>\n    <body name="base">' + "".join(legs)
            + '\n    </body>\n  </worldbody>\n  <equality>\n'
            + '    <connect body1="upper2" body2="platform_body" anchor="0 0 0"/>\n'
            + '    <connect body1="upper3" body2="platform_body" anchor="0 0 0"/>\n  </equality>\n</mujoco>\n')


def rps_mjcf_sidecar() -> str:
    return ('name = "rps_mjcf"\n[output]\nframe = "platform"\nkind = "pose"\naxes = ["z", "rx", "ry"]\n'
            '[drives]\njoints = ["p1", "p2", "p3"]\n')


# ---------------------------------------------------------------- mesh visuals
#: OBJ of a unit box from x = 0 to 1 (y, z in ±0.5): a link along x once scaled.
BOX_OBJ = ("".join(f"v {x} {y} {z}\n" for x in (0, 1) for y in (-0.5, 0.5) for z in (-0.5, 0.5))
           + "f 1 2 4 3\nf 5 7 8 6\nf 1 5 6 2\nf 3 4 8 7\nf 1 3 7 5\nf 2 6 8 4\n")


def prism_stl(sides: int = 6) -> str:
    """ASCII STL of a closed prism: a regular polygon of radius 1 in the x-y plane, z in ±0.5."""
    a = np.linspace(0.0, 2 * np.pi, sides, endpoint=False)
    top = np.column_stack([np.cos(a), np.sin(a), np.full(sides, 0.5)])
    bottom = top * [1.0, 1.0, -1.0]
    facets = []
    for i in range(sides):
        j = (i + 1) % sides
        facets += [([0, 0, 0.5], top[i], top[j]), ([0, 0, -0.5], bottom[j], bottom[i]),
                   (bottom[i], bottom[j], top[j]), (bottom[i], top[j], top[i])]
    lines = ["solid prism"]
    for facet in facets:
        p = np.array(facet, dtype=float)
        n = np.cross(p[1] - p[0], p[2] - p[0])
        n /= np.linalg.norm(n)
        lines += [f"facet normal {n[0]:.9g} {n[1]:.9g} {n[2]:.9g}", " outer loop"]
        lines += [f"  vertex {v[0]:.9g} {v[1]:.9g} {v[2]:.9g}" for v in p] + [" endloop", "endfacet"]
    return "\n".join(lines + ["endsolid prism"]) + "\n"


def meshed_3rrr(folder, visuals: dict, files: dict):
    """planar_3rrr written to ``folder``/robot with the ``<visual>`` of each link in ``visuals``
    (link -> (mesh URI, scale, origin xyz, origin rpy)) and the mesh ``files`` (path relative to
    ``folder`` -> text) written; returns (URDF path, ``folder``/packages)."""
    import re

    from parallel_gpc.model.description import urdf_dir

    folder = Path(folder)
    for rel, text in files.items():
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        (folder / rel).write_text(text)
    (folder / "robot").mkdir(exist_ok=True)
    (folder / "packages").mkdir(exist_ok=True)
    urdf = (urdf_dir() / "planar_3rrr.urdf").read_text()
    for link, (uri, scale, xyz, rpy) in visuals.items():
        visual = (f'<visual><origin xyz="{" ".join(map(repr, xyz))}" rpy="{" ".join(map(repr, rpy))}"/>'
                  f'<geometry><mesh filename="{uri}" scale="{" ".join(map(repr, scale))}"/></geometry>'
                  '<material name="platform"/></visual>')
        urdf, n = re.subn(rf'(<link name="{link}">.*?)<visual>.*?</visual>', lambda g: g.group(1) + visual, urdf,
                          count=1, flags=re.DOTALL)
        assert n == 1, link
    path = write(folder / "robot", "r", urdf, (urdf_dir() / "planar_3rrr.toml").read_text())
    return path, folder / "packages"


def write(tmp_path, stem: str, model: str, sidecar: str, model_suffix: str = ".urdf",
          sidecar_suffix: str = ".toml"):
    """Write ``stem`` + suffixes to ``tmp_path``; returns the model file's path."""
    path = tmp_path / f"{stem}{model_suffix}"
    path.write_text(model)
    (tmp_path / f"{stem}{sidecar_suffix}").write_text(sidecar)
    return path


# ---------------------------------------------------------------- planar 3-PRR in the x-y plane
#: platform circumradius, rod length (m), rod angle from radial and slide angle from the rod (rad),
#: stroke (m) and drive limit (N) of the 3-PRR written from docs/your-robot.md.
PRR_RADIUS, PRR_ROD = 0.10, 0.30
PRR_ROD_ANGLE, PRR_SLIDE_ANGLE = math.radians(40.0), math.radians(60.0)
PRR_STROKE, PRR_FORCE = 0.15, 50.0


def prr_leg(i: int, rod_angle: float = PRR_ROD_ANGLE):
    """(platform anchor, slider position at q = 0, slide axis) of leg i in the x-y plane (m)."""
    phi = math.radians(90.0 + 120.0 * i)
    anchor = PRR_RADIUS * np.array([math.cos(phi), math.sin(phi)])
    rod = np.array([math.cos(phi + rod_angle), math.sin(phi + rod_angle)])  # anchor → slider
    axis = np.array([math.cos(phi + rod_angle + PRR_SLIDE_ANGLE), math.sin(phi + rod_angle + PRR_SLIDE_ANGLE)])
    return anchor, anchor + PRR_ROD * rod, axis


def prr3_urdf(rod_angle: float = PRR_ROD_ANGLE) -> str:
    """A planar 3-PRR: three prismatic drives ``s1..s3`` on the base (±PRR_STROKE), a revolute
    at each slider, rods to a triangular platform (tree through leg 1; legs 2 and 3 close on the
    platform by point closures). The platform centre is at the origin at q = 0. With
    ``rod_angle`` 0 the rods are radial: their lines meet at the centre, and the platform can
    turn about it with the drives locked (a singular home)."""
    inertia = '<inertia ixx="{ixx}" ixy="0" ixz="0" iyy="{ixx}" iyz="0" izz="{izz}"/>'
    parts = ['<?xml version="1.0"?>', '<robot name="prr3_test">', '  <link name="base"/>']
    anchor1 = prr_leg(0)[0]
    for i in range(3):
        anchor, slider, axis = prr_leg(i, rod_angle)
        back = anchor - slider  # slider → platform anchor, in the rod frame (no rotation anywhere at q = 0)
        k = i + 1
        parts += [
            f'  <joint name="s{k}" type="prismatic"><parent link="base"/><child link="slider{k}"/>'
            f'<origin xyz="{slider[0]:.9f} {slider[1]:.9f} 0"/><axis xyz="{axis[0]:.9f} {axis[1]:.9f} 0"/>'
            f'<limit lower="{-PRR_STROKE}" upper="{PRR_STROKE}" effort="{PRR_FORCE}" velocity="1"/></joint>',
            f'  <link name="slider{k}"><inertial><mass value="0.5"/>{inertia.format(ixx="1e-4", izz="1e-4")}</inertial></link>',
            f'  <joint name="rev{k}" type="revolute"><parent link="slider{k}"/><child link="rod{k}"/>'
            f'<axis xyz="0 0 1"/><limit lower="-3.14" upper="3.14" effort="0" velocity="10"/></joint>',
            f'  <link name="rod{k}"><inertial><origin xyz="{back[0] / 2:.9f} {back[1] / 2:.9f} 0"/><mass value="0.3"/>'
            f'{inertia.format(ixx="2.25e-3", izz="2.25e-3")}</inertial></link>',
        ]
        if k == 1:
            parts += [
                f'  <joint name="pivot1" type="revolute"><parent link="rod1"/><child link="platform"/>'
                f'<origin xyz="{back[0]:.9f} {back[1]:.9f} 0"/><axis xyz="0 0 1"/>'
                f'<limit lower="-3.14" upper="3.14" effort="0" velocity="10"/></joint>',
                f'  <link name="platform"><inertial><origin xyz="{-anchor1[0]:.9f} {-anchor1[1]:.9f} 0"/>'
                f'<mass value="1.0"/>{inertia.format(ixx="2.5e-3", izz="5e-3")}</inertial></link>',
                f'  <joint name="centre_joint" type="fixed"><parent link="platform"/><child link="centre"/>'
                f'<origin xyz="{-anchor1[0]:.9f} {-anchor1[1]:.9f} 0"/></joint>',
                '  <link name="centre"/>',
            ]
        else:
            rel = anchor - anchor1
            parts += [
                f'  <joint name="tip{k}_joint" type="fixed"><parent link="rod{k}"/><child link="tip{k}"/>'
                f'<origin xyz="{back[0]:.9f} {back[1]:.9f} 0"/></joint>',
                f'  <link name="tip{k}"/>',
                f'  <joint name="seat{k}_joint" type="fixed"><parent link="platform"/><child link="seat{k}"/>'
                f'<origin xyz="{rel[0]:.9f} {rel[1]:.9f} 0"/></joint>',
                f'  <link name="seat{k}"/>',
            ]
    return "\n".join(parts + ["</robot>", ""])


def prr3_sidecar() -> str:
    """The 3-PRR's sidecar (TOML): pose output (x, y, rz) of the platform centre, the drives'
    strokes from the URDF as position limits."""
    closures = "".join(f'\n[[closures]]\nname = "leg{k}"\nkind = "point"\nframes = ["tip{k}", "seat{k}"]\n'
                       for k in (2, 3))
    return ('name = "prr3_test"\n\n[output]\nframe = "centre"\nkind = "pose"\naxes = ["x", "y", "rz"]\n\n'
            '[home]\npose = [0.0, 0.0, 0.0]\nA = [-0.01, -0.005, -0.03]\nB = [0.01, 0.008, 0.03]\n'
            '[home.q_guess]\ns1 = 0.0\ns2 = 0.0\ns3 = 0.0\n\n'
            f'[drives]\njoints = ["s1", "s2", "s3"]\ntorque_limit = {PRR_FORCE}\n\n'
            '[limits]\ndrive_position = "urdf"\n' + closures)


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


def assert_same_reduced_dynamics(robot_a, robot_b, n: int = 6, seed: int = 0) -> None:
    """Two models of one mechanism (same outputs and drives) give the same reduced terms M_r, h_r,
    B_r, the same ÿ and the same factorization (3), which reproduces Ẋ, at n random reachable
    states and inputs near home."""
    from parallel_gpc import ReducedModel

    ma, mb = ReducedModel(robot_a), ReducedModel(robot_b)
    rng = np.random.default_rng(seed)
    for X in random_output_states(robot_a, rng, n):
        ta, tb = ma.terms(X), mb.terms(X)
        np.testing.assert_allclose(ta.M_r, tb.M_r, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(ta.h_r, tb.h_r, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(ta.B_r, tb.B_r, rtol=1e-10, atol=1e-12)
        u = rng.uniform(-5, 5, robot_a.n_u)
        np.testing.assert_allclose(ta.acceleration(u), tb.acceleration(u), rtol=1e-9, atol=1e-10)
        Aa, Ba, ca = ma.factorize(X)
        Ab, Bb, cb = mb.factorize(X)
        np.testing.assert_allclose(Aa @ X + Ba @ u + ca, Ab @ X + Bb @ u + cb, rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(Aa @ X + Ba @ u + ca, ma.state_derivative(X, u), rtol=1e-9, atol=1e-10)


def assert_stage_jacobians_match_differences(model, traj, u, Ts: float, stages: int) -> None:
    """The stage Jacobians ∂Φ/∂X (``ReducedModel.stage_jacobians``) along a trajectory against central
    differences of the whole stage map Φ = A_d X + B_d u + c_d (2·n_x ``discrete`` per stage), to 1e-7
    of their largest entry, and not the frozen A_d (the derivative of A_d(X) matters along the move)."""
    J = model.stage_jacobians(traj, u, Ts)
    J_ref = model.stage_jacobians_differences(traj, u, Ts)
    assert J.shape == J_ref.shape == (stages, model.n_x, model.n_x)
    assert np.abs(J - J_ref).max() <= 1e-7 * np.abs(J_ref).max()
    A_d = model.simulate_factorized(traj[0], u, Ts)[0]
    assert np.abs(J_ref - A_d).max() > 1e-3 * np.abs(J_ref - np.eye(model.n_x)).max()


def fast_move(robot, K: int):
    """(X0, u (K, n_u)) of a fast move with inputs that vary along the horizon (planar_4rrr, or any robot near
    its home pose): the trajectories of the stage-Jacobian and rollout tests."""
    if robot.name == "planar_4rrr":
        X0 = np.array([0.5, 0.4, 0.1, 0.8, -0.5, 1.0])
    else:
        X0 = np.concatenate([robot.home_pose + 0.01 * np.sin(np.arange(robot.n_y) + 1.0),
                             0.3 * np.cos(np.arange(robot.n_y))])
    ramp = np.linspace(-1.0, 1.0, K)[:, None] * np.linspace(0.5, 1.5, robot.n_u)[None, :]
    scale = 1.0 if robot.name == "planar_4rrr" else 0.3
    return X0, scale * (np.cos(np.arange(robot.n_u))[None, :] + ramp)
