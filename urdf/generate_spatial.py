"""Generate the embedded spatial robots: a Delta robot and Stewart-Gough hexapods (6 and 8 legs).

Called by ``python urdf/generate.py`` (which also writes the planar robots). The numbers are
our own stand-in (the paper gives no robot data); every file states them in a comment.
Gravity acts along -z (Pinocchio's default); the spatial robots stand upright, so gravity
loads the drives.

Modelling choices (1-DOF URDF joints only, so that the outputs are joint coordinates):

* The platform hangs on virtual joints from the world: ``PX-PY-PZ`` for the translational Delta,
  ``PX-PY-PZ-RZ-RY-RX`` for the hexapods. Hexapod orientation: roll-pitch-yaw
  (φ, θ, ψ) with R = Rz(ψ)·Ry(θ)·Rx(φ), the URDF ``rpy`` convention; singular only at
  θ = ±90°, far outside the workspace.
* Every loop is cut at a spherical joint: the ``point`` closure (3 rows) is exactly a
  spherical joint, so the S needs no URDF joints. A universal joint is two revolute joints
  through one point (no spin of the distal link or leg about its own axis, which would be an
  idle degree of freedom and leave the closure Jacobian rank deficient).
* Delta: each parallelogram (two S-S rods) is replaced by one equivalent rod with a universal
  joint at the elbow and a spherical joint at the platform; the constant platform orientation,
  which a real Delta gets from its parallelograms, comes from the translational virtual joints.
  Modelling the two rods with four spherical joints would add two idle spins per leg and an
  over-constrained four-bar loop (rank-deficient closures) for the same platform motion.
* Hexapods: U-P-S legs, a universal joint at the base (two revolutes), the prismatic drive
  between cylinder and piston, the spherical joint at the platform (the cut).
"""

from __future__ import annotations

import math

import numpy as np

LIMIT_ANGLE = 12.566  # rad, effectively unlimited revolute joints


# ------------------------------------------------------------------------------ URDF pieces
def number(x: float, spec: str = ".12g") -> str:
    """``x`` formatted with ``spec``, |x| < 1e-12 written as 0 and no zero with a sign.

    A value that is zero up to rounding (an asin of ±1e-17) has a sign that differs between
    machines; the generated files must not depend on it (no ``-0.0000``, no ``6.1e-17``).
    """
    x = float(x)
    text = format(0.0 if abs(x) < 1e-12 else x, spec)
    return text[1:] if text.startswith("-") and float(text) == 0.0 else text


def xyz_text(xyz) -> str:
    """Three numbers of a URDF ``xyz`` or ``rpy`` attribute (:func:`number`, 12 digits)."""
    return " ".join(number(c) for c in xyz)


def joint(name: str, kind: str, parent: str, child: str, xyz=(0, 0, 0), rpy=(0, 0, 0), axis=(0, 0, 1),
          limit=(-LIMIT_ANGLE, LIMIT_ANGLE), effort: float = 0.0) -> str:
    """One URDF joint (``revolute``, ``prismatic`` or ``fixed``)."""
    body = [f'  <joint name="{name}" type="{kind}">',
            f'    <parent link="{parent}"/><child link="{child}"/>',
            f'    <origin xyz="{xyz_text(xyz)}" rpy="{xyz_text(rpy)}"/>']
    if kind != "fixed":
        body += [f'    <axis xyz="{xyz_text(axis)}"/>',
                 f'    <limit lower="{number(limit[0], ".6g")}" upper="{number(limit[1], ".6g")}" '
                 f'effort="{effort:.6g}" velocity="20"/>']
    return "\n".join(body + ["  </joint>", ""])


def cylinder_inertia(mass: float, length: float, radius: float) -> tuple[float, float, float]:
    """(ixx, iyy, izz) of a solid cylinder along its z-axis about its centre (kg·m²)."""
    side = mass * (3 * radius**2 + length**2) / 12.0
    return side, side, 0.5 * mass * radius**2


