"""Run sweep cells as independent tasks: serially in-process or on a Dask cluster.

``run_sweep(spec_or_cells, workers=…, scheduler=…, store=…)``:

* ``workers=0`` — serial, in this process (debugging; exceptions show where they happen);
* ``workers=None`` or n ≥ 2 — n streams of cells: this process and a local Dask cluster
  (``LocalCluster``: n − 1 worker processes, one thread each, bound to 127.0.0.1 (its HTTP port
  too)), started and closed here; default n = the cores this process may run on
  (:func:`~parallel_gpc.model.native_update.available_cores`); ``workers=1`` — one worker process
  runs every cell (a cell that crashes it does not end the sweep);
* ``scheduler="tcp://HOST:PORT"`` (or a ``distributed.Client``) — an existing cluster whose
  workers can import ``parallel_gpc`` and read the robot files.

Cells go to Dask in batches, one task per batch (:func:`run_cells`), sized as the sweep runs: on
a running cluster the first tasks are single cells; then a batch holds about
:data:`BATCH_SECONDS` of work at the mean cell time measured so far, and never more than its
share of the cells left (:data:`SHARES` per stream; :data:`IN_FLIGHT` batches queued per worker),
so that the streams finish together; at the tail, when a share is one cell, one batch per worker
is queued, not two (:func:`in_flight`). A cell of 0.1 s thus pays the scheduler's 5–25 ms per task
once per ten cells, not once per cell. The records of a batch are journalled as it returns.

A sweep on a local cluster of its own (:mod:`.local_cluster`) runs cells in this process from
start to end, one at a time, and starts the cluster of n − 1 workers in the background once the
work left (cells left × their mean time here) repays its cost
(:func:`~.local_cluster.cluster_pays`: the work left once it is up, shared, saves more than it
costs; 16 cells of 0.1 s do start it), and waits for its workers' forks before its next cell
(they do not wait for a whole cell, :data:`~.local_cluster.FORK_GATE`). The moment it is up,
its workers take batches from the same queue (a cell runs once, here or there), the first ones
sized by the time per cell measured here (no single-cell tasks); this process journals their
records between two of its cells. This process is one of the n streams because it is there
anyway: a cluster of n workers would add a process, its fork, heartbeats and twice the Dask tasks
(64 cells of 0.1 s on 2 cores: 0.41–0.58 CPU-s outside the cells instead of 0.24–0.37,
``benchmarks/bench_sweep.py --overhead``), CPU taken from the cells on a machine with one core per
stream. A sweep too small to repay it never starts the cluster: it runs as a serial one. The cluster
is closed in the background as soon as its last batch returned (while this process may still run
its last cell, and while the records and tables are assembled), and ``run_sweep`` returns once it
is closed.

Local workers are forked from this process where the platform allows it
(:data:`~.local_cluster.START_METHOD`, Linux): they start with the modules the first cells
imported (the package, Pinocchio, the compiled core) instead of importing them again (spawned:
~1.7 CPU-s per worker), and Dask's periodic checks run seldom
(:data:`~.local_cluster.CLUSTER_CONFIG`). Elsewhere they are spawned and get this process's
``sys.path``, so a package found through ``PYTHONPATH`` or an editable install is found by the
workers too. A progress bar shows done / failed / ETA as cells (batches) finish. A cell that
fails is a record with its error, a cell whose closed loop diverged a record of the part run; the
sweep goes on. Ctrl-C cancels the cells not yet finished and keeps the finished ones (already
journalled in the store; a batch still running is lost, at most :data:`BATCH_SECONDS` per worker
of work), so a rerun resumes; the local cluster's workers ignore Ctrl-C (the sweep stops them)
and the cluster's shutdown is quiet. A store is locked while the sweep runs: a second sweep into
the same folder is refused.
"""

from __future__ import annotations

import contextlib
import math
import re
import statistics
import threading
import time
import uuid
from collections import deque
from dataclasses import dataclass, field
from queue import Empty, SimpleQueue

from tqdm import tqdm

from ..errors import InvalidParameterError
from .local_cluster import (
    DASK_LOGGERS,
    FORK_GATE,
    BackgroundCluster,
    cluster_pays,
    local_cluster_cost,
    quiet_loggers,
)
from .spec import SweepSpec, failed_record, run_cell
from .store import SweepStore, records_frame

