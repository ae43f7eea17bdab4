"""Figures, one module per family; each function returns a :class:`matplotlib.figure.Figure`
and :func:`save_figure` writes one (the only place figures touch the file system). Importing them
never changes the matplotlib backend.

* :mod:`.tracking` — closed-loop runs (the paper's Fig. 2): paths, time histories, the comparison;
* :mod:`.planning` — the planner (the paper's Fig. 3 and 4);
* :mod:`.robustness` — the robustness study;
* :mod:`.sweep` — a sweep's table: heatmaps, Pareto front, robustness bands;
* :mod:`.bench` — the benchmark: median time per call vs N.
"""

from .._lazy import lazy_exports

_PUBLIC = {
    "save_figure": "common",
    "plot_paths": "tracking", "plot_time_histories": "tracking", "plot_comparison": "tracking",
    "plot_fig3": "planning", "plot_fig4": "planning", "robot_outline": "planning",
    "plot_robustness": "robustness",
    "heatmap": "sweep", "pareto_front": "sweep", "pareto_mask": "sweep", "robustness_bands": "sweep",
    "plot_sweep": "sweep", "check_plots": "sweep",
    "plot_results": "bench",
}

__all__ = list(_PUBLIC)

__getattr__, __dir__ = lazy_exports(__name__, globals(), _PUBLIC)
