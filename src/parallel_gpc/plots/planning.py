"""Figures of the planner (the paper's Fig. 3 and Fig. 4), returned as matplotlib figures.

* :func:`plot_fig3` — the platform path in the x-y plane for each mode, with small platform
  markers along it showing the orientation ψ, the start A and end B, and the robot sketched at
  A and at the last planned pose.
* :func:`plot_fig4` — time histories for each mode: position, orientation, velocities and
  drive torques.

The figures are built with :class:`matplotlib.figure.Figure` (no pyplot state, no GUI), so they
work headless and do not change the caller's matplotlib backend.
"""

from __future__ import annotations

import math

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Polygon

from ..gpc.planning import PlanResult

#: Colors of the modes (and of anything else the figures draw per mode).
MODE_COLORS = {"a": "tab:red", "b": "tab:blue", "once": "tab:gray"}
_DRIVE_COLORS = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown"]


def _columns(res: PlanResult) -> tuple[list[tuple[int, str]], list[tuple[int, str]], int | None]:
    """(translational, angular, yaw) outputs of a plan: (index, TeX name) pairs, x, y[, z] and
    ψ (planar) or φ, θ, ψ (roll, pitch, yaw); yaw is the index of the rotation about z or None."""
    n = res.poses.shape[1]
    angular = np.arange(n) >= 2 if res.angular is None else np.asarray(res.angular, dtype=bool)
    lin = [(int(i), name) for i, name in zip(np.flatnonzero(~angular), ("x", "y", "z"))]
    names = (r"\psi",) if angular.sum() == 1 else (r"\phi", r"\theta", r"\psi")
    ang = [(int(i), name) for i, name in zip(np.flatnonzero(angular), names)]
    return lin, ang, (ang[-1][0] if ang else None)


def robot_outline(robot, q: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """Planar sketch of a robot at configuration q: legs and platform in the x-y plane.

    For each closure, the side whose joint chain does not pass through the platform (output)
    joints is a leg, drawn through its joint origins to the closure frame; the other side's
    closure frames are the platform corners.

    Returns:
        (legs, platform): a list of (n_i, 2) polylines and the (n, 2) platform polygon (m).
    """
    import pinocchio as pin

    model = robot.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, np.asarray(q, dtype=float))
    output_v = set(np.asarray(robot.y_idx).tolist())
    output_joints = {j for j in range(1, model.njoints) if model.joints[j].idx_v in output_v}

    def chain(frame_id: int) -> list[int]:
        joints, j = [], model.frames[frame_id].parentJoint
        while j != 0:
            joints.append(j)
            j = model.parents[j]
        return joints[::-1]

    legs, corners = [], []
    for closure in robot.description.closures:
        for name in closure.frames:
            fid = model.getFrameId(name)
            joints = chain(fid)
            tip = np.asarray(data.oMf[fid].translation)[:2]
            if output_joints.intersection(joints):
                corners.append(tip)
            else:
                legs.append(np.array([np.asarray(data.oMi[j].translation)[:2] for j in joints] + [tip]))
    platform = np.array(corners) if corners else np.zeros((0, 2))
    if len(platform) > 2:  # order the corners around their centre
        centre = platform.mean(axis=0)
        platform = platform[np.argsort(np.arctan2(*(platform - centre).T[::-1]))]
    return legs, platform


def _pose_marker(x: float, y: float, psi: float, size: float) -> np.ndarray:
    """A small isosceles triangle at (x, y) whose nose points along the platform x-axis (ψ)."""
    shape = np.array([[1.0, 0.0], [-0.6, 0.55], [-0.6, -0.55]]) * size
    c, s = math.cos(psi), math.sin(psi)
    return shape @ np.array([[c, s], [-s, c]]) + [x, y]


def _draw_robot(ax, robot, q, color: str, alpha: float, linestyle: str = "-", label: str | None = None) -> None:
    legs, platform = robot_outline(robot, q)
    for i, leg in enumerate(legs):
        ax.plot(leg[:, 0], leg[:, 1], linestyle, color=color, alpha=alpha, lw=1.2, marker="o", ms=2.5,
                label=label if i == 0 else None)
        ax.plot(*leg[0], "s", color=color, alpha=alpha, ms=5)  # base / drive
    if len(platform) > 2:
        ax.add_patch(Polygon(platform, closed=True, fill=False, ec=color, alpha=alpha, ls=linestyle, lw=1.2))


def _angle_text(rad: float) -> str:
    deg = abs(math.degrees(rad))
    return f"{deg:.3g}°" if deg < 1 else f"{deg:.1f}°"


