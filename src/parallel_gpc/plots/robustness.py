"""Figure of the robustness study: tracking error vs mass change, noise and a constant force."""

from __future__ import annotations

import math

from matplotlib.figure import Figure

from ..sweeps import RobustnessResult


def plot_robustness(result: RobustnessResult) -> Figure:
    """Three panels: RMS position error vs mass change, vs noise level, and steady-state error vs
    the constant load on the first output (a force in N, a moment in N·m for an angle; named by
    the output label), one line per form, the error axes from 0. Diverged runs are left out."""
    forms = list(dict.fromkeys(r["form"] for r in result.rows))
    labels, angular = result.settings.get("outputs", ["x"]), result.settings.get("angular", [False])
    force = f"{'moment' if angular[0] else 'force'} on output {labels[0]} [{'N·m' if angular[0] else 'N'}]"
    panels = (("mass", "plant mass / inertia change [%]", "rms_position_error_mm", "RMS position error [mm]"),
              ("noise", "pose noise σ [m, rad]", "rms_position_error_mm", "RMS position error [mm]"),
              ("disturbance", force, "steady_state_error_mm", "steady-state position error [mm]"))
    fig = Figure(figsize=(14, 4.2), layout="constrained")
    axes = fig.subplots(1, 3)
    for ax, (study, xlabel, key, ylabel) in zip(axes, panels):
        for form in forms:
            nominal = [r for r in result.rows if r["form"] == form and r["study"] == "nominal"]
            rows = nominal + [r for r in result.rows if r["form"] == form and r["study"] == study]
            pts = sorted((r["value"], r[key]) for r in rows if r["status"] == "ok")
            pts = [(x, y) for x, y in pts if not math.isnan(y)]
            if pts:
                xs, ys = zip(*pts)
                ax.plot(xs, ys, "o-", label=form)
            for r in rows:
                if r["status"].startswith("diverged"):
                    ax.annotate("diverged", (r["value"], 0), textcoords="offset points", xytext=(0, 5),
                                fontsize=7, rotation=90)
        if study == "noise":
            ax.set_xscale("symlog", linthresh=1e-6)
        # errors are norms: from 0 (rounding noise of 1e-14 mm is not drawn as a trend), 8 % above the largest
        top = max((float(max(line.get_ydata(), default=0.0)) for line in ax.lines), default=0.0)
        ax.set_ylim(0.0, 1.08 * top if top > 0.0 else None)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.set_title(study)
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    s = result.settings
    fig.suptitle(f"GPC robustness, {s.get('robot')}: Ts = {s.get('Ts')} s, N = {s.get('N')}, "
                 f"Qy = {s.get('Qy')}, Qu = {s.get('Qu')}, {s.get('reference')} reference"
                 + (" (interrupted)" if result.interrupted else ""))
    return fig
