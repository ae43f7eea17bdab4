"""Closed-loop studies: simulation of a controller on a plant, tracking runs, the forms compared.

* :mod:`.simulation` — :func:`simulate` one controller against a plant, the recorded
  :class:`SimulationResult`;
* :mod:`.tracking` — :func:`run_tracking` builds the controller's model and the plant from
  :class:`TrackingSettings` and runs every form; :func:`metrics_table`;
* :mod:`.comparison` — the paper's Fig. 2 comparison measured (``parallel-gpc demo``), and the
  encoder-only loop beside the full-state one (:func:`sensors_table`);
* :mod:`.tables` — the one column mechanism of those text tables (:func:`text_table`, :class:`Column`).

Many closed loops as tasks (sweeps, the robustness study) are :mod:`parallel_gpc.sweeps`; figures
are :mod:`parallel_gpc.plots`; the benchmark harness is :mod:`parallel_gpc.bench`.
"""

from .._lazy import lazy_exports

_PUBLIC = {
    "DIVERGENCE_ERRORS": "simulation", "FLAT_KEYS": "tracking",
    "SimulationResult": "simulation", "simulate": "simulation", "null_space_component": "simulation",
    "null_space_components": "simulation",
    "TrackingSettings": "tracking", "run_tracking": "tracking", "metrics_table": "tracking",
    "run_limits": "tracking", "LIMIT_SOURCES": "tracking",
    "DEMO_SETTINGS": "comparison", "run_comparison": "comparison", "comparison_table": "comparison",
    "sensors_table": "comparison",
    "deadbeat_check": "comparison", "DeadbeatCheck": "comparison", "steady_state_error": "comparison",
    "one_step_deadbeat_input": "comparison",
    "run_loop": "loop",
    "Column": "tables", "text_table": "tables",
}

__all__ = list(_PUBLIC)

__getattr__, __dir__ = lazy_exports(__name__, globals(), _PUBLIC)