def plot_fig3(results: list[PlanResult], robot=None, n_markers: int = 11,
              marker_size: float = 0.04) -> Figure:
    """Fig. 3: the planned platform paths in the x-y plane, one panel per mode.

    Args:
        results: plans to draw (usually modes a, b and once, same A and B).
        robot: draw the robot at A and the platform at the last pose (needs the results' ``q``).
        n_markers: number of orientation markers along each path.
        marker_size: marker length in m.

    Returns:
        The figure.
    """
    fig = Figure(figsize=(5.6 * len(results), 6.2))
    axes = fig.subplots(1, len(results), squeeze=False, sharex=True, sharey=True)[0]
    for ax, res in zip(axes, results):
        color = MODE_COLORS.get(res.mode, "tab:green")
        if robot is not None and res.q is not None:
            _draw_robot(ax, robot, res.q[0], "0.6", 0.7, label="robot at A")
            _, platform = robot_outline(robot, res.q[-1])
            if len(platform) > 2:
                ax.add_patch(Polygon(platform, closed=True, fill=False, ec=color, lw=1.5, ls="--",
                                     label=f"platform at t = {res.t[-1]:.2f} s"))
        ax.plot(res.poses[:, 0], res.poses[:, 1], "-", color=color, lw=2, label="platform path")
        lin, ang, yaw = _columns(res)
        idx = np.unique(np.linspace(0, len(res.t) - 1, n_markers if yaw is not None else 0).round().astype(int))
        for j, i in enumerate(idx):
            x, y, psi = res.poses[i, 0], res.poses[i, 1], res.poses[i, yaw]
            ax.add_patch(Polygon(_pose_marker(x, y, psi, marker_size), closed=True, fc=color, ec="k", lw=0.5,
                                 alpha=0.85, label=rf"orientation $\psi$ every {res.t[idx[1]] - res.t[idx[0]]:.2f} s"
                                 if j == 0 and len(idx) > 1 else None))
        for pose, name, mk in ((res.start, "A", "o"), (res.target, "B", "*")):
            ax.plot(pose[0], pose[1], mk, color="k", ms=11 if mk == "*" else 8, zorder=5)
            if yaw is not None:
                ax.add_patch(Polygon(_pose_marker(pose[0], pose[1], pose[yaw], 2 * marker_size), closed=True,
                                     fill=False, ec="k", lw=1.0, ls=":"))
            text = ", ".join([f"{pose[i]:.2f} m" for i, _ in lin] + [f"{math.degrees(pose[i]):.0f}°" for i, _ in ang])
            ax.annotate(f"{name} [{text}]", pose[:2],
                        xytext=(10, -16) if name == "A" else (-10, 14), textcoords="offset points", fontsize=9,
                        ha="left" if name == "A" else "right")
        pos, ang = res.end_error
        reach = res.time_to_reach
        ax.set_title(f"{res.label}\nend error {pos:.2g} m, {_angle_text(ang)}; "
                     + ("not within tolerance" if math.isnan(reach) else f"reached at {reach:.2f} s"), fontsize=10)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_aspect("equal", adjustable="box")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper left", fontsize=8)
    s = results[0].settings
    fig.suptitle(f"Quadratically-optimal planning A → B (Nmax = {s.Nmax}, Nmin = {s.Nmin}, k = {s.k}, "
                 f"Ts = {1000 * s.Ts:g} ms)", fontsize=11, y=0.98)
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.08, top=0.86, wspace=0.12)
    return fig


def plot_fig4(results: list[PlanResult]) -> Figure:
    """Fig. 4: time histories of the plans, one column per mode.

    Rows: platform position x, y (m); orientation ψ (deg); linear velocity (m/s); angular
    velocity (deg/s); drive torques (N·m). Dashed vertical lines mark the planned arrival
    t = Nmax·Ts and, in mode (b), the step where the horizon reaches Nmin; dotted lines the
    end pose B and the torque limits.

    Returns:
        The figure.
    """
    fig = Figure(figsize=(6.0 * len(results), 12.0), layout="constrained")
    axes = fig.subplots(5, len(results), squeeze=False, sharex="all", sharey="row")  # comparable columns
    for col, res in enumerate(results):
        s = res.settings
        ax = axes[:, col]
        t, tu = res.t, res.t[:-1]
        lin, ang = _columns(res)[:2]
        for k, (i, lab) in enumerate(lin):
            ax[0].plot(t, res.poses[:, i], color=_DRIVE_COLORS[k], label=f"${lab}$")
            ax[0].axhline(res.target[i], color=_DRIVE_COLORS[k], ls=":", lw=1)
            ax[2].plot(t, res.velocities[:, i], color=_DRIVE_COLORS[k], label=rf"$\dot {lab}$")
        ax[0].set_ylabel("position [m]")
        for k, (i, lab) in enumerate(ang):
            color = "tab:green" if len(ang) == 1 else _DRIVE_COLORS[3 + k]
            ax[1].plot(t, np.degrees(res.poses[:, i]), color=color, label=f"${lab}$")
            ax[1].axhline(math.degrees(res.target[i]), color=color, ls=":", lw=1, label=f"${lab}$ of B")
            ax[3].plot(t, np.degrees(res.velocities[:, i]), color=color, label=rf"$\dot{lab}$")
        ax[1].set_ylabel("orientation [deg]")
        ax[2].set_ylabel("velocity [m/s]")
        ax[3].set_ylabel("angular velocity [deg/s]")
        for j in range(res.u.shape[1]):
            ax[4].step(tu, res.u[:, j], where="post", color=_DRIVE_COLORS[j % len(_DRIVE_COLORS)], label=f"$u_{j + 1}$")
        if s.limits.torque is not None:
            lim = np.max(s.limits.torque)
            for sign in (1, -1):
                ax[4].axhline(sign * lim, color="k", ls=":", lw=1, label="torque limit" if sign > 0 else None)
        ax[4].set_ylabel("drive torque [N·m]")
        for a in ax:
            a.axvline(s.duration, color="0.3", ls="--", lw=1)
            if res.mode == "b" and s.Nmax > s.Nmin:
                a.axvline((s.Nmax - s.Nmin) * s.Ts, color="0.6", ls="-.", lw=1)
            a.grid(True, alpha=0.3)
            if a.get_legend_handles_labels()[0]:  # no orientation rows' legend for a translational robot
                a.legend(loc="best", fontsize=8)
        pos, ang = res.end_error
        ax[0].set_title(f"{res.label}\nend error {pos:.2g} m, {_angle_text(ang)}, energy "
                        f"{res.energy:.3g} N²m²s, peak {res.peak_torque:.3g} N·m", fontsize=10)
        note = "dashed: planned arrival Nmax·Ts" + ("; dash-dot: N reaches Nmin" if res.mode == "b" else "")
        ax[4].set_xlabel(f"t [s]    ({note})")
    fig.suptitle("Time histories of the planned moves", fontsize=11)
    return fig