#: A Dask scheduler address: ``PROTOCOL://HOST:PORT`` (e.g. ``tcp://10.0.0.5:8786``).
SCHEDULER_ADDRESS = re.compile(r"^[a-z][a-z0-9+.-]*://\S+:\d{1,5}$")
#: Work per Dask task, s: a batch holds this much at the mean cell time measured so far (the
#: scheduler's 5–25 ms per task is ≤ 2.5 % of it; Ctrl-C loses at most this much per worker).
BATCH_SECONDS = 1.0
#: Batches queued per worker (one running, the next ready: no idle gap between two).
IN_FLIGHT = 2
#: A batch holds at most the cells left / (SHARES · streams): a worker's batches in flight
#: (:data:`IN_FLIGHT`) and one share more, so that what a worker still holds when no cell is left
#: is about what this process or another worker still runs (64 cells of 0.1 s, this process and
#: one worker: the worker finished 0.3–0.47 s after this process with 2 shares, 0.01–0.32 s with 3,
#: median 0.1 s).
SHARES = IN_FLIGHT + 1
#: How often this process, waiting for its own cluster's last batches, checks that the cluster
#: has not failed, s.
RESULT_POLL_SECONDS = 0.2


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
        local: cells run in this process (its own local cluster only; all of them when the
            cluster did not pay).
        batches: cells per Dask task, in the order submitted (empty: no cluster was used).
        timeline: when the phases of the run happened, s since ``run_sweep`` began, in order:
            ``"cluster start"``, ``"forked"`` (its workers, before this process's next cell),
            ``"cluster up"``, ``"client up"``, ``"first batches"``
            (submitted), ``"local done"`` (this process ran its last cell), ``"on_up done"`` (the
            cluster's last batch returned), ``"last record"``, ``"close begin"``, ``"closed"``
            (a cluster of its own), ``"tables written"``, ``"done"``; the phases a run did not
            have are missing.
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
    timeline: dict = field(default_factory=dict)

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

    def add_all(self, records) -> None:
        """:meth:`add` each of ``records`` in turn."""
        for record in records:
            self.add(record)


def run_sweep(spec, *, workers: int | None = None, scheduler=None, store=None, progress: bool = True,
              on_record=None, retry_failed: bool = False, func=run_cell) -> SweepResult:
    """Run every cell of a sweep not already finished in ``store``.

    Args:
        spec: a :class:`~parallel_gpc.sweeps.spec.SweepSpec` or a list of cells.
        workers: 0 = serial in-process; n ≥ 2 = this process and a LocalCluster of n − 1
            processes; 1 = a LocalCluster of one process; None = the cores this process may use.
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
    start = time.perf_counter()
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
    timeline = []
    # a cluster of our own still closing is waited for on the way out, whatever happens
    with contextlib.ExitStack() as closing:
        with tqdm(total=len(cells), initial=result.skipped, disable=not progress, desc="sweep", unit="cell") as bar:
            collector = _Collector(result, store, bar, on_record)
            try:
                if workers == 0 and scheduler is None:
                    _run_serial(todo, func, collector)
                elif scheduler is None:
                    from ..model import available_cores

                    _run_own_cluster(todo, func, collector, workers or available_cores(), closing, timeline)
                else:
                    _run_on(scheduler, todo, func, collector)
            except KeyboardInterrupt:
                result.interrupted = True
        timeline.append(("last record", time.perf_counter()))
        by_key = {**done, **{r["key"]: r for r in collector.fresh}}
        result.records = [{**by_key[c.key], "index": c.index} for c in cells if c.key in by_key]
        result.failed = sum(r["status"] == "failed" for r in result.records)
        result.diverged = sum(r["status"] == "diverged" for r in result.records)
        if store is not None:
            store.write_tables(r for r in result.records if r["status"] != "interrupted")
        timeline.append(("tables written", time.perf_counter()))
    timeline.append(("done", time.perf_counter()))
    result.timeline = {event: t - start for event, t in sorted(timeline, key=lambda e: e[1])}
    return result


def _run_serial(cells, func, collector: _Collector) -> None:
    for cell in cells:
        collector.add(func(cell))
        if collector.result.interrupted:  # Ctrl-C inside a run: its partial record is kept, the sweep stops
            return


def _run_own_cluster(cells, func, collector: _Collector, n_workers: int, closing: contextlib.ExitStack,
                     timeline: list) -> None:
    """Run ``n_workers`` streams of cells: this process and a local cluster of ``n_workers`` − 1
    workers, started in the background once the work left repays it.

    The cells run here one at a time from the queue's left (each inside
    :data:`~.local_cluster.FORK_GATE`); after each, if no cluster is starting and
    :func:`~.local_cluster.cluster_pays` says the work left (cells left × their mean time here)
    repays :func:`~.local_cluster.local_cluster_cost`, a :class:`~.local_cluster.BackgroundCluster`
    of ``n_workers`` − 1 processes starts, and this process waits for its workers' forks
    (:meth:`~.local_cluster.BackgroundCluster.wait_forked`) before its next cell. The moment its
    client connects, its thread submits the first batches from the same queue (under its lock: a
    cell runs once, here or there), sized by the time per cell measured here and shared with this
    process (:class:`_Dispatch`), and hands the batches' records back as they return
    (``results``); this process keeps running cells,
    journals those records between two cells, and once the queue is empty waits for the batches
    still running. No cluster starts if the work never repays it (a small sweep runs all here, as
    ``workers=0``). ``n_workers`` = 1 (a cluster asked for as such: its process isolates a crash)
    starts one worker at once, and it runs every cell. The cluster closes in the background once
    its last batch returned (or on an error or Ctrl-C), and ``closing`` waits for it.
    """
    here = n_workers >= 2  # this process is one of the streams
    queue, lock, times, taken = deque(cells), threading.Lock(), [], []
    results = SimpleQueue()  # from the cluster's side: lists of records, an exception, None at the end

    def on_up(client):  # in the cluster's thread, the moment it is up
        with lock:
            if not queue or collector.result.interrupted:
                return None  # all ran here meanwhile, or the sweep stopped
            dispatch = _Dispatch(client, queue, func, collector.result.batches,
                                 statistics.fmean(times) if times else None, lock=lock, streams_here=int(here))
            taken.append(dispatch)
        dispatch.fill()
        timeline.append(("first batches", time.perf_counter()))
        dispatch.feed(results)  # until the last batch returned (or the sweep stopped)
        return dispatch

    cluster, busy = None, True  # busy: the cluster's side has batches to return (or may take some)
    if not here:
        cluster = BackgroundCluster(1, on_up, timeline, close_after_on_up=True)
        closing.callback(cluster.join)
    try:
        while here and not collector.result.interrupted:
            if cluster is not None and cluster.error is not None:
                raise cluster.error
            busy = busy and _add_returned(results, collector, cluster, block=False)
            with FORK_GATE:
                with lock:
                    if not queue:
                        break
                    cell = queue.popleft()
                begin = time.perf_counter()
                record = _run_one(func, cell)
                times.append(time.perf_counter() - begin)
                collector.add(record)
                collector.result.local += 1
            if cluster is None and cluster_pays(statistics.fmean(times) * len(queue), n_workers,
                                                local_cluster_cost()):
                # closed once its last batch returned: while this process may still run a cell
                cluster = BackgroundCluster(n_workers - 1, on_up, timeline, close_after_on_up=True)
                closing.callback(cluster.join)
                cluster.wait_forked()  # the workers fork now, not once the next cell is over
        timeline.append(("local done", time.perf_counter()))
        if cluster is None or collector.result.interrupted:
            return
        with lock:
            if not taken and not queue:  # every cell ran here: the cluster gets none
                return
        while busy and not collector.result.interrupted:
            busy = _add_returned(results, collector, cluster, block=True)
    finally:
        with lock:
            dispatches = list(taken)
        for dispatch in dispatches:  # Ctrl-C or an error: no more batches, the ones queued cancelled
            dispatch.stop()
        if cluster is not None:  # closed in the background; `closing` waits for it
            cluster.stop()


def _add_returned(results: SimpleQueue, collector: _Collector, cluster: BackgroundCluster | None,
                  block: bool) -> bool:
    """Hand the records of the batches returned from ``cluster`` to ``collector``: those already
    there, or (``block``) the next batch's, waiting for it. Returns False once the cluster's side
    is done; raises what it raised, or the error that stopped the cluster's start."""
    while True:
        try:
            item = results.get(timeout=RESULT_POLL_SECONDS) if block else results.get_nowait()
        except Empty:
            if not block:
                return True
            if cluster.error is not None:
                raise cluster.error from None
            continue
        if item is None:
            return False
        if isinstance(item, BaseException):
            raise item
        collector.add_all(item)
        if block:
            return True


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


def batch_size(left: int, streams: int, per_cell: float | None) -> int:
    """Cells in the next Dask task of a sweep (guided self-scheduling).

    Args:
        left: cells not yet submitted (≥ 1).
        streams: cells that run at once: the cluster's worker threads, plus this process when it
            runs cells from the same queue (≥ 1).
        per_cell: measured time of one cell in s, or None before any batch returned.

    Returns:
        1 before any measurement; else :data:`BATCH_SECONDS` of work, at most the cells left /
        (:data:`SHARES` · streams) so that the last batches shrink and the streams finish
        together; at least 1.
    """
    if per_cell is None:
        return 1
    share = math.ceil(left / (SHARES * streams))
    return max(1, min(share, int(BATCH_SECONDS / max(per_cell, 1e-6))))


def in_flight(left: int, streams: int, n_workers: int) -> int:
    """Batches a sweep keeps queued on a cluster (submitted, not returned).

    Args:
        left: cells not yet submitted. streams: as in :func:`batch_size`.
        n_workers: the cluster's worker threads.

    Returns:
        :data:`IN_FLIGHT` per worker thread (one running, the next ready); one per worker thread
        once the cells left are the last single-cell shares (``left`` ≤ :data:`SHARES` ·
        ``streams``): a cell queued behind a running one would wait there while another stream
        runs out of cells (64 cells of 0.2 s, this process and one worker: the worker's last
        batch returned 0.25 s after this process's last cell, at idle), whereas the round trip of
        a batch it waits for instead is 4–25 ms.
    """
    return (IN_FLIGHT if left > SHARES * streams else 1) * n_workers


class _Dispatch:
    """Cells of a queue as Dask tasks of a few cells each (:func:`batch_size`), kept
    :data:`IN_FLIGHT` per worker thread, their records collected as they return."""

    def __init__(self, client, queue: deque, func, batches: list, per_cell: float | None, *,
                 lock: threading.Lock | None = None, streams_here: int = 0):
        """Args:
            client: a connected ``distributed.Client``.
            queue: the cells to run (taken from its left as batches are submitted).
            func: the cell function.
            batches: a list the size of each batch submitted is appended to.
            per_cell: time of one cell measured in this process, s (sizes the first batches), or
                None (single cells until a batch returns).
            lock: held while cells are taken from ``queue`` (this process takes cells from it too).
            streams_here: cells run at the same time in this process from the same queue (its
                share of the cells left counts in the batches' sizes).
        """
        from dask.distributed import as_completed

        self.client, self.queue, self.func, self.batches = client, queue, func, batches
        self.lock = contextlib.nullcontext() if lock is None else lock
        self.n_workers = max(1, sum(client.nthreads().values()))
        self.streams = self.n_workers + streams_here
        # per batch: its time per cell (s); the one measured here sizes the first batches
        self.per_cell = [] if per_cell is None else [per_cell]
        self.futures, self.finished, self.token = {}, as_completed(), uuid.uuid4().hex[:8]
        self.stopped = False

    def fill(self) -> None:
        """Submit batches until :func:`in_flight` are queued (:data:`IN_FLIGHT` per worker, one at the
        tail) or no cell is left."""
        while not self.stopped and len(self.futures) < in_flight(len(self.queue), self.streams, self.n_workers):
            # the median over batches: a worker's first task (it may import the package) counts once
            per_cell = statistics.median(self.per_cell) if self.per_cell else None
            with self.lock:
                if not self.queue:
                    return
                size = batch_size(len(self.queue), self.streams, per_cell)
                batch = [self.queue.popleft() for _ in range(min(len(self.queue), size))]
            future = self.client.submit(run_cells, batch, self.func, pure=False,
                                        key=f"sweep-{self.token}-{batch[0].key}-{len(batch)}")
            self.futures[future] = batch
            self.finished.add(future)
            self.batches.append(len(batch))

    def collect(self, handle) -> None:
        """Hand each batch's records (a list, in cell order) to ``handle`` as it returns, keeping
        the workers busy, until every batch returned or :meth:`stop` was called."""
        for future in self.finished:
            batch = self.futures.pop(future)
            if self.stopped:
                return
            try:
                records, seconds = future.result()
                self.per_cell.append(seconds / len(batch))
            except Exception as exc:  # noqa: BLE001 - the task itself failed (worker lost, unpicklable …)
                records = [failed_record(cell, f"{type(exc).__name__}: {exc}") for cell in batch]
            self.fill()  # keep the workers busy, then journal
            handle(records)

    def feed(self, results: SimpleQueue) -> None:
        """:meth:`collect` into ``results`` (run in a thread other than the one journalling): each
        batch's records, then None, or the exception raised."""
        try:
            self.collect(results.put)
        except BaseException as exc:  # noqa: BLE001 - handed to the thread that journals
            results.put(exc)
        else:
            results.put(None)

    def stop(self) -> None:
        """Submit no more batches and cancel the ones not returned (Ctrl-C, an error)."""
        self.stopped = True
        if self.futures:
            with quiet_loggers(*DASK_LOGGERS):
                self.client.cancel(list(self.futures))


def _run_on(scheduler, cells, func, collector: _Collector) -> None:
    """Run the cells on a running cluster: a ``Client`` or a scheduler's address (connected here)."""
    from dask.distributed import Client

    if isinstance(scheduler, Client):
        client, own_client = scheduler, False
    else:
        try:
            client, own_client = Client(scheduler), True
        except (OSError, ValueError, TimeoutError) as exc:
            raise InvalidParameterError(f"cannot reach the Dask scheduler {scheduler!r}: "
                                        f"{' '.join(str(exc).split()) or type(exc).__name__}") from None
    dispatch = None
    try:
        dispatch = _Dispatch(client, deque(cells), func, collector.result.batches, None)
        dispatch.fill()
        dispatch.collect(collector.add_all)
    finally:
        if dispatch is not None:  # a shared cluster: free its workers
            dispatch.stop()
        if own_client:
            with quiet_loggers(*DASK_LOGGERS):
                client.close()
