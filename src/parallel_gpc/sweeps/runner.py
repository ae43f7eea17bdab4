"""Run sweep cells as independent tasks: serially in-process or on a Dask cluster.

``run_sweep(spec_or_cells, workers=…, scheduler=…, store=…)``:

* ``workers=0`` — serial, in this process (debugging; exceptions show where they happen);
* ``workers=None`` or n ≥ 1 — a local Dask cluster (``LocalCluster``: n worker processes, one
  thread each, bound to 127.0.0.1 (its HTTP port too); default n = CPU cores), started and closed here;
* ``scheduler="tcp://HOST:PORT"`` (or a ``distributed.Client``) — an existing cluster whose
  workers can import ``parallel_gpc`` and read the robot files.

Spawned local workers get this process's ``sys.path`` (multiprocessing "spawn"), so a package
found through ``PYTHONPATH`` or an editable install is found by the workers too. A progress bar
shows done / failed / ETA as cells finish (``distributed.as_completed``). A cell that fails is a
record with its error; the sweep goes on. Ctrl-C cancels the cells not yet finished and keeps the
finished ones (already journalled in the store), so a rerun resumes.
"""

from __future__ import annotations

import logging
import os
import uuid
from dataclasses import dataclass, field

from tqdm import tqdm

from ..errors import InvalidParameterError
from .spec import SweepSpec, failed_record, run_cell
from .store import SweepStore, records_frame


@dataclass
class SweepResult:
    """Outcome of :func:`run_sweep`.

    Attributes:
        records: records of the finished cells, in cell order (reused ones included).
        ran: cells run by this call. skipped: cells found finished in the store.
        failed: cells whose record has status ``"failed"``.
        interrupted: Ctrl-C stopped the sweep before every cell finished.
        total: cells in the sweep.
    """

    records: list = field(default_factory=list)
    ran: int = 0
    skipped: int = 0
    failed: int = 0
    interrupted: bool = False
    total: int = 0

    def frame(self):
        """The records as a pandas DataFrame (see :func:`~parallel_gpc.sweeps.store.records_frame`)."""
        return records_frame(self.records)


class _Collector:
    """Receives records as cells finish: journal, progress bar, callback, counts."""

    def __init__(self, result: SweepResult, store, bar, on_record):
        self.result, self.store, self.bar, self.on_record = result, store, bar, on_record
        self.fresh = []

    def add(self, record: dict) -> None:
        self.result.ran += 1
        if record["status"] == "failed":
            self.result.failed += 1
        if record["status"] == "interrupted":
            self.result.interrupted = True
        elif self.store is not None:
            record = self.store.append(record)
        self.fresh.append(record)
        self.bar.update(1)
        self.bar.set_postfix(failed=self.result.failed, refresh=False)
        if self.on_record is not None:
            self.on_record(record)


def run_sweep(spec, *, workers: int | None = None, scheduler=None, store=None, progress: bool = True,
              on_record=None, retry_failed: bool = False, func=run_cell) -> SweepResult:
    """Run every cell of a sweep not already finished in ``store``.

    Args:
        spec: a :class:`~parallel_gpc.sweeps.spec.SweepSpec` or a list of cells.
        workers: 0 = serial in-process; n ≥ 1 = a LocalCluster of n processes; None = CPU cores.
        scheduler: address ``"tcp://HOST:PORT"`` of a running Dask scheduler, or a Client
            (then ``workers`` is ignored).
        store: a :class:`~parallel_gpc.sweeps.store.SweepStore`, a folder path, or None
            (keep the records in memory only).
        progress: show the progress bar (done / failed / ETA).
        on_record: callback receiving each record as its cell finishes (in this process).
        retry_failed: run the cells recorded as failed again.
        func: the cell function (default :func:`~parallel_gpc.sweeps.spec.run_cell`); it must
            be importable by the workers.

    Returns:
        :class:`SweepResult`.

    Raises:
        InvalidParameterError: workers < 0 or not an integer.
    """
    if workers is not None and (not isinstance(workers, int) or isinstance(workers, bool) or workers < 0):
        raise InvalidParameterError(f"workers = {workers!r} must be 0 (serial), a number of processes ≥ 1, or None")
    cells = spec.cells() if isinstance(spec, SweepSpec) else list(spec)
    if store is not None and not isinstance(store, SweepStore):
        store = SweepStore(store)
    if store is not None and isinstance(spec, SweepSpec):
        store.save_spec(spec)
    done = store.finished(retry_failed) if store is not None else {}
    todo, seen = [], set(done)
    for cell in cells:
        if cell.key not in seen:
            seen.add(cell.key)
            todo.append(cell)
    result = SweepResult(total=len(cells), skipped=len(cells) - len(todo))
    with tqdm(total=len(cells), initial=result.skipped, disable=not progress, desc="sweep", unit="cell") as bar:
        collector = _Collector(result, store, bar, on_record)
        try:
            if workers == 0 and scheduler is None:
                _run_serial(todo, func, collector)
            elif todo:
                _run_dask(todo, func, collector, workers, scheduler)
        except KeyboardInterrupt:
            result.interrupted = True
    by_key = {**done, **{r["key"]: r for r in collector.fresh}}
    result.records = [{**by_key[c.key], "index": c.index} for c in cells if c.key in by_key]
    result.failed = sum(r["status"] == "failed" for r in result.records)
    if store is not None:
        store.write_tables(r for r in result.records if r["status"] != "interrupted")
    return result


def _run_serial(cells, func, collector: _Collector) -> None:
    for cell in cells:
        collector.add(func(cell))
        if collector.result.interrupted:  # Ctrl-C inside a run: its partial record is kept, the sweep stops
            return


def _run_dask(cells, func, collector: _Collector, workers, scheduler) -> None:
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if isinstance(scheduler, Client):
        client, own_client = scheduler, False
    elif scheduler is not None:
        client, own_client = Client(scheduler), True
    else:
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                               host="127.0.0.1", dashboard_address="127.0.0.1:0", silence_logs=logging.WARNING)
        client, own_client = Client(cluster), True
    token = uuid.uuid4().hex[:8]
    futures = {}
    try:
        for cell in cells:
            futures[client.submit(func, cell, key=f"sweep-{token}-{cell.key}", pure=False)] = cell
        for future in as_completed(futures):
            cell = futures.pop(future)
            try:
                record = future.result()
            except Exception as exc:  # noqa: BLE001 - the task itself failed (worker lost, unpicklable …)
                record = failed_record(cell, f"{type(exc).__name__}: {exc}")
            collector.add(record)
    finally:
        if futures:
            client.cancel(list(futures))
        if own_client:
            client.close()
        if cluster is not None:
            cluster.close()