def link(name: str, mass: float = 0.0, com=(0, 0, 0), rpy=(0, 0, 0), length: float = 0.0,
         radius: float = 0.0, material: str = "") -> str:
    """A link that is a solid cylinder of ``mass`` along the z-axis of the frame (com, rpy),
    drawn with the same cylinder; ``mass == 0`` gives an empty link (a virtual-joint link)."""
    if mass == 0.0:
        return f'  <link name="{name}"/>\n'
    ixx, iyy, izz = cylinder_inertia(mass, length, radius)
    return (f'  <link name="{name}">\n'
            f'    <inertial>\n      <origin xyz="{xyz_text(com)}" rpy="{xyz_text(rpy)}"/>\n'
            f'      <mass value="{mass:.6g}"/>\n'
            f'      <inertia ixx="{ixx:.6g}" ixy="0" ixz="0" iyy="{iyy:.6g}" iyz="0" izz="{izz:.6g}"/>\n'
            f'    </inertial>\n'
            f'    <visual>\n      <origin xyz="{xyz_text(com)}" rpy="{xyz_text(rpy)}"/>\n'
            f'      <geometry><cylinder radius="{radius:.6g}" length="{length:.6g}"/></geometry>\n'
            f'      <material name="{material}"/>\n    </visual>\n  </link>\n')


def frame(name: str, parent: str, xyz) -> str:
    """A massless frame fixed to ``parent`` at ``xyz`` (closure frames)."""
    return f'  <link name="{name}"/>\n' + joint(f"{name}_joint", "fixed", parent, name, xyz)


MATERIALS = ('  <material name="base"><color rgba="0.3 0.3 0.3 1"/></material>\n'
             '  <material name="drive"><color rgba="0.85 0.35 0.1 1"/></material>\n'
             '  <material name="distal"><color rgba="0.2 0.45 0.8 1"/></material>\n'
             '  <material name="platform"><color rgba="0.2 0.7 0.3 1"/></material>\n')

_VIRTUAL = {"x": ("prismatic", (1, 0, 0)), "y": ("prismatic", (0, 1, 0)), "z": ("prismatic", (0, 0, 1)),
            "yaw": ("revolute", (0, 0, 1)), "pitch": ("revolute", (0, 1, 0)), "roll": ("revolute", (1, 0, 0))}


def virtual_chain(coords: list[str]) -> str:
    """The platform's virtual joints ``platform_<c>`` from the world, in the order of ``coords``
    (x, y, z, yaw, pitch, roll); the last child is the link ``platform``."""
    parts, parent = [], "world"
    for i, c in enumerate(coords):
        kind, axis = _VIRTUAL[c]
        child = "platform" if i == len(coords) - 1 else f"platform_{c}_link"
        if child != "platform":
            parts.append(link(child))
        parts.append(joint(f"platform_{c}", kind, parent, child, axis=axis, limit=(-3.0, 3.0)))
        parent = child
    return "".join(parts)


def header(name: str, comment: str) -> str:
    return (f'<?xml version="1.0"?>\n<!-- {comment} -->\n<robot name="{name}">\n' + MATERIALS
            + '  <link name="world"/>\n')


