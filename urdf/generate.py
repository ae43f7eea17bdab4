"""Generate the embedded robot files (URDF open tree + TOML closure sidecar).

Run ``python urdf/generate.py`` to rewrite ``planar_4rrr.*`` and ``planar_3rrr.*`` (planar n-RRR,
this module) and the spatial robots ``delta_3rus``, ``hexapod_6ups``, ``hexapod_8ups``
(:mod:`generate_spatial`).
The numbers are our own stand-in (the paper gives no robot data); see DESIGN §1.

Geometry (SI units): bases at the corners of a 1 m x 1 m square, proximal and distal links
0.6 m, slender rods of 2 kg, a 5 kg platform with attachment radius ``ATTACH_RADIUS`` at
225°, 315°, 45°, 135° (each facing its base). The plane is horizontal (gravity along -z), so
gravity does no work. The platform is a child of the world through two prismatic joints and
one revolute joint, so y = [x, y, psi] are coordinates of q.
"""

from __future__ import annotations

import math
from pathlib import Path

from generate_spatial import SPATIAL_ROBOTS, number, xyz_text  # the spatial robots; one number format (no -0)

HERE = Path(__file__).resolve().parent
BASES = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
ATTACH_ANGLES_DEG = [225.0, 315.0, 45.0, 135.0]
ATTACH_RADIUS = 0.12
LINK_LENGTH = 0.6
LINK_MASS = 2.0
LINK_RADIUS = 0.015
PLATFORM_MASS = 5.0
PLATFORM_RADIUS = 0.15
PLATFORM_THICKNESS = 0.03
DRIVE_TORQUE_LIMIT = 60.0
# Elbow branch: +1 bends each leg counter-clockwise (elbow angle in (0, pi)).
ELBOW_SIGN = 1.0
HOME_POSE = (0.5, 0.5, 0.0)


def leg_ik(base, point, sign: float = ELBOW_SIGN) -> tuple[float, float]:
    """Analytic inverse kinematics of one RR leg with equal links: (drive, elbow) in rad."""
    dx, dy = point[0] - base[0], point[1] - base[1]
    d = math.hypot(dx, dy)
    beta = math.acos(max(-1.0, min(1.0, (d * d - 2 * LINK_LENGTH**2) / (2 * LINK_LENGTH**2))))
    return math.atan2(dy, dx) - sign * beta / 2, sign * beta


def _rod_inertia(mass: float, length: float, radius: float) -> str:
    ixx = 0.5 * mass * radius**2
    iyy = mass * (3 * radius**2 + length**2) / 12.0
    return (
        f'<inertia ixx="{ixx:.6g}" ixy="0" ixz="0" iyy="{iyy:.6g}" iyz="0" izz="{iyy:.6g}"/>'
    )


def _link_rod(name: str, colour: str) -> str:
    half = LINK_LENGTH / 2
    return f"""  <link name="{name}">
    <inertial>
      <origin xyz="{half} 0 0" rpy="0 0 0"/>
      <mass value="{LINK_MASS}"/>
      {_rod_inertia(LINK_MASS, LINK_LENGTH, LINK_RADIUS)}
    </inertial>
    <visual>
      <origin xyz="{half} 0 0" rpy="0 1.5707963267948966 0"/>
      <geometry><cylinder radius="{LINK_RADIUS}" length="{LINK_LENGTH}"/></geometry>
      <material name="{colour}"/>
    </visual>
  </link>
"""


def _revolute(name: str, parent: str, child: str, xyz, yaw: float = 0.0) -> str:
    return f"""  <joint name="{name}" type="revolute">
    <parent link="{parent}"/>
    <child link="{child}"/>
    <origin xyz="{xyz_text(xyz)}" rpy="0 0 {number(yaw)}"/>
    <axis xyz="0 0 1"/>
    <limit lower="-12.566" upper="12.566" effort="{DRIVE_TORQUE_LIMIT}" velocity="20"/>
  </joint>
"""


def _fixed(name: str, parent: str, xyz) -> str:
    return f"""  <link name="{name}"/>
  <joint name="{name}_joint" type="fixed">
    <parent link="{parent}"/>
    <child link="{name}"/>
    <origin xyz="{xyz_text(xyz)}" rpy="0 0 0"/>
  </joint>
"""


