"""A spatial 6-UPS (Gough-Stewart) test mechanism whose base universal joints are declared in the
sidecar (``joint_type: UJOINT``, or ``UJOINT_AB`` with named axes per leg) or written as two
revolute joints in series through one point."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from mechanisms import platform_links

#: base / platform radii, home height (m), half-angles of the joint pairs (rad), masses (kg).
UPS_RB, UPS_RP, UPS_H, UPS_HALF = 0.35, 0.2, 0.5, math.radians(15)
M_CYL, M_ROD, M_TOP = 0.6, 0.4, 3.0


def ups_legs() -> list[tuple[float, float]]:
    """(base angle, platform angle) in rad of the 6 legs: base pairs around 0°, 120°, 240°,
    each leg to the nearest joint of the neighbouring platform pair."""
    legs = []
    for c in (0.0, 2 * math.pi / 3, 4 * math.pi / 3):
        legs += [(c - UPS_HALF, c - math.pi / 3 + UPS_HALF), (c + UPS_HALF, c + math.pi / 3 - UPS_HALF)]
    return legs


def _axes(pair: str) -> tuple[int, int, int]:
    """Indices (first, second, third) of the coordinate axes of a pair such as ``"ZY"``."""
    a, b = ("XYZ".index(c) for c in pair)
    return a, b, 3 - a - b


def _rot(axis: int, angle: float) -> np.ndarray:
    return pin.exp3(angle * np.eye(3)[axis])


def ups_leg_home(base_angle: float, platform_angle: float, pair: str = "XY") -> tuple[float, float, float]:
    """(a, b, length) of a leg at home: its direction in the base frame Rz(base_angle) is
    R_A(a) R_B(b) e_C for the axes A, B of ``pair`` and the third axis C (for "XY":
    Rx(a) Ry(b) e_z = (sin b, −cos b sin a, cos b cos a)); length in m."""
    leg = np.array([UPS_RP * math.cos(platform_angle) - UPS_RB * math.cos(base_angle),
                    UPS_RP * math.sin(platform_angle) - UPS_RB * math.sin(base_angle), UPS_H])
    d = pin.rpy.rpyToMatrix(0, 0, base_angle).T @ leg / np.linalg.norm(leg)
    A, B, C = _axes(pair)
    eA, eB, eC = np.eye(3)[[A, B, C]]
    # R_B(b) e_C = cos b e_C + sin b (e_B × e_C), and R_A(a) keeps the e_A component
    b = math.asin(d[A] / float(np.cross(eB, eC) @ eA))
    perp = d - d[A] * eA
    a = math.atan2(float(np.cross(eC, perp) @ eA), float(eC @ perp))
    return a, b, float(np.linalg.norm(leg))


def _vec(axis: int, scale: float) -> str:
    return " ".join(f"{scale * x:g}" for x in np.eye(3)[axis])


def ups_urdf(universal: bool, pairs=None, extras: dict | None = None) -> str:
    """6-UPS: base universal joints turning about x then y of a frame Rz(base angle) (one
    placeholder revolute ``u<k>`` about x for a sidecar ``UJOINT``, or revolutes ``u<k>a`` about x
    and ``u<k>b`` about y through one point), prismatic legs ``p<k>``; the platform hangs on leg 1's
    spherical joint ``s1`` (placeholder for a sidecar ``SPHERICAL``); legs 2-6 close on it by
    point closures ``tip<k>``–``attach<k>``.

    ``pairs`` (6 strings such as ``"ZY"``): leg k's universal joint turns about axis A then B of
    its frame (sidecar ``UJOINT_AB``; the placeholder revolute is about x whatever the pair, as
    Gepetto's loader ignores it) and its prismatic joint runs along the third axis C, the rod a
    point mass; the two-revolute version gets massless ``<inertial>`` blocks (mass 0) on its
    cross links. ``extras``: link name → XML appended inside that link (e.g. visuals)."""
    extras = extras or {}
    parts = ['<?xml version="1.0"?>\n<robot name="ups">\n  <link name="base"/>']
    s1_world = None
    for k, (ab, ap) in enumerate(ups_legs(), start=1):
        pair = pairs[k - 1] if pairs else "XY"
        A, B, C = _axes(pair)
        base = f'xyz="{UPS_RB * math.cos(ab):.15g} {UPS_RB * math.sin(ab):.15g} 0" rpy="0 0 {ab:.15g}"'
        limit = '<limit lower="-3" upper="3" effort="0" velocity="9"/>'
        if universal:
            parts.append(f"""
  <joint name="u{k}" type="revolute"><parent link="base"/><child link="cyl{k}"/>
    <origin {base}/><axis xyz="1 0 0"/>{limit}</joint>""")
        else:
            massless = '<inertial><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>'
            parts.append(f"""
  <joint name="u{k}a" type="revolute"><parent link="base"/><child link="cross{k}"/>
    <origin {base}/><axis xyz="{_vec(A, 1)}"/>{limit}</joint><link name="cross{k}">{massless if pairs else ""}</link>
  <joint name="u{k}b" type="revolute"><parent link="cross{k}"/><child link="cyl{k}"/>
    <axis xyz="{_vec(B, 1)}"/>{limit}</joint>""")
        moments = ["0.004"] * 3
        moments[C] = "0.0003"
        rod = (f'<inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/>' if pairs
               else '<inertia ixx="0.002" ixy="0" ixz="0" iyy="0.002" iyz="0" izz="0.0001"/>')
        parts.append(f"""
  <link name="cyl{k}"><inertial><origin xyz="{_vec(C, 0.1)}"/><mass value="{M_CYL}"/>
    <inertia ixx="{moments[0]}" ixy="0" ixz="0" iyy="{moments[1]}" iyz="0" izz="{moments[2]}"/></inertial>{extras.get(f"cyl{k}", "")}</link>
  <joint name="p{k}" type="prismatic"><parent link="cyl{k}"/><child link="rod{k}"/>
    <axis xyz="{_vec(C, 1)}"/><limit lower="0" upper="1" effort="50" velocity="1"/></joint>
  <link name="rod{k}"><inertial><origin xyz="{_vec(C, -0.1)}"/><mass value="{M_ROD}"/>
    {rod}</inertial></link>
  <joint name="tip{k}_joint" type="fixed"><parent link="rod{k}"/><child link="tip{k}"/></joint>
  <link name="tip{k}"/>""")
        if k == 1:
            a, b, length = ups_leg_home(ab, ap, pair)
            s1_world = (pin.SE3(pin.rpy.rpyToMatrix(0, 0, ab), np.array([UPS_RB * math.cos(ab), UPS_RB * math.sin(ab), 0]))
                        * pin.SE3(_rot(A, a) @ _rot(B, b), np.zeros(3))
                        * pin.SE3(np.eye(3), length * np.eye(3)[C]))
    centre = s1_world.inverse() * pin.SE3(np.eye(3), np.array([0, 0, UPS_H]))  # platform centre in s1's frame
    parts.append("""
  <joint name="s1" type="revolute"><parent link="tip1"/><child link="top"/><axis xyz="1 0 0"/>
    <limit lower="-3" upper="3" effort="0" velocity="9"/></joint>""")
    parts.append(platform_links("top", centre, M_TOP, 'ixx="0.03" ixy="0.002" ixz="0" iyy="0.035" iyz="0" izz="0.06"',
                                UPS_RP, [(k, ap) for k, (_, ap) in enumerate(ups_legs(), start=1) if k > 1]))
    return "".join(parts)


def ups_sidecar(universal: bool, pairs=None) -> str:
    """Gepetto-style YAML sidecar of :func:`ups_urdf`: pose output (6 axes), drives p1-p6, the
    joint types (``UJOINT`` u1-u6 when ``universal``, ``UJOINT_AB`` with ``pairs``, ``SPHERICAL``
    s1) and the home guess (a list [a, b] for a universal joint)."""
    types, guess = {}, {}
    for k, (ab, ap) in enumerate(ups_legs(), start=1):
        pair = pairs[k - 1] if pairs else "XY"
        a, b, length = ups_leg_home(ab, ap, pair)
        if universal:
            types[f"u{k}"], guess[f"u{k}"] = f"UJOINT_{pair}" if pairs else "UJOINT", [round(a, 12), round(b, 12)]
        else:
            guess |= {f"u{k}a": round(a, 12), f"u{k}b": round(b, 12)}
        guess[f"p{k}"] = round(length, 12)
    types["s1"] = "SPHERICAL"
    return ("closed_loop: " + str([[f"tip{k}", f"attach{k}"] for k in range(2, 7)]) + "\n"
            "type: [3D, 3D, 3D, 3D, 3D]\n"
            f"name_mot: {[f'p{k}' for k in range(1, 7)]}\njoint_name: {list(types)}\njoint_type: {list(types.values())}\n"
            "output: {frame: platform, kind: pose, axes: [x, y, z, rx, ry, rz]}\n"
            f"home: {{q_guess: {guess}}}\n").replace("'", "")