def base_plate(radius: float, z: float, thickness: float = 0.02) -> str:
    """A thin fixed disc (drawn, no mass) marking the base: a visual-only link on the world."""
    return (f'  <link name="base_plate">\n    <visual>\n      <origin xyz="0 0 0" rpy="0 0 0"/>\n'
            f'      <geometry><cylinder radius="{radius:.6g}" length="{thickness:.6g}"/></geometry>\n'
            f'      <material name="base"/>\n    </visual>\n  </link>\n'
            + joint("base_plate_joint", "fixed", "world", "base_plate", (0, 0, z)))


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rz(yaw)·Ry(pitch)·Rx(roll) (URDF rpy; the hexapods' orientation parametrization)."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


def toml_list(values, spec: str = ".6g") -> str:
    """A TOML list of numbers formatted by :func:`number`."""
    return "[" + ", ".join(number(v, spec) for v in values) + "]"


def toml_names(names) -> str:
    return "[" + ", ".join(f'"{n}"' for n in names) + "]"


def sidecar(name: str, description: str, numbers: str, output: list[str], labels: list[str], units: list[str],
            home, poses: dict, branch: list[str], q_guess: dict, drives: list[str], limits: list[float],
            closures: list[tuple[str, str]], state_limits: list[str] | None = None) -> str:
    """The TOML closure sidecar (parallel-gpc robot format); ``state_limits``: the lines of a
    ``[limits]`` table (comments included), or None."""
    lines = [f"# Closure sidecar of {name}.urdf (parallel-gpc robot format, see docs/robot-files.md).",
             "# Numbers are our own stand-in; the paper gives no robot data:",
             *(f"#   {line}" for line in numbers.splitlines()),
             f'name = "{name}"', f'description = "{description}"', "",
             "[output]", 'frame = "platform"', f"joints = {toml_names(output)}",
             f"labels = {toml_names(labels)}", f"units = {toml_names(units)}", "",
             "[home]", "# platform pose [" + ", ".join(f"{lab} {u}" for lab, u in zip(labels, units)) + "]",
             f"pose = {toml_list(home)}",
             "# default start and end poses of `parallel-gpc plan` (same coordinates)",
             *(f"{k} = {toml_list(v)}" for k, v in poses.items()),
             "# passive joints whose sign of sin(q) identifies the assembly branch",
             f"branch_joints = {toml_names(branch)}", "",
             "[home.q_guess]", "# leg joint values (rad, m) at the home pose, the start of assembly",
             *(f"{k} = {number(v, '.4f')}" for k, v in q_guess.items()), "",
             "[drives]", f"joints = {toml_names(drives)}",
             "# N·m for revolute drives, N for prismatic drives",
             f"torque_limit = {toml_list(limits)}", ""]
    if state_limits:
        lines += ["[limits]", *state_limits, ""]
    for i, (a, b) in enumerate(closures):
        lines += ["[[closures]]", f'name = "leg_{i + 1}"', 'kind = "point"', f'frames = ["{a}", "{b}"]', ""]
    return "\n".join(lines)


# ------------------------------------------------------------------------------ Delta robot
DELTA = dict(base_radius=0.20, arm_length=0.25, arm_mass=0.8, arm_radius=0.015, rod_length=0.60, rod_mass=0.2,
             rod_radius=0.008, platform_radius=0.05, platform_mass=0.5, platform_thickness=0.02,
             torque_limit=30.0, home=(0.0, 0.0, -0.50), A=(-0.10, -0.08, -0.58), B=(0.10, 0.08, -0.42))
DELTA_NUMBERS = ("Delta robot: base radius 0.20 m (drive axes), upper arms 0.25 m / 0.8 kg, equivalent distal\n"
                 "rods 0.60 m / 0.2 kg (U at the elbow, S at the platform), platform radius 0.05 m / 0.5 kg,\n"
                 "drives 120 deg apart at z = 0, platform below (gravity -z), drive torque limit 30 N·m.")


def delta_leg_ik(p: np.ndarray, alpha: float, n: int = 0) -> tuple[float, float, float]:
    """(drive, elbow_a, elbow_b) in rad placing leg ``alpha`` (rad) of the Delta at platform
    position ``p`` (m), on the elbow-out branch."""
    d = DELTA
    u = np.array([math.cos(alpha), math.sin(alpha), 0.0])
    rel = rot_z(alpha).T @ (p + d["platform_radius"] * u - d["base_radius"] * u)  # leg frame
    a, b, c = rel
    la, lr = d["arm_length"], d["rod_length"]
    # |rel - la (cos t, 0, -sin t)| = lr  <=>  A cos t + B sin t = C
    A, B, C = -2 * a * la, 2 * c * la, lr**2 - a * a - b * b - c * c - la**2
    rho, phi = math.hypot(A, B), math.atan2(B, A)
    t = max((phi + s * math.acos(max(-1.0, min(1.0, C / rho))) for s in (-1, 1)), key=math.cos)
    elbow = la * np.array([math.cos(t), 0.0, -math.sin(t)])
    rod = rot_y(t).T @ ((rel - elbow) / lr)  # in the arm frame: (cos q1 cos q2, sin q2, -sin q1 cos q2)
    return t, math.atan2(-rod[2], rod[0]), math.asin(max(-1.0, min(1.0, rod[1])))


def delta_files(name: str = "delta_3rus", n_legs: int = 3) -> tuple[str, str]:
    """(URDF, TOML sidecar) of the translational Delta robot with ``n_legs`` R-U-S legs."""
    d = DELTA
    la, lr = d["arm_length"], d["rod_length"]
    parts = [header(name, "Delta robot, our stand-in numbers: " + DELTA_NUMBERS.replace("\n", " ")),
             base_plate(d["base_radius"] + 0.05, 0.03), virtual_chain(["x", "y", "z"])]
    parts.append(link("platform", d["platform_mass"], length=d["platform_thickness"],
                      radius=d["platform_radius"], material="platform"))
    q_guess = {}
    side = (0.0, math.pi / 2, 0.0)  # cylinder axis z -> link x
    for i in range(n_legs):
        k, alpha = i + 1, 2 * math.pi * i / n_legs
        u = (math.cos(alpha), math.sin(alpha), 0.0)
        parts.append(frame(f"attach_{k}", "platform", [d["platform_radius"] * c for c in u]))
        parts.append(joint(f"drive_{k}", "revolute", "world", f"arm_{k}", [d["base_radius"] * c for c in u],
                           (0, 0, alpha), (0, 1, 0), effort=d["torque_limit"]))
        parts.append(link(f"arm_{k}", d["arm_mass"], (la / 2, 0, 0), side, la, d["arm_radius"], "drive"))
        parts.append(joint(f"elbow_a_{k}", "revolute", f"arm_{k}", f"elbow_{k}", (la, 0, 0), axis=(0, 1, 0)))
        parts.append(link(f"elbow_{k}", 0.0))
        parts.append(joint(f"elbow_b_{k}", "revolute", f"elbow_{k}", f"rod_{k}", axis=(0, 0, 1)))
        parts.append(link(f"rod_{k}", d["rod_mass"], (lr / 2, 0, 0), side, lr, d["rod_radius"], "distal"))
        parts.append(frame(f"tip_{k}", f"rod_{k}", (lr, 0, 0)))
        t, e1, e2 = delta_leg_ik(np.array(d["home"]), alpha)
        q_guess.update({f"drive_{k}": t, f"elbow_a_{k}": e1, f"elbow_b_{k}": e2})
    parts.append("</robot>\n")
    legs = range(1, n_legs + 1)
    redundant = f", {n_legs - 3} redundant drive" if n_legs > 3 else ""
    toml = sidecar(name, f"Delta robot {n_legs}-RUS (parallelogram as equivalent rod), {n_legs} drives, "
                         f"3 translational DOF{redundant}, vertical (gravity -z)", DELTA_NUMBERS,
                   ["platform_x", "platform_y", "platform_z"], ["x", "y", "z"], ["m", "m", "m"], d["home"],
                   {"A": d["A"], "B": d["B"]}, [f"elbow_a_{k}" for k in legs], q_guess,
                   [f"drive_{k}" for k in legs], [d["torque_limit"]] * n_legs,
                   [(f"tip_{k}", f"attach_{k}") for k in legs])
    return "".join(parts), toml


# ------------------------------------------------------------------------------ hexapods
HEXAPOD = dict(base_radius=0.50, base_half_angle=10.0, platform_radius=0.30, platform_half_angle=10.0,
               cylinder_length=0.45, cylinder_mass=3.0, cylinder_radius=0.04, piston_length=0.45,
               piston_mass=1.5, piston_radius=0.025, platform_mass=15.0, platform_thickness=0.05,
               stroke=(0.45, 1.30), force_limit=1000.0, home=(0.0, 0.0, 0.70, 0.0, 0.0, 0.0),
               A=(-0.10, -0.08, 0.62, math.radians(-5.0), math.radians(4.0), math.radians(-10.0)),
               B=(0.10, 0.08, 0.80, math.radians(5.0), math.radians(-4.0), math.radians(10.0)))
HEXAPOD_NUMBERS = ("Stewart-Gough hexapod, U-P-S legs: base joints on radius 0.50 m (pairs 2x10 deg apart) at\n"
                   "z = 0, platform joints on radius 0.30 m (pairs 2x10 deg apart, offset half a pair pitch),\n"
                   "cylinders 0.45 m / 3 kg, pistons 0.45 m / 1.5 kg, platform 15 kg (disc 0.35 m x 0.05 m),\n"
                   "leg length (drive coordinate) 0.45 ... 1.30 m, drive force limit 1000 N, gravity -z.")


def hexapod_points(n_legs: int) -> list[tuple[float, float]]:
    """(base angle, platform angle) in rad of each leg: pairs of base joints around 360°·k/n_pairs,
    each leg going to the nearest platform joint of the neighbouring platform pair."""
    h, pairs = HEXAPOD, n_legs // 2
    pitch = 2 * math.pi / pairs
    db, dp = math.radians(h["base_half_angle"]), math.radians(h["platform_half_angle"])
    legs = []
    for k in range(pairs):
        c = k * pitch
        legs += [(c - db, c - pitch / 2 + dp), (c + db, c + pitch / 2 - dp)]
    return legs


def hexapod_leg_ik(pose, base_angle: float, platform_angle: float) -> tuple[float, float, float]:
    """(u_a, u_b, length) in rad, rad, m of one U-P-S leg at platform pose
    [x, y, z, roll, pitch, yaw] (m, rad)."""
    h = HEXAPOD
    b = h["base_radius"] * np.array([math.cos(base_angle), math.sin(base_angle), 0.0])
    p = h["platform_radius"] * np.array([math.cos(platform_angle), math.sin(platform_angle), 0.0])
    leg = np.asarray(pose[:3]) + rpy_matrix(*pose[3:]) @ p - b
    length = float(np.linalg.norm(leg))
    d = rot_z(base_angle).T @ leg / length  # (sin q2, -cos q2 sin q1, cos q2 cos q1)
    return math.atan2(-d[1], d[2]), math.asin(max(-1.0, min(1.0, d[0]))), length


def hexapod_files(name: str = "hexapod_6ups", n_legs: int = 6) -> tuple[str, str]:
    """(URDF, TOML sidecar) of the Stewart-Gough platform with ``n_legs`` U-P-S legs (even)."""
    h = HEXAPOD
    numbers = HEXAPOD_NUMBERS if n_legs == 6 else HEXAPOD_NUMBERS.replace("pairs 2x10", f"{n_legs // 2} pairs 2x10")
    parts = [header(name, f"Stewart-Gough platform with {n_legs} U-P-S legs, our stand-in numbers: "
                    + numbers.replace("\n", " ")),
             base_plate(h["base_radius"] + 0.08, -0.02),
             virtual_chain(["x", "y", "z", "yaw", "pitch", "roll"]),
             link("platform", h["platform_mass"], length=h["platform_thickness"], radius=h["platform_radius"] + 0.05,
                  material="platform")]
    lc, lp = h["cylinder_length"], h["piston_length"]
    q_guess = {}
    for i, (ab, ap) in enumerate(hexapod_points(n_legs)):
        k = i + 1
        parts.append(frame(f"attach_{k}", "platform",
                           (h["platform_radius"] * math.cos(ap), h["platform_radius"] * math.sin(ap), 0.0)))
        parts.append(joint(f"u_a_{k}", "revolute", "world", f"u_{k}",
                           (h["base_radius"] * math.cos(ab), h["base_radius"] * math.sin(ab), 0.0),
                           (0, 0, ab), (1, 0, 0)))
        parts.append(link(f"u_{k}", 0.0))
        parts.append(joint(f"u_b_{k}", "revolute", f"u_{k}", f"cylinder_{k}", axis=(0, 1, 0)))
        parts.append(link(f"cylinder_{k}", h["cylinder_mass"], (0, 0, lc / 2), length=lc,
                          radius=h["cylinder_radius"], material="drive"))
        parts.append(joint(f"drive_{k}", "prismatic", f"cylinder_{k}", f"piston_{k}", axis=(0, 0, 1),
                           limit=h["stroke"], effort=h["force_limit"]))
        parts.append(link(f"piston_{k}", h["piston_mass"], (0, 0, -lp / 2), length=lp,
                          radius=h["piston_radius"], material="distal"))
        parts.append(frame(f"tip_{k}", f"piston_{k}", (0, 0, 0)))
        qa, qb, s = hexapod_leg_ik(h["home"], ab, ap)
        q_guess.update({f"u_a_{k}": qa, f"u_b_{k}": qb, f"drive_{k}": s})
    parts.append("</robot>\n")
    legs = range(1, n_legs + 1)
    redundant = f", {n_legs - 6} redundant drives" if n_legs > 6 else ""
    toml = sidecar(name, f"Stewart-Gough platform {n_legs}-UPS, {n_legs} prismatic drives, 6 DOF{redundant}, "
                         "vertical (gravity -z)", numbers,
                   ["platform_x", "platform_y", "platform_z", "platform_roll", "platform_pitch", "platform_yaw"],
                   ["x", "y", "z", "roll", "pitch", "yaw"], ["m", "m", "m", "rad", "rad", "rad"], h["home"],
                   {"A": h["A"], "B": h["B"]}, [], q_guess, [f"drive_{k}" for k in legs],
                   [h["force_limit"]] * n_legs, [(f"tip_{k}", f"attach_{k}") for k in legs],
                   HEXAPOD_STROKE if name == "hexapod_6ups" else None)
    return "".join(parts), toml


#: the [limits] table of hexapod_6ups: its legs' stroke, hard.
HEXAPOD_STROKE = ["# the legs' stroke 0.45 ... 1.30 m: the drives' <limit> ranges of hexapod_6ups.urdf, hard",
                  "# (the controller never plans a leg beyond it; soft kinds would be relaxed at an exact penalty)",
                  'drive_position = "urdf"', "soft = []"]


#: name -> generator of the embedded spatial robots.
SPATIAL_ROBOTS = {
    "delta_3rus": lambda: delta_files("delta_3rus", 3),
    "hexapod_6ups": lambda: hexapod_files("hexapod_6ups", 6),
    "hexapod_8ups": lambda: hexapod_files("hexapod_8ups", 8),
}
