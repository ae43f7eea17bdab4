"""Figure of the benchmark: median time per call vs horizon N, one panel per section."""

from __future__ import annotations

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure


def plot_results(rows: list[dict]) -> Figure:
    """Median time vs N per back end: one panel per section, one line style per robot."""
    sections = ["unconstrained", "limited", "step", "loop", "qpmpc"]
    robots = list(dict.fromkeys(r["robot"] for r in rows))  # run order: the default robot first
    fig = Figure(figsize=(13, 14), layout="tight")
    axes = fig.subplots(3, 2)
    axes = axes.ravel()
    styles = ["-", "--", ":", "-."]
    markers = ["o", "s", "^", "D", "v", "P"]  # with the line style: five robots stay apart
    titles = {"unconstrained": "unconstrained solve", "limited": "solve with binding torque limits",
              "step": "full control step (GPCController.step), replayed",
              "loop": "full control step in the closed loop", "qpmpc": "LTV MPC problem: ours vs qpmpc"}
    for ax, section in zip(axes, sections):
        methods = list(dict.fromkeys(r["method"] for r in rows if r["section"] == section))
        # one colour per method of the panel (tab10 repeats after ten: the step panels have ~20)
        palette = colormaps["tab10" if len(methods) <= 10 else "tab20"]
        colors = palette(np.arange(len(methods)) % palette.N)
        for mi, method in enumerate(methods):
            for ri, robot in enumerate(robots):
                pts = sorted((r["N"], r["median_us"]) for r in rows if r["section"] == section
                             and r["method"] == method and r["robot"] == robot and r["median_us"])
                if pts:
                    ax.plot([p[0] for p in pts], [p[1] for p in pts], styles[ri % 4], marker=markers[ri % 6], ms=3,
                            color=colors[mi], label=method if ri == 0 else None)
        ax.set_yscale("log")
        ax.set_xlabel("horizon N")
        ax.set_title(titles[section])
        ax.grid(True, which="both", alpha=0.3)
        if ax.lines:  # a section the run did not measure (e.g. qpmpc not installed) stays an empty panel
            ax.legend(fontsize=7, loc="upper left")
        ax.set_ylabel("median time per call [µs]")
    for ax in axes[len(sections):]:
        ax.axis("off")
    fig.suptitle("GPC on the S-curve: " + ", ".join(f"{r} ({styles[i % 4]} {markers[i % 6]})"
                                                    for i, r in enumerate(robots)))
    return fig
