"""Figures of closed-loop runs (paper Fig. 2): the path in the plane or space of the robot's
translational outputs, and time histories; axes named by the output labels, in their units.

Each function returns a :class:`matplotlib.figure.Figure`; save it with
:func:`~parallel_gpc.plots.common.save_figure` or ``fig.savefig``.
"""

from __future__ import annotations

import textwrap

import numpy as np
from matplotlib.figure import Figure

from ..gpc import pose_error_norms
from .common import mark_drive_limit
from .paths import draw_path, path_axes
from ..studies import SimulationResult

def plot_paths(results: dict[str, SimulationResult], title: str = "platform path") -> Figure:
    """Reference and tracked paths in the plane or space of the translational outputs (axes
    named by the output labels, in m), one line per GPC form; for planar [x, y, ψ] outputs small
    orientation markers along the path; with one translational output, that coordinate over time.
    A reference that holds one pose is drawn as a cross."""
    fig = Figure(figsize=(5.5, 5.5), layout="tight")
    first = next(iter(results.values()))
    space = first.output_space
    ax, cols = path_axes(fig, space)
    if len(cols) > 1 and not np.ptp(first.reference[:, cols], axis=0).any():  # a hold: one point, no line
        draw_path(ax, cols, first.t[:1], first.reference[:1], "kx", ms=12, mew=2, label="reference (hold)")
    else:
        draw_path(ax, cols, first.t, first.reference, "k--", lw=2, label="reference")
    angles = space.rotational
    # orientation markers: 5 % of the drawn extent (a path of 8 mm got 2.5 mm markers from a 5 cm floor)
    extent = max(float(np.ptp(np.vstack([first.reference[:, cols], *(r.pose[:, cols] for r in results.values())]),
                              axis=0).max()), 1e-9)
    for name, res in results.items():
        draw_path(ax, cols, res.t, res.pose, lw=1.2, label=name)
        if len(cols) == 2 and len(angles) == 1:  # planar: the platform's orientation along the path
            step = max(1, len(res.t) // 12)
            size = 0.05 * extent
            for k in range(0, len(res.t), step):
                (x, y), psi = res.pose[k, cols], res.pose[k, angles[0]]
                ax.plot([x, x + size * np.cos(psi)], [y, y + size * np.sin(psi)], color="0.4", lw=0.8)
    ax.set_title("\n".join(textwrap.wrap(title, 56)))  # the figure is 5.5 in wide: long titles wrap
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    return fig


def plot_time_histories(results: dict[str, SimulationResult], title: str = "time histories") -> Figure:
    """Over time (s), one column per GPC form: the tracking error of each output (one panel
    each, mm or mrad), the velocities (m/s and rad/s panels for the outputs present) and the
    drive efforts (one line per drive, labelled with the drive's name and unit: N·m revolute,
    N prismatic)."""
    names = list(results)
    space = results[names[0]].output_space
    groups = [(idx, unit) for idx, unit in ((space.translational, "m/s"), (space.rotational, "rad/s")) if idx]
    rows = space.n_y + len(groups) + 1
    fig = Figure(figsize=(5.0 * len(names), 1.7 * rows + 1.0), layout="constrained")
    axes = fig.subplots(rows, len(names), sharex=True, squeeze=False)
    for col, name in enumerate(names):
        res = results[name]
        err = res.error
        for i in range(space.n_y):
            ax = axes[i, col]
            ax.plot(res.t, 1e3 * err[:, i], color=f"C{i}")
            ax.set_ylabel(f"error {space.axis_label(i, 'm')}")
        axes[0, col].set_title(name)
        for g, (idx, unit) in enumerate(groups):
            ax = axes[space.n_y + g, col]
            for i in idx:
                ax.plot(res.t, res.velocity[:, i], color=f"C{i}", label=f"d{space.name(i)}/dt")
            ax.set_ylabel(f"velocity [{unit}]")
            ax.legend(fontsize=7, ncol=3)
        ax_u = axes[-1, col]
        for j in range(res.u.shape[1]):
            ax_u.plot(res.t, res.u[:, j], label=space.drive_label(j))
        ax_u.set_ylabel(f"drive effort [{space.drive_unit}]")
        ax_u.set_xlabel("t [s]")
        ax_u.legend(fontsize=7, ncol=2)
        for ax in axes[:, col]:
            ax.grid(True, alpha=0.3)
    fig.suptitle(title)
    return fig


def plot_comparison(runs: dict, limits=None, title: str = "GPC forms compared"):
    """The forms side by side on shared axes: position and orientation error norms (mm and
    mrad, log scale; orientation only for robots with angular outputs) with the disturbance
    estimate off (dashed) and on (solid), drive efforts (the robot's drive unit) with the
    estimate on, and the limit lines if one is set (a legend entry instead when the efforts stay
    below a tenth of it).

    Args:
        runs: results keyed by (form, estimator gain α), as from
            :func:`~parallel_gpc.studies.comparison.run_comparison`.
        limits: the runs' :class:`~parallel_gpc.limits.Limits` (its torque limit is drawn), or None.
        title: figure title.

    Returns:
        A :class:`matplotlib.figure.Figure`.
    """
    forms = list(dict.fromkeys(form for form, _ in runs))
    gains = sorted({gain for _, gain in runs})
    space = next(iter(runs.values())).output_space
    rows = 3 if space.has_angles else 2  # no orientation row without angular outputs
    peak = max(float(np.max(np.abs(r.u), initial=0.0)) for (_, gain), r in runs.items() if gain == gains[-1])
    fig = Figure(figsize=(4.2 * len(forms), 2.9 * rows), layout="constrained")
    axes = fig.subplots(rows, len(forms), sharex="all", sharey="row", squeeze=False)
    for col, form in enumerate(forms):
        ax_p, ax_u = axes[0, col], axes[-1, col]
        for gain in gains:
            res = runs.get((form, gain))
            if res is None:
                continue
            style = "-" if gain == gains[-1] else "--"
            label = f"estimator α = {gain:g}"
            pos, ang = pose_error_norms(res.error, res.angular)
            ax_p.semilogy(res.t, np.maximum(1e3 * pos, 1e-9), style, label=label)
            if rows == 3:
                axes[1, col].semilogy(res.t, np.maximum(1e3 * ang, 1e-9), style, label=label)
            if gain == gains[-1]:
                for j in range(res.u.shape[1]):
                    ax_u.plot(res.t, res.u[:, j], lw=1.0, label=space.drive_label(j))
        if limits is not None and limits.torque is not None:
            mark_drive_limit(ax_u, limits.torque, peak, space.drive_unit)
        ax_p.set_title(form)
        ax_u.set_xlabel("t [s]")
        for ax in axes[:, col]:
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=7, loc="best")
    axes[0, 0].set_ylabel("position error [mm]")
    if rows == 3:
        axes[1, 0].set_ylabel("orientation error [mrad]")
    axes[-1, 0].set_ylabel(f"drive effort [{space.drive_unit}] (α = {gains[-1]:g})")
    fig.suptitle(title)
    return fig
