"""Figures of closed-loop runs (paper Fig. 2): path in the plane and time histories.

Each function returns a :class:`matplotlib.figure.Figure`; save it with
:func:`~parallel_gpc.plots.common.save_figure` or ``fig.savefig``.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from ..gpc.references import pose_error_norms
from ..studies.simulation import SimulationResult

_DOTTED = {"x": "ẋ", "y": "ẏ", "z": "ż", "ψ": "ψ̇"}


def _channels(res: SimulationResult) -> list[tuple[str, bool]]:
    """(name, is angle) of each output: x, y, ψ for planar robots; x, y, z and roll φ, pitch θ,
    yaw ψ for spatial ones (``res.angular``; None is the planar convention)."""
    n = res.pose.shape[1]
    angular = np.arange(n) >= 2 if res.angular is None else np.asarray(res.angular, dtype=bool)
    lin, ang = iter(("x", "y", "z")), iter(("ψ",) if angular.sum() == 1 else ("φ", "θ", "ψ"))
    return [(next(ang if a else lin, f"y{i + 1}"), bool(a)) for i, a in enumerate(angular)]


def plot_paths(results: dict[str, SimulationResult], title: str = "platform path") -> Figure:
    """Reference and tracked platform paths in the x–y plane (m), one line per GPC form (with
    orientation markers for planar robots; a top view for spatial ones)."""
    fig = Figure(figsize=(5.5, 5.5), layout="tight")
    ax = fig.subplots()
    first = next(iter(results.values()))
    ax.plot(first.reference[:, 0], first.reference[:, 1], "k--", lw=2, label="reference")
    for name, res in results.items():
        ax.plot(res.pose[:, 0], res.pose[:, 1], lw=1.2, label=name)
        step = max(1, len(res.t) // 12)
        planar = [c for c, _ in _channels(res)] == ["x", "y", "ψ"]
        for k in range(0, len(res.t), step if planar else len(res.t) + 1):  # platform orientation markers
            x, y, psi = res.pose[k, :3]
            ax.plot([x, x + 0.03 * np.cos(psi)], [y, y + 0.03 * np.sin(psi)], color="0.4", lw=0.8)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    return fig


def plot_time_histories(results: dict[str, SimulationResult], title: str = "time histories") -> Figure:
    """Tracking error (mm, mrad), platform velocity and drive torques (N·m) over time (s), one
    column per GPC form."""
    names = list(results)
    fig = Figure(figsize=(5.0 * len(names), 8.0), layout="tight")
    axes = fig.subplots(3, len(names), sharex=True, squeeze=False)
    for col, name in enumerate(names):
        res = results[name]
        ax_e, ax_v, ax_u = axes[:, col]
        err = res.error
        channels = _channels(res)
        for i, (label, angle) in enumerate(channels):
            ax_e.plot(res.t, 1e3 * err[:, i], label=f"{label} [mrad]" if angle else label)
        ax_e.set_ylabel("error [mm, mrad]")
        ax_e.set_title(f"{name}")
        ax_e.legend(fontsize=7)
        for i, (label, angle) in enumerate(channels):
            dotted = _DOTTED.get(label, label + "\u0307")
            ax_v.plot(res.t, res.velocity[:, i], label=f"{dotted} [rad/s]" if angle else f"{dotted} [m/s]")
        ax_v.set_ylabel("velocity")
        ax_v.legend(fontsize=7)
        for j in range(res.u.shape[1]):
            ax_u.plot(res.t, res.u[:, j], label=f"u{j + 1}")
        ax_u.set_ylabel("drive torque [N·m]")
        ax_u.set_xlabel("t [s]")
        ax_u.legend(fontsize=7, ncol=2)
        for ax in (ax_e, ax_v, ax_u):
            ax.grid(True, alpha=0.3)
    fig.suptitle(title)
    return fig


def plot_comparison(runs: dict, limits=None, title: str = "GPC forms compared"):
    """The forms side by side on shared axes: position and orientation error norms (mm and
    mrad, log scale) with the disturbance estimate off (dashed) and on (solid), drive torques
    (N·m) with the estimate on, and the torque limit lines if one is set.

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
    fig = Figure(figsize=(4.2 * len(forms), 8.5), layout="constrained")
    axes = fig.subplots(3, len(forms), sharex="all", sharey="row", squeeze=False)
    for col, form in enumerate(forms):
        ax_p, ax_a, ax_u = axes[:, col]
        for gain in gains:
            res = runs.get((form, gain))
            if res is None:
                continue
            style = "-" if gain == gains[-1] else "--"
            label = f"estimator α = {gain:g}"
            pos, ang = pose_error_norms(res.error, res.angular)
            ax_p.semilogy(res.t, np.maximum(1e3 * pos, 1e-9), style, label=label)
            ax_a.semilogy(res.t, np.maximum(1e3 * ang, 1e-9), style, label=label)
            if gain == gains[-1]:
                for j in range(res.u.shape[1]):
                    ax_u.plot(res.t, res.u[:, j], lw=1.0, label=f"u{j + 1}")
        if limits is not None and limits.torque is not None:
            lim = float(np.max(limits.torque))
            for sign in (1, -1):
                ax_u.axhline(sign * lim, color="k", ls=":", lw=1, label="torque limit" if sign > 0 else None)
        ax_p.set_title(form)
        ax_u.set_xlabel("t [s]")
        for ax in (ax_p, ax_a, ax_u):
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=7, loc="best")
    axes[0, 0].set_ylabel("position error [mm]")
    axes[1, 0].set_ylabel("orientation error [mrad]")
    axes[2, 0].set_ylabel(f"drive torque [N·m] (α = {gains[-1]:g})")
    fig.suptitle(title)
    return fig
