"""Run sweep cells as independent tasks: serially in-process or on a Dask cluster.

``run_sweep(spec_or_cells, workers=…, scheduler=…, store=…)``:

* ``workers=0`` — serial, in this process (debugging; exceptions show where they happen);
* ``workers=None`` or n ≥ 1 — a local Dask cluster (``LocalCluster``: n worker processes, one
  thread each, bound to 127.0.0.1 (its HTTP port too); default n = CPU cores), started and closed here;
* ``scheduler="tcp://HOST:PORT"`` (or a ``distributed.Client``) — an existing cluster whose
  workers can import ``parallel_gpc`` and read the robot files.

Cells go to Dask in batches, one task per batch (:func:`run_cells`), sized as the sweep runs: on
a running cluster the first tasks are single cells; then a batch holds about
:data:`BATCH_SECONDS` of work at the mean cell time measured so far, and never more than its
share of the cells left (:data:`IN_FLIGHT` batches queued per worker), so the workers finish
together. A cell of 0.1 s thus pays the scheduler's 5–25 ms per task once per ten cells, not
once per cell. The records of a batch are journalled as it returns. A sweep on a local cluster
it starts itself first runs cells in this process for :data:`PROBE_SECONDS` (or until the
cluster clearly pays, :data:`PROBE_MARGIN`): if the work left (cells left × mean cell time) would
not pay for starting the cluster (:func:`local_cluster_cost` per the time the extra workers
save) the rest runs here too, so a small sweep is never slower than a serial one; otherwise the
cluster's first batches are sized from the probe's time per cell (no single-cell tasks).

Local workers are forked from this process where the platform allows it (:data:`START_METHOD`,
Linux): they start with the modules the probe imported (the package, Pinocchio, the compiled
core) instead of importing them again (spawned: ~1.7 CPU-s per worker), and Dask's periodic
checks run seldom (:data:`CLUSTER_CONFIG`). Elsewhere they are spawned and get this process's
``sys.path``, so a package found through ``PYTHONPATH`` or an editable install is found by the
workers too. A progress bar shows done / failed / ETA as cells (batches) finish
(``distributed.as_completed``). A cell that fails is a record with its error, a cell whose
closed loop diverged a record of the part run; the sweep goes on. Ctrl-C cancels the cells not
yet finished and keeps the finished ones (already journalled in the store; a batch still
running is lost, at most :data:`BATCH_SECONDS` per worker of work), so a rerun resumes; the
local cluster's workers ignore Ctrl-C (the sweep stops them) and the cluster's shutdown is
quiet. A store is locked while the sweep runs: a second sweep into the same folder is refused.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import re
import signal
import statistics
import sys
import threading
import time
import uuid
from collections import deque
from dataclasses import dataclass, field

from tqdm import tqdm

from ..errors import InvalidParameterError
from .spec import SweepSpec, failed_record, run_cell
from .store import SweepStore, records_frame

#: A Dask scheduler address: ``PROTOCOL://HOST:PORT`` (e.g. ``tcp://10.0.0.5:8786``).
SCHEDULER_ADDRESS = re.compile(r"^[a-z][a-z0-9+.-]*://\S+:\d{1,5}$")
#: Work per Dask task, s: a batch holds this much at the mean cell time measured so far (the
#: scheduler's 5–25 ms per task is ≤ 2.5 % of it; Ctrl-C loses at most this much per worker).
BATCH_SECONDS = 1.0
#: Batches queued per worker (one running, the next ready: no idle gap between two).
IN_FLIGHT = 2
#: In-process run time before deciding whether a local cluster pays for itself, s.
PROBE_SECONDS = 0.5
#: The probe decides sooner, after any cell, once the work left would repay the cluster's cost
#: this many times over (64 cells of 0.13 s: after the first; the other worker stops idling).
PROBE_MARGIN = 4.0
#: How a sweep's own local workers are started (multiprocessing): forked on Linux (the workers
#: inherit this process's imports; on macOS fork is unsafe, on Windows absent), else spawned.
START_METHOD = "fork" if sys.platform.startswith("linux") else "spawn"
#: Cost of a sweep's own local cluster, s: its start-up and shutdown plus the workers' imports,
#: with a margin for the last batches' imbalance. Measured on 2 cores at load average 6.5–7.6:
#: forked 0.46–1.03 s start + 0.11–0.24 s close (0.04 CPU-s per worker); spawned 3.4–4.8 s start,
#: 5–7.6 s of imports on the workers (1.7–2.2 CPU-s each) and 1.8–2.8 s close. A cluster is
#: started only if the time its extra workers save repays it (:func:`cluster_pays`).
LOCAL_START_SECONDS = 1.0 if START_METHOD == "fork" else 3.0
#: Time to import ``dask.distributed`` in a process that has not yet, s (0.54–0.61 CPU-s measured,
#: 2 cores): paid by the first sweep of a process that starts a cluster (:func:`local_cluster_cost`).
DASK_IMPORT_SECONDS = 0.6
#: Dask settings of a sweep's own local cluster (:func:`start_local_cluster`): no statistical
#: profiler sampling the running cell's stack every 10 ms (it feeds a dashboard nobody watches),
#: and the periodic checks of the scheduler, nannies and workers (event-loop tick every 20 ms,
#: system monitor every 0.5 s, memory monitor every 0.1 s) slowed to once per second or five:
#: idle, they took 0.08 of a core in this process and 0.03 per worker (10 s idle, 2 forked
#: workers, load average 9: 0.80 CPU-s here and 0.30 per worker; slowed: 0.12 and 0.04–0.05),
#: CPU the workers need on a machine with one core per worker.
CLUSTER_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.worker.multiprocessing-method": START_METHOD,
}
#: Loggers of Dask quieted while a sweep's cluster shuts down (cancelled tasks, closing comms).
_DASK_LOGGERS = ("distributed", "tornado", "asyncio")


@dataclass
class SweepResult:
    """Outcome of :func:`run_sweep`.

    Attributes:
        records: records of the finished cells, in cell order (reused ones included), and the
            partial record (status ``"interrupted"``, not saved) of a cell Ctrl-C stopped mid-run.
        ran: cells run by this call. skipped: cells found finished in the store.
        failed: cells whose record has status ``"failed"``.
        diverged: cells whose closed loop diverged (status ``"diverged"``: metrics of the part run).
        skipped_lines: lines of the store's journal that were not records (skipped, counted).
        interrupted: Ctrl-C stopped the sweep before every cell finished.
        total: cells in the sweep.
        local: cells run in this process before deciding whether a cluster pays (its own local
            cluster only; all of them when it did not pay).
        batches: cells per Dask task, in the order submitted (empty: no cluster was used).
    """

    records: list = field(default_factory=list)
    ran: int = 0
    skipped: int = 0
    failed: int = 0
    diverged: int = 0
    skipped_lines: int = 0
    interrupted: bool = False
    total: int = 0
    local: int = 0
    batches: list = field(default_factory=list)

    @property
    def finished(self) -> int:
        """Cells finished (and saved in the store, if any): the records but an interrupted one."""
        return sum(r["status"] != "interrupted" for r in self.records)

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
            else:
                per_cell = None
                if scheduler is None:  # our own cluster: worth starting only for enough work
                    todo, per_cell = _run_probe(todo, func, collector, workers or os.cpu_count() or 1)
                if todo and not result.interrupted:
                    _run_dask(todo, func, collector, workers, scheduler, per_cell)
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


def _run_probe(cells, func, collector: _Collector, n_workers: int) -> tuple[list, float | None]:
    """Run cells in this process for :data:`PROBE_SECONDS` (less when the work left repays the
    cluster :data:`PROBE_MARGIN` times over).

    Returns:
        (the cells left for a local cluster of ``n_workers``, the probe's time per cell in s):
        no cells if the work left would not repay the cluster's start-up (:func:`cluster_pays`),
        then all ran here. One worker is a cluster asked for as such (its worker process isolates
        a crash): no probe, (cells, None).
    """
    if n_workers < 2:
        return cells, None
    queue, start = deque(cells), time.perf_counter()
    while queue and not collector.result.interrupted:
        elapsed = time.perf_counter() - start
        done = len(cells) - len(queue)
        if done:
            work_left, cost = elapsed / done * len(queue), local_cluster_cost()
            if cluster_pays(work_left, n_workers, cost * (1.0 if elapsed >= PROBE_SECONDS else PROBE_MARGIN)):
                return list(queue), elapsed / done
        collector.add(_run_one(func, queue.popleft()))
        collector.result.local += 1
    return [], None


def run_cells(cells, func=run_cell) -> tuple[list, float]:
    """Run a batch of cells one after the other (one Dask task of :func:`run_sweep`).

    Args:
        cells: the :class:`~parallel_gpc.sweeps.spec.Cell` s of the batch.
        func: the cell function.

    Returns:
        (records in cell order, wall time of the batch in s). A cell whose ``func`` raised is a
        failed record (the batch goes on).
    """
    start = time.perf_counter()
    records = [_run_one(func, cell) for cell in cells]
    return records, time.perf_counter() - start


def _run_one(func, cell) -> dict:
    try:
        return func(cell)
    except Exception as exc:  # noqa: BLE001 - a cell function that raises (run_cell records its own errors)
        return failed_record(cell, f"{type(exc).__name__}: {' '.join(str(exc).split())}")


def batch_size(left: int, n_workers: int, per_cell: float | None) -> int:
    """Cells in the next Dask task of a sweep (guided self-scheduling).

    Args:
        left: cells not yet submitted (≥ 1).
        n_workers: worker threads of the cluster (≥ 1).
        per_cell: measured time of one cell in s, or None before any batch returned.

    Returns:
        1 before any measurement; else :data:`BATCH_SECONDS` of work, at most the cells left /
        (:data:`IN_FLIGHT` · workers) so that the last batches shrink and the workers finish
        together; at least 1.
    """
    if per_cell is None:
        return 1
    share = math.ceil(left / (IN_FLIGHT * n_workers))
    return max(1, min(share, int(BATCH_SECONDS / max(per_cell, 1e-6))))


def cluster_pays(work_left: float, n_workers: int, cost: float | None = None) -> bool:
    """Whether starting a local cluster of ``n_workers`` (≥ 2) for ``work_left`` seconds of serial
    work saves time: the work the extra workers take over, ``work_left · (1 − 1/n)``, must exceed
    the cluster's ``cost`` in s (default :data:`LOCAL_START_SECONDS`)."""
    return work_left * (1 - 1 / n_workers) > (LOCAL_START_SECONDS if cost is None else cost)


def local_cluster_cost() -> float:
    """What a sweep's own local cluster costs this process, s: :data:`LOCAL_START_SECONDS`, plus
    :data:`DASK_IMPORT_SECONDS` while ``dask.distributed`` is not imported yet."""
    return LOCAL_START_SECONDS + (0.0 if "distributed" in sys.modules else DASK_IMPORT_SECONDS)


def _run_dask(cells, func, collector: _Collector, workers, scheduler, probe_per_cell: float | None) -> None:
    from dask.distributed import Client, as_completed

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
        # the workers inherit SIGINT ignored (Ctrl-C reaches this process only)
        start_quiet_resource_tracker()
        with _sigint_ignored():
            cluster = start_local_cluster(workers or os.cpu_count() or 1)
        client, own_client = Client(cluster), True
    token = uuid.uuid4().hex[:8]
    futures = {}
    queue = deque(cells)
    try:
        n_workers = max(1, sum(client.nthreads().values()))
        # per batch: its time per cell (s); the probe's (run here) sizes the first batches
        per_cell, finished = [] if probe_per_cell is None else [probe_per_cell], as_completed()

        def submit() -> None:
            # the median over batches: a worker's first task (it may import the package) counts once
            size = batch_size(len(queue), n_workers, statistics.median(per_cell) if per_cell else None)
            batch = [queue.popleft() for _ in range(min(len(queue), size))]
            future = client.submit(run_cells, batch, func, key=f"sweep-{token}-{batch[0].key}-{len(batch)}",
                                   pure=False)
            futures[future] = batch
            finished.add(future)
            collector.result.batches.append(len(batch))

        while queue and len(futures) < IN_FLIGHT * n_workers:
            submit()
        for future in finished:
            batch = futures.pop(future)
            try:
                records, seconds = future.result()
                per_cell.append(seconds / len(batch))
            except Exception as exc:  # noqa: BLE001 - the task itself failed (worker lost, unpicklable …)
                records = [failed_record(cell, f"{type(exc).__name__}: {exc}") for cell in batch]
            while queue and len(futures) < IN_FLIGHT * n_workers:  # keep the workers busy, then journal
                submit()
            for record in records:
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


def start_local_cluster(n_workers: int):
    """A Dask ``LocalCluster`` as :func:`run_sweep` starts its own: ``n_workers`` processes of one
    thread, forked where possible (:data:`START_METHOD`), with :data:`CLUSTER_CONFIG`, bound to
    127.0.0.1 (its dashboard on a free port). Also the way to keep one running for many sweeps
    (``run_sweep(…, scheduler=Client(cluster))``).

    Args:
        n_workers: worker processes (≥ 1).

    Returns:
        the running ``distributed.LocalCluster`` (close it, or use it as a context manager).

    Raises:
        InvalidParameterError: n_workers not an integer ≥ 1.
    """
    if not isinstance(n_workers, int) or isinstance(n_workers, bool) or n_workers < 1:
        raise InvalidParameterError(f"n_workers = {n_workers!r} must be a number of worker processes ≥ 1")
    import dask
    from dask.distributed import LocalCluster

    with dask.config.set(CLUSTER_CONFIG):
        return LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                            dashboard_address="127.0.0.1:0", silence_logs=logging.WARNING)


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


#: warnings filter of multiprocessing's resource tracker process (its shutdown report)
TRACKER_QUIET = "ignore::UserWarning:multiprocessing.resource_tracker"


def start_quiet_resource_tracker() -> None:
    """Start multiprocessing's resource tracker (shared by this process and the cluster's worker
    processes) without its shutdown report: after Ctrl-C stops a sweep, the worker processes die
    holding a semaphore of the cluster's queues, and the tracker — which still unlinks it — printed
    "There appear to be 1 leaked semaphore objects" as a Python warning after our one-line message.
    The filter reaches that process only (PYTHONWARNINGS is set while it starts, then restored)."""
    from multiprocessing import resource_tracker

    old = os.environ.get("PYTHONWARNINGS")
    os.environ["PYTHONWARNINGS"] = TRACKER_QUIET if not old else f"{old},{TRACKER_QUIET}"
    try:
        resource_tracker.ensure_running()
    finally:
        if old is None:
            del os.environ["PYTHONWARNINGS"]
        else:
            os.environ["PYTHONWARNINGS"] = old


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
