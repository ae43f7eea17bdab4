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
record with its error, a cell whose closed loop diverged a record of the part run; the sweep
goes on. Ctrl-C cancels the cells not yet finished and keeps the finished ones (already
journalled in the store), so a rerun resumes; the local cluster's workers ignore Ctrl-C (the
sweep stops them) and the cluster's shutdown is quiet. A store is locked while the sweep runs:
a second sweep into the same folder is refused.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import signal
import threading
import uuid
from dataclasses import dataclass, field

from tqdm import tqdm

from ..errors import InvalidParameterError
from .spec import SweepSpec, failed_record, run_cell
from .store import SweepStore, records_frame

#: A Dask scheduler address: ``PROTOCOL://HOST:PORT`` (e.g. ``tcp://10.0.0.5:8786``).
SCHEDULER_ADDRESS = re.compile(r"^[a-z][a-z0-9+.-]*://\S+:\d{1,5}$")
#: Loggers of Dask quieted while a sweep's cluster shuts down (cancelled tasks, closing comms).
_DASK_LOGGERS = ("distributed", "tornado", "asyncio")


@dataclass
class SweepResult:
    """Outcome of :func:`run_sweep`.

    Attributes:
        records: records of the finished cells, in cell order (reused ones included).
        ran: cells run by this call. skipped: cells found finished in the store.
        failed: cells whose record has status ``"failed"``.
        diverged: cells whose closed loop diverged (status ``"diverged"``: metrics of the part run).
        skipped_lines: lines of the store's journal that were not records (skipped, counted).
        interrupted: Ctrl-C stopped the sweep before every cell finished.
        total: cells in the sweep.
    """

    records: list = field(default_factory=list)
    ran: int = 0
    skipped: int = 0
    failed: int = 0
    diverged: int = 0
    skipped_lines: int = 0
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
        InvalidParameterError: workers < 0 or not an integer; a scheduler that is not an address
            ``PROTOCOL://HOST:PORT`` or a Client, or that cannot be reached; the store's folder is
            in use by another sweep.
    """
    if workers is not None and (not isinstance(workers, int) or isinstance(workers, bool) or workers < 0):
        raise InvalidParameterError(f"workers = {workers!r} must be 0 (serial), a number of processes ≥ 1, or None")
    check_scheduler(scheduler)
    if store is not None and not isinstance(store, SweepStore):
        store = SweepStore(store)
    with store.locked() if store is not None else contextlib.nullcontext():
        return _run_locked(spec, workers, scheduler, store, progress, on_record, retry_failed, func)


def check_scheduler(scheduler) -> None:
    """A scheduler is None, a ``distributed.Client`` or an address ``PROTOCOL://HOST:PORT``.

    Raises:
        InvalidParameterError: naming the value and the valid forms.
    """
    if scheduler is None or type(scheduler).__name__ == "Client":
        return
    if not isinstance(scheduler, str) or not SCHEDULER_ADDRESS.match(scheduler):
        raise InvalidParameterError(f"scheduler = {scheduler!r} is not the address of a Dask scheduler; give "
                                    "PROTOCOL://HOST:PORT, e.g. tcp://127.0.0.1:8786 (or a distributed.Client)")


def _run_locked(spec, workers, scheduler, store, progress, on_record, retry_failed, func) -> SweepResult:
    cells = spec.cells() if isinstance(spec, SweepSpec) else list(spec)
    if store is not None and isinstance(spec, SweepSpec):
        store.save_spec(spec)
    done = store.finished(retry_failed) if store is not None else {}
    todo, seen = [], set(done)
    for cell in cells:
        if cell.key not in seen:
            seen.add(cell.key)
            todo.append(cell)
    result = SweepResult(total=len(cells), skipped=len(cells) - len(todo),
                         skipped_lines=store.skipped_lines if store is not None else 0)
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
    result.diverged = sum(r["status"] == "diverged" for r in result.records)
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
        try:
            client, own_client = Client(scheduler), True
        except (OSError, ValueError, TimeoutError) as exc:
            raise InvalidParameterError(f"cannot reach the Dask scheduler {scheduler!r}: "
                                        f"{' '.join(str(exc).split()) or type(exc).__name__}") from None
    else:
        with _sigint_ignored():  # the workers inherit it: Ctrl-C reaches this process only
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
        with _quiet(*_DASK_LOGGERS):
            if futures and cluster is None:  # a shared cluster: free its workers (ours is closed)
                client.cancel(list(futures))
            if futures and cluster is not None:  # our workers: no warnings about the tasks closing cancels
                with contextlib.suppress(Exception):
                    client.run(silence_dask_logs, wait=True)
            if own_client:
                client.close()
            if cluster is not None:
                cluster.close()


def silence_dask_logs() -> None:
    """Silence Dask's loggers in this process for good (run on a sweep's own workers before they close)."""
    for name in _DASK_LOGGERS:
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)


@contextlib.contextmanager
def _sigint_ignored():
    """SIGINT ignored in the block (main thread only): processes started in it inherit that."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def _quiet(*names):
    """The named loggers silenced (above CRITICAL) in the block."""
    loggers = [logging.getLogger(n) for n in names]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)
