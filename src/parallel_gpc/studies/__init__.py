"""Studies layer: closed-loop simulation, tracking runs, robustness study, sweeps, benchmark harness, plots.

The figures live in one module per family (``plots_tracking``, ``plots_planning``,
``plots_robustness``, ``plots_bench``, ``plots_sweep``); each returns a
:class:`matplotlib.figure.Figure`, and :func:`save_figure` writes one. Importing them never
changes the matplotlib backend. Sweeps (``sweep``, ``sweep_runner``, ``sweep_store``) run many
closed loops as independent tasks, serially or on Dask.
"""

from .simulation import SimulationResult, simulate
from .tracking import TrackingSettings, metrics_table, run_tracking
from .robustness import COLUMNS, RobustnessResult, robustness_cases, robustness_study
from .plots_common import save_figure
from .sweep import Cell, SweepSpec, load_spec, run_cell
from .sweep_runner import SweepResult, run_sweep
from .sweep_store import SweepStore, load_results

__all__ = ["SimulationResult", "simulate", "TrackingSettings", "metrics_table", "run_tracking",
           "COLUMNS", "RobustnessResult", "robustness_cases", "robustness_study", "save_figure",
           "Cell", "SweepSpec", "load_spec", "run_cell", "SweepResult", "run_sweep", "SweepStore", "load_results"]
