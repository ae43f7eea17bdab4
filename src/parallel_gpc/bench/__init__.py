"""The benchmark harness of the control step (``parallel-gpc bench``).

* :mod:`.problems` — what to run (:class:`BenchConfig`), the closed-loop samples along the
  S-curve and the controllers that replay them;
* :mod:`.store` — what is recorded per (section, robot, N, method);
* :mod:`.harness` — :func:`run_benchmark` times every method on those problems and returns the
  rows; :func:`closed_loop_wall_time`;
* :mod:`.report` — ratios, targets, the text table and the Markdown report;
* :mod:`.qpmpc` — the same LTV problem in the ``qpmpc`` package's terms (the comparison rows).
"""

from .._lazy import lazy_exports

_PUBLIC = {
    "BenchConfig": "problems", "run_benchmark": "harness", "write_benchmark": "harness",
    "closed_loop_wall_time": "harness", "lapack_qr_unit": "harness",
    "format_table": "report", "format_targets": "report", "markdown_report": "report", "evaluate_targets": "report", "machine_info": "report",
    "TARGETS": "report",
}

__all__ = list(_PUBLIC)

__getattr__, __dir__ = lazy_exports(__name__, globals(), _PUBLIC)
