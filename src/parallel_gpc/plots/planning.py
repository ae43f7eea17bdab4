"""Figures of the planner (the paper's Fig. 3 and Fig. 4), returned as matplotlib figures.

* :func:`plot_fig3` — the path in the plane or space of the translational outputs for each
  mode (planar robots: with small platform markers showing the orientation ψ), the start A and
  end B, and the robot sketched from its joint frames at A and at the last planned pose.
* :func:`plot_fig4` — time histories for each mode: translational and angular outputs (rows
  only for those present), velocities and drive efforts in the robot's drive unit.

The figures are built with :class:`matplotlib.figure.Figure` (no pyplot state, no GUI), so they
work headless and do not change the caller's matplotlib backend.
"""

from __future__ import annotations

import math

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Polygon

from ..gpc import PlanResult
from ..model import output_world_axes, stick_figure
from .common import mark_drive_limit
from .paths import draw_path, path_axes

#: Colors of the modes (and of anything else the figures draw per mode).
MODE_COLORS = {"a": "tab:red", "b": "tab:blue", "once": "tab:gray"}
_DRIVE_COLORS = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown"]


def robot_outline(robot, q: np.ndarray, axes=(0, 1)) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """Sketch of a robot at configuration q from its joint frames
    (:func:`~parallel_gpc.model.skeleton.stick_figure`), projected on world axes ``axes``.

    For each closure, the side whose joint chain does not pass through the platform is a leg,
    drawn through its joint origins to the closure frame; the other side's closure frames are
    platform corners (with the joint of a platform that a leg of the tree carries).

    Args:
        robot: the :class:`~parallel_gpc.model.robot.ParallelRobot`.
        q: (nq,) configuration.
        axes: world axes kept (0 = x, 1 = y, 2 = z): two for a plane, three for space.

    Returns:
        (legs, platform, rails): a list of (n_i, len(axes)) polylines, the (n, len(axes))
        platform polygon and the (r, 2, len(axes)) rails of the prismatic drives (their stroke,
        :attr:`~parallel_gpc.model.skeleton.Skeleton.rails`), all in m.
    """
    sk = stick_figure(robot, q)
    axes = list(axes)
    return [leg[:, axes] for leg in sk.legs], sk.platform[:, axes], sk.rails[:, :, axes]


def _world_axes(robot, cols: list[int]) -> list[int] | None:
    """World axes of the drawn output columns, or None when one has none (no robot drawn)."""
    axes = [output_world_axes(robot)[c] for c in cols]
    return None if None in axes or len(set(axes)) != len(axes) else axes


def _pose_marker(x: float, y: float, psi: float, size: float) -> np.ndarray:
    """A small isosceles triangle at (x, y) whose nose points along the platform x-axis (ψ)."""
    shape = np.array([[1.0, 0.0], [-0.6, 0.55], [-0.6, -0.55]]) * size
    c, s = math.cos(psi), math.sin(psi)
    return shape @ np.array([[c, s], [-s, c]]) + [x, y]


def _closed(platform: np.ndarray) -> np.ndarray:
    """The platform polygon with its first corner repeated (every edge drawn; two corners: one edge)."""
    return np.vstack([platform, platform[:1]]) if len(platform) > 2 else platform


def _draw_robot(ax, robot, q, axes: list[int], color: str, alpha: float, label: str | None = None) -> None:
    """The robot's legs (joint origins, drives as squares), platform (every edge between its
    corners) and the prismatic drives' rails (thick grey, dots at the stroke limits) at q on
    a path axes whose columns are the world axes ``axes``."""
    legs, platform, rails = robot_outline(robot, q, axes)
    for i, rail in enumerate(rails):
        ax.plot(*rail.T, "-", color="0.8", lw=4, solid_capstyle="butt", zorder=0,
                label="drive rails (stroke)" if i == 0 else None)
        ax.plot(*rail.T, "o", color="0.4", ms=3, zorder=0)  # the stroke limits
    for i, leg in enumerate(legs):
        ax.plot(*leg.T, "-", color=color, alpha=alpha, lw=1.2, marker="o", ms=2.5, label=label if i == 0 else None)
        ax.plot(*leg[0], "s", color=color, alpha=alpha, ms=5)  # base / drive
    if len(platform) > 1:
        ax.plot(*_closed(platform).T, "-", color=color, alpha=alpha, lw=1.2, label="platform" if label else None)


