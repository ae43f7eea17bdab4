"""Studies layer: closed-loop simulation, tracking runs, robustness study, benchmark harness, plots."""

from .simulation import SimulationResult, simulate
from .tracking import TrackingSettings, metrics_table, run_tracking
from .robustness import RobustnessResult, robustness_study

__all__ = ["SimulationResult", "simulate", "TrackingSettings", "metrics_table", "run_tracking",
           "RobustnessResult", "robustness_study"]
