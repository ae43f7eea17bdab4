"""Studies layer: closed-loop simulation, tracking runs, robustness study, benchmark harness, plots.

The figures live in one module per family (``plots_tracking``, ``plots_planning``,
``plots_robustness``, ``plots_bench``); each returns a :class:`matplotlib.figure.Figure`, and
:func:`save_figure` writes one. Importing them never changes the matplotlib backend.
"""

from .simulation import SimulationResult, simulate
from .tracking import TrackingSettings, metrics_table, run_tracking
from .robustness import COLUMNS, RobustnessResult, robustness_cases, robustness_study
from .plots_common import save_figure

__all__ = ["SimulationResult", "simulate", "TrackingSettings", "metrics_table", "run_tracking",
           "COLUMNS", "RobustnessResult", "robustness_cases", "robustness_study", "save_figure"]