def _angle_text(rad: float) -> str:
    deg = abs(math.degrees(rad))
    return f"{deg:.3g}°" if deg < 1 else f"{deg:.1f}°"


def plot_fig3(results: list[PlanResult], robot=None, n_markers: int = 11,
              marker_size: float | None = None) -> Figure:
    """Fig. 3: the planned paths in the plane or space of the translational outputs (axes named
    by the output labels), one panel per mode, with the start A and end B.

    Args:
        results: plans to draw (usually modes a, b and once, same A and B).
        robot: draw the robot at A (legs from its joint frames) and its platform at the last pose
            (needs the results' ``q``; only where the drawn outputs move along world axes).
        n_markers: number of orientation markers along each path (planar [x, y, ψ] outputs).
        marker_size: marker length in m (default 7 % of the path's span, at least 1 cm).

    Returns:
        The figure.
    """
    space = results[0].output_space
    fig = Figure(figsize=(5.6 * len(results), 6.2))
    for k, res in enumerate(results):
        ax, cols = path_axes(fig, space, (1, len(results), k + 1))
        over_time = len(cols) == 1
        color = MODE_COLORS.get(res.mode, "tab:green")
        world = None if robot is None or res.q is None or over_time else _world_axes(robot, cols)
        if world is not None:
            _draw_robot(ax, robot, res.q[0], world, "0.6", 0.7, label="robot at A")
            _, platform, _ = robot_outline(robot, res.q[-1], world)
            if len(platform) > 1:
                ax.plot(*_closed(platform).T, "--", color=color, lw=1.5, label=f"platform at t = {res.t[-1]:.2f} s")
        draw_path(ax, cols, res.t, res.poses, "-", color=color, lw=2, label="path")
        angles = space.rotational
        if len(cols) == 2 and len(angles) == 1:  # planar: orientation markers along the path
            yaw = angles[0]
            size = marker_size or max(0.07 * float(np.ptp(res.poses[:, cols], axis=0).max()), 0.01)
            idx = np.unique(np.linspace(0, len(res.t) - 1, n_markers).round().astype(int))
            for j, i in enumerate(idx):
                ax.add_patch(Polygon(_pose_marker(*res.poses[i, cols], res.poses[i, yaw], size), closed=True,
                                     fc=color, ec="k", lw=0.5, alpha=0.85,
                                     label=rf"orientation ${space.name(yaw)}$ every {res.t[idx[1]] - res.t[idx[0]]:.2f} s"
                                     if j == 0 and len(idx) > 1 else None))
            for pose in (res.start, res.target):
                ax.add_patch(Polygon(_pose_marker(*pose[cols], pose[yaw], 2 * size), closed=True,
                                     fill=False, ec="k", lw=1.0, ls=":"))
        # each label on the side away from the other point (A and B may be close, in any direction)
        away = np.sign([res.target[c] - res.start[c] for c in cols]) if not over_time else np.ones(2)
        away[away == 0] = 1.0
        for pose, name, mk in ((res.start, "A", "o"), (res.target, "B", "*")):
            text = ", ".join(f"{space.name(i)} {pose[i]:.3g} m" if not space.angular[i]
                             else f"{space.name(i)} {math.degrees(pose[i]):.0f}°" for i in range(space.n_y))
            where = ([res.t[0] if name == "A" else res.t[-1]] if over_time else []) + [pose[c] for c in cols]
            ax.plot(*([v] for v in where), mk, color="k", ms=11 if mk == "*" else 8, zorder=5)
            if len(where) == 2:
                sx, sy = away if name == "B" else -away
                ax.annotate(f"{name} [{text}]", where, xytext=(10 * sx, 10 if sy > 0 else -18),
                            textcoords="offset points", fontsize=9, ha="left" if sx > 0 else "right")
            else:
                ax.text(*where, f" {name}", fontsize=9)
        pos, ang = res.end_error
        reach = res.time_to_reach
        error = f"end error {pos:.2g} m" + (f", {_angle_text(ang)}" if space.has_angles else "")
        ax.set_title(f"{res.label}\n{error}; " + ("not within tolerance" if math.isnan(reach)
                                                  else f"reached at {reach:.2f} s"), fontsize=10)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper left", fontsize=8)
    s = results[0].settings
    fig.suptitle(f"Quadratically-optimal planning A → B (Nmax = {s.Nmax}, Nmin = {s.Nmin}, k = {s.k}, "
                 f"Ts = {1000 * s.Ts:g} ms)", fontsize=11, y=0.98)
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.08, top=0.86, wspace=0.25)
    return fig