def urdf_text(name: str, n_legs: int) -> str:
    """Return the URDF of the planar n-RRR open tree (legs cut at the platform)."""
    ip = 0.5 * PLATFORM_MASS * PLATFORM_RADIUS**2
    parts = [
        f'<?xml version="1.0"?>\n<robot name="{name}">\n',
        '  <material name="base"><color rgba="0.3 0.3 0.3 1"/></material>\n',
        '  <material name="drive"><color rgba="0.85 0.35 0.1 1"/></material>\n',
        '  <material name="distal"><color rgba="0.2 0.45 0.8 1"/></material>\n',
        '  <material name="platform"><color rgba="0.2 0.7 0.3 1"/></material>\n',
        '  <link name="world"/>\n',
        '  <link name="platform_x_link"/>\n  <link name="platform_y_link"/>\n',
        """  <joint name="platform_x" type="prismatic">
    <parent link="world"/><child link="platform_x_link"/>
    <origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="1 0 0"/>
    <limit lower="-2" upper="3" effort="0" velocity="10"/>
  </joint>
  <joint name="platform_y" type="prismatic">
    <parent link="platform_x_link"/><child link="platform_y_link"/>
    <origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-2" upper="3" effort="0" velocity="10"/>
  </joint>
  <joint name="platform_psi" type="revolute">
    <parent link="platform_y_link"/><child link="platform"/>
    <origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-12.566" upper="12.566" effort="0" velocity="20"/>
  </joint>
""",
        f"""  <link name="platform">
    <inertial>
      <origin xyz="0 0 0" rpy="0 0 0"/>
      <mass value="{PLATFORM_MASS}"/>
      <inertia ixx="{ip / 2:.6g}" ixy="0" ixz="0" iyy="{ip / 2:.6g}" iyz="0" izz="{ip:.6g}"/>
    </inertial>
    <visual>
      <origin xyz="0 0 0" rpy="0 0 0"/>
      <geometry><cylinder radius="{PLATFORM_RADIUS}" length="{PLATFORM_THICKNESS}"/></geometry>
      <material name="platform"/>
    </visual>
  </link>
""",
    ]
    for i in range(n_legs):
        k = i + 1
        bx, by = BASES[i]
        a = math.radians(ATTACH_ANGLES_DEG[i])
        parts.append(_fixed(f"attach_{k}", "platform",
                            (ATTACH_RADIUS * math.cos(a), ATTACH_RADIUS * math.sin(a), 0.0)))
        parts.append(_revolute(f"drive_{k}", "world", f"proximal_{k}", (bx, by, 0.0)))
        parts.append(_link_rod(f"proximal_{k}", "drive"))
        parts.append(_revolute(f"elbow_{k}", f"proximal_{k}", f"distal_{k}",
                               (LINK_LENGTH, 0.0, 0.0)))
        parts.append(_link_rod(f"distal_{k}", "distal"))
        parts.append(_fixed(f"tip_{k}", f"distal_{k}", (LINK_LENGTH, 0.0, 0.0)))
    parts.append("</robot>\n")
    return "".join(parts)


def sidecar_text(name: str, n_legs: int) -> str:
    """Return the TOML closure sidecar of the planar n-RRR."""
    lines = [
        f"# Closure sidecar of {name}.urdf (parallel-gpc robot format, see docs/robot-files.md).",
        "# Numbers are our own stand-in; the paper gives no robot data.",
        f'name = "{name}"',
        f'description = "planar {n_legs}-RRR, {n_legs} drives, 3 DOF, horizontal plane"',
        "",
        "[output]",
        'frame = "platform"',
        'joints = ["platform_x", "platform_y", "platform_psi"]',
        'labels = ["x", "y", "psi"]',
        'units = ["m", "m", "rad"]',
        "",
        "[home]",
        "# platform pose [x m, y m, psi rad] and the elbow branch used to assemble the legs",
        f"pose = [{HOME_POSE[0]}, {HOME_POSE[1]}, {HOME_POSE[2]}]",
        "# passive joints whose sign of sin(q) identifies the assembly branch",
        "branch_joints = [" + ", ".join(f'"elbow_{i + 1}"' for i in range(n_legs)) + "]",
        "",
        "[home.q_guess]",
        "# rough leg angles (rad) at the home pose, the starting point of assembly",
    ]
    for i in range(n_legs):
        a = math.radians(ATTACH_ANGLES_DEG[i]) + HOME_POSE[2]
        point = (HOME_POSE[0] + ATTACH_RADIUS * math.cos(a), HOME_POSE[1] + ATTACH_RADIUS * math.sin(a))
        drive, elbow = leg_ik(BASES[i], point)
        lines += [f"drive_{i + 1} = {number(drive, '.3f')}", f"elbow_{i + 1} = {number(elbow, '.3f')}"]
    lines += [
        "",
        "[drives]",
        "joints = [" + ", ".join(f'"drive_{i + 1}"' for i in range(n_legs)) + "]",
        "torque_limit = [" + ", ".join(f"{DRIVE_TORQUE_LIMIT}" for _ in range(n_legs)) + "]",
        "",
    ]
    for i in range(n_legs):
        lines += [
            "[[closures]]",
            f'name = "leg_{i + 1}"',
            'kind = "point"',
            f'frames = ["tip_{i + 1}", "attach_{i + 1}"]',
            "",
        ]
    return "\n".join(lines)


def main() -> None:
    for name, n_legs in (("planar_4rrr", 4), ("planar_3rrr", 3)):
        (HERE / f"{name}.urdf").write_text(urdf_text(name, n_legs))
        (HERE / f"{name}.toml").write_text(sidecar_text(name, n_legs))
    for name, files in SPATIAL_ROBOTS.items():
        urdf, sidecar = files()
        (HERE / f"{name}.urdf").write_text(urdf)
        (HERE / f"{name}.toml").write_text(sidecar)


if __name__ == "__main__":
    main()
