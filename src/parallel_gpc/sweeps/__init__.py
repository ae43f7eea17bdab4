"""Many closed loops as independent tasks: parameter sweeps and the robustness study.

* :mod:`.spec` — a sweep spec (grid and/or seeded random samples) expanded into :class:`Cell` s;
  :func:`run_cell` runs one (a tracking run of :mod:`parallel_gpc.studies`);
* :mod:`.runner` — :func:`run_sweep` runs cells serially or on a Dask cluster;
* :mod:`.local_cluster` — a sweep's own local cluster: settings, cost, start and stop in the background;
* :mod:`.store` — a sweep's folder: the append-only journal and the tidy table
  (:func:`load_results`);
* :mod:`.robustness` — the robustness study (mass change, noise, a constant force) as a sweep.
"""

from .._lazy import lazy_exports

_PUBLIC = {
    "Cell": "spec", "SweepSpec": "spec", "load_spec": "spec", "run_cell": "spec", "failed_record": "spec",
    "cell_settings": "spec", "drive_q_indices": "spec", "drive_work": "spec", "result_metrics": "spec",
    "METRIC_COLUMNS": "spec", "TIMING_COLUMNS": "spec", "RECORD_COLUMNS": "spec", "SETTLE_FRACTION": "spec",
    "SweepResult": "runner", "run_sweep": "runner", "check_scheduler": "runner", "run_cells": "runner",
    "batch_size": "runner", "in_flight": "runner", "ClusterCost": "local_cluster", "cluster_pays": "local_cluster",
    "start_local_cluster": "local_cluster",
    "BackgroundCluster": "local_cluster", "local_cluster_cost": "local_cluster", "MAX_CELLS": "spec",
    "SPEC_MAX_BYTES": "spec",
    "SweepStore": "store", "load_results": "store", "records_frame": "store",
    "COLUMNS": "robustness", "RobustnessCase": "robustness", "RobustnessResult": "robustness",
    "DEFAULT_DISTURBANCES": "robustness", "DEFAULT_MASS_SCALES": "robustness", "DEFAULT_NOISE_LEVELS": "robustness",
    "DEFAULT_WEIGHTS": "robustness",
    "robustness_cases": "robustness", "robustness_cells": "robustness", "robustness_study": "robustness",
    "DEFAULT_MASS_SCALES": "robustness", "DEFAULT_NOISE_LEVELS": "robustness", "DEFAULT_DISTURBANCES": "robustness",
    "DEFAULT_WEIGHTS": "robustness",
}

__all__ = list(_PUBLIC)

__getattr__, __dir__ = lazy_exports(__name__, globals(), _PUBLIC)