def plot_fig4(results: list[PlanResult]) -> Figure:
    """Fig. 4: time histories of the plans, one column per mode.

    Rows: translational outputs (m); angular outputs (deg; only if the robot has them);
    their velocities (m/s, and deg/s if angular); drive efforts (one line per drive, labelled
    with the drive's name and unit: N·m revolute, N prismatic). Dashed vertical lines mark the
    planned arrival t = Nmax·Ts and, in mode (b), the step where the horizon reaches Nmin; dotted lines the end pose B and the drive
    limits (a legend entry instead when the efforts stay below a tenth of the limit: off scale). Curves are labelled with the output labels.

    Returns:
        The figure.
    """
    space = results[0].output_space
    lin, ang = space.translational, space.rotational
    rows = [("position [m]", lin, "pose", 1.0), ("orientation [deg]", ang, "pose", math.degrees(1.0)),
            ("velocity [m/s]", lin, "velocity", 1.0), ("angular velocity [deg/s]", ang, "velocity", math.degrees(1.0))]
    rows = [r for r in rows if r[1]]
    peak = max(float(np.max(np.abs(r.u), initial=0.0)) for r in results)  # the effort rows share their y axis
    fig = Figure(figsize=(6.0 * len(results), 2.4 * (len(rows) + 1)), layout="constrained")
    axes = fig.subplots(len(rows) + 1, len(results), squeeze=False, sharex="all", sharey="row")  # comparable columns
    for col, res in enumerate(results):
        s = res.settings
        ax = axes[:, col]
        t, tu = res.t, res.t[:-1]
        for a, (ylabel, idx, what, factor) in zip(ax, rows):
            for k, i in enumerate(idx):
                color = _DRIVE_COLORS[i % len(_DRIVE_COLORS)]
                name = space.name(i)
                if what == "pose":
                    a.plot(t, factor * res.poses[:, i], color=color, label=name)
                    a.axhline(factor * res.target[i], color=color, ls=":", lw=1, label="B (dotted)" if k == 0 else None)
                else:
                    a.plot(t, factor * res.velocities[:, i], color=color, label=f"d{name}/dt")
            a.set_ylabel(ylabel)
        for j in range(res.u.shape[1]):
            ax[-1].step(tu, res.u[:, j], where="post", color=_DRIVE_COLORS[j % len(_DRIVE_COLORS)],
                        label=space.drive_label(j))
        if s.limits.torque is not None:
            mark_drive_limit(ax[-1], s.limits.torque, peak, space.drive_unit)
        ax[-1].set_ylabel(f"drive effort [{space.drive_unit}]")
        for a in ax:
            a.axvline(s.duration, color="0.3", ls="--", lw=1)
            if res.mode == "b" and s.Nmax > s.Nmin:
                a.axvline((s.Nmax - s.Nmin) * s.Ts, color="0.6", ls="-.", lw=1)
            a.grid(True, alpha=0.3)
            if a.get_legend_handles_labels()[0]:
                a.legend(loc="best", fontsize=8)
        pos, angle = res.end_error
        error = f"end error {pos:.2g} m" + (f", {_angle_text(angle)}" if ang else "")
        ax[0].set_title(f"{res.label}\n{error}, ∫‖u‖²dt {res.effort_integral:.3g} {space.effort_unit}, "
                        f"peak {res.peak_drive_effort:.3g} {space.drive_unit}", fontsize=10)
        note = "dashed: planned arrival Nmax·Ts" + ("; dash-dot: N reaches Nmin" if res.mode == "b" else "")
        ax[-1].set_xlabel(f"t [s]    ({note})")
    fig.suptitle("Time histories of the planned moves", fontsize=11)
    return fig
