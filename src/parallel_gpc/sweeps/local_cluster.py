"""A sweep's own local Dask cluster: its settings, what it costs, and its start and stop in the background.

:func:`start_local_cluster` starts the cluster :func:`~parallel_gpc.sweeps.runner.run_sweep` uses
when it is given no scheduler (also the way to keep one running for many sweeps);
:func:`cluster_pays` and :func:`local_cluster_cost` decide whether it is worth starting.
:class:`BackgroundCluster` starts it in a thread while this process keeps running cells, and stops
it in that thread once told to, so that the start-up and the shutdown overlap useful work; joining
it (:meth:`BackgroundCluster.join`, which a second Ctrl-C does not cut short) guarantees that the
workers are gone.

Forking next to a running cell. Local workers are forked where the platform allows it
(:data:`START_METHOD`): a child process gets a copy of every lock of this process in the state it
had at the fork, so a fork while this process's main thread is inside a cell (BLAS, the compiled
core, malloc) could hand the workers a lock that nobody will release. Hence :data:`FORK_GATE`
(:class:`ForkGate`): every ``os.fork`` of this process passes it just before forking (an at-fork
hook, installed with the first cluster started in the background), and the code running cells
next to a starting cluster holds it around each cell: a worker is forked between two cells, when
the main thread is in the same state as when it waited for a cluster started in the foreground;
a fork waiting for the gate goes before the next cell.

Ctrl-C. The thread that starts the cluster blocks SIGINT; the threads and processes it starts (Dask's
event loop, the nannies' process watchers, the forked or spawned workers) inherit that mask, so a
Ctrl-C (SIGINT to the terminal's process group) reaches this process alone and the sweep stops its
workers itself.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
import threading
import time
from typing import NamedTuple

from ..errors import InvalidParameterError

#: How a sweep's own local workers are started (multiprocessing): forked on Linux (the workers
#: inherit this process's imports; on macOS fork is unsafe, on Windows absent), else spawned.
START_METHOD = "fork" if sys.platform.startswith("linux") else "spawn"
#: Start of a sweep's own local cluster, s: from the decision to start it to its workers' first
#: cell, while this process goes on running cells (so the workers take a share of the work left
#: after it only). Measured forked on 2 cores, ``dask.distributed`` imported, this process running
#: cells of 0.1 s meanwhile (``SweepResult.timeline``: "cluster start" to "first batches"): 0.19–0.32 s
#: at idle, the fork waiting for the cell running (:data:`FORK_GATE`); 0.46–1.03 s at load average
#: 6.5–7.6. Spawned: 3.4–4.8 s at that load, before the workers' imports.
LOCAL_START_SECONDS = 0.5 if START_METHOD == "fork" else 3.0
#: What a sweep's own local cluster costs beyond its start, s: time the streams lose on a machine
#: with one core per stream — this process's cells slowed while the cluster's thread starts it
#: (0.02–0.04 s), Dask's CPU in this process and the workers (scheduler, client, nanny,
#: heartbeats: 0.02–0.2 CPU-s per sweep), the last batches' imbalance (0.04–0.11 s between this
#: process's last cell and the cluster's) and the close (0.02 s); measured at idle on 2 cores,
#: 16 cells of 0.1 s and 64 of 0.2 s (``benchmarks/bench_sweep.py``). Spawned workers import the
#: package again (1.7–2.2 CPU-s each).
LOCAL_COST_SECONDS = 0.25 if START_METHOD == "fork" else 3.0
#: Time to import ``dask.distributed`` in a process that has not yet, s (0.26–0.3 CPU-s at idle,
#: 0.54–0.61 at load, 2 cores): paid by the first sweep of a process that starts a cluster, in its
#: start (the import comes first) and in its cost (the import holds the interpreter's lock the
#: cells here need) (:func:`local_cluster_cost`).
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
DASK_LOGGERS = ("distributed", "tornado", "asyncio")


class ForkGate:
    """Keeps this process's forks out of the cells run next to a starting cluster (module docstring).

    Once installed (:meth:`install`), every ``os.fork`` of this process passes it just before
    forking; ``with gate:`` around a cell holds it for the cell. A fork waits for the cell running
    (at most :data:`FORK_WAIT_SECONDS`), and a cell waits for the forks already waiting (a cell
    does not take the gate again before them: the workers are not kept waiting cell after cell).
    Re-entrant: a cell that forks does not wait for itself.
    """

    def __init__(self):
        self._lock, self._turn, self._forks = threading.RLock(), threading.Condition(), 0
        self._held, self._installed = threading.local(), False
        #: forks of this process since the gate was installed (:meth:`wait_forked`)
        self.forked = 0

    def install(self) -> None:
        """Register the at-fork hooks (once per process; POSIX). The hooks registered last run
        first before a fork: installed after ``dask.distributed`` and the modules it imports
        (whose hooks take locks of their own: logging, concurrent.futures), the wait for a
        cell holds none of them."""
        with self._turn:
            if self._installed or not hasattr(os, "register_at_fork"):
                return
            self._installed = True
        os.register_at_fork(before=self._before_fork, after_in_parent=self._after_fork_in_parent,
                            after_in_child=self._after_fork_in_child)

    def wait_forked(self, count: int, timeout: float) -> bool:
        """Wait until :attr:`forked` ≥ ``count`` (at most ``timeout`` s); whether it is."""
        with self._turn:
            return self._turn.wait_for(lambda: self.forked >= count, timeout)

    def __enter__(self):
        with self._turn:
            while self._forks:
                self._turn.wait()
        self._lock.acquire()
        return self

    def __exit__(self, *exc):
        self._lock.release()

    def _before_fork(self) -> None:
        with self._turn:
            self._forks += 1
        self._held.value = self._lock.acquire(timeout=FORK_WAIT_SECONDS)

    def _after_fork_in_parent(self) -> None:
        with self._turn:
            self._forks -= 1
            self.forked += 1
            self._turn.notify_all()
        if getattr(self._held, "value", False):
            self._lock.release()

    def _after_fork_in_child(self) -> None:
        self._forks = 0
        if getattr(self._held, "value", False):
            self._lock.release()


#: Longest a fork waits for the cell running, s: a bound, should the cell wait for a lock that
#: the forking thread holds (another module's at-fork hook run before this one).
FORK_WAIT_SECONDS = 30.0
#: The gate of this process (see :class:`ForkGate`), installed by the first :class:`BackgroundCluster`.
FORK_GATE = ForkGate()
#: Longest the thread running cells waits for its starting cluster's workers to be forked before
#: its next cell, s (:meth:`BackgroundCluster.wait_forked`): at idle they fork 0.02–0.1 s after the
#: start (``dask.distributed`` imported); a bound should the start stall.
FORK_LEAD_SECONDS = 1.0
#: How often :meth:`BackgroundCluster.wait_forked` checks that the start has not ended (failed), s.
FORK_POLL_SECONDS = 0.01


class ClusterCost(NamedTuple):
    """What a sweep's own local cluster costs (:func:`local_cluster_cost`, :func:`cluster_pays`).

    Attributes:
        start: s from the decision to start it to its workers' first cell (this process runs
            cells meanwhile).
        cost: s the streams lose to it beyond that (CPU of its start and of Dask, the last
            batches' imbalance, its close).
    """

    start: float
    cost: float


def cluster_pays(work_left: float, n_workers: int, cost: ClusterCost | None = None) -> bool:
    """Whether running ``work_left`` seconds of serial work on ``n_workers`` (≥ 2) streams — this
    process and a local cluster of ``n_workers`` − 1 workers started for it — saves time.

    This process runs cells while the cluster starts (``cost.start`` s); the work left after that
    is shared by the ``n_workers`` streams, which saves ``(work_left − start) · (1 − 1/n)``: that
    must exceed ``cost.cost``. Default cost: :data:`LOCAL_START_SECONDS`, :data:`LOCAL_COST_SECONDS`.
    """
    start, extra = (LOCAL_START_SECONDS, LOCAL_COST_SECONDS) if cost is None else cost
    return (work_left - start) * (1 - 1 / n_workers) > extra


def local_cluster_cost() -> ClusterCost:
    """What a sweep's own local cluster costs this process: :data:`LOCAL_START_SECONDS` and
    :data:`LOCAL_COST_SECONDS`, each plus :data:`DASK_IMPORT_SECONDS` while ``dask.distributed``
    is not imported yet."""
    importing = 0.0 if "distributed" in sys.modules else DASK_IMPORT_SECONDS
    return ClusterCost(LOCAL_START_SECONDS + importing, LOCAL_COST_SECONDS + importing)


def start_local_cluster(n_workers: int):
    """A Dask ``LocalCluster`` as :func:`~parallel_gpc.sweeps.runner.run_sweep` starts its own:
    ``n_workers`` processes of one thread, forked where possible (:data:`START_METHOD`), with
    :data:`CLUSTER_CONFIG`, bound to 127.0.0.1 (its dashboard on a free port). Also the way to keep
    one running for many sweeps (``run_sweep(…, scheduler=Client(cluster))``).

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


class BackgroundCluster:
    """A sweep's own local cluster, started and stopped in a thread of its own.

    The thread (SIGINT blocked, see the module docstring) starts the cluster
    (:func:`start_local_cluster`) and a ``Client``, calls ``on_up(client)`` (e.g. to submit the
    first tasks as soon as the workers are there, and collect them as they return), sets
    :attr:`up`, then waits for :meth:`stop` and closes the client and the cluster, its workers'
    Dask loggers silenced first. Whoever creates one must :meth:`join` it: then no worker process,
    Dask thread or this thread is left.

    Attributes:
        up: ``threading.Event`` set once ``on_up`` returned (or the start failed: :attr:`error`).
        value: what ``on_up`` returned. error: the exception the start or ``on_up`` raised, or None.
        timeline: (event, ``time.perf_counter()`` s) pairs: ``"cluster start"``, ``"forked"`` (the
            workers, seen by :meth:`wait_forked`), ``"cluster up"``
            (workers running), ``"client up"``, ``"on_up done"``, ``"close begin"``, ``"closed"``.
    """

    def __init__(self, n_workers: int, on_up, timeline: list | None = None, *, close_after_on_up: bool = False):
        """Start the thread.

        Args:
            n_workers: worker processes (≥ 1).
            on_up: called in the thread with the connected ``distributed.Client``; its result is
                :attr:`value`.
            timeline: a list the events are appended to (a new one if None).
            close_after_on_up: close the cluster as soon as ``on_up`` returned (it used the cluster
                for all it had to do), not only once :meth:`stop` is called.
        """
        self.up, self.value, self.error = threading.Event(), None, None
        self.timeline = [] if timeline is None else timeline
        self._on_up, self._n_workers = on_up, n_workers
        # the workers' forks: set once the thread's imports are done, with the gate's count to reach
        self._importing, self._forking, self._forks_done = "distributed" not in sys.modules, threading.Event(), 0
        self._stop = threading.Event()
        if close_after_on_up:
            self._stop.set()
        self._thread = threading.Thread(target=self._run, name="sweep cluster", daemon=True)
        self._thread.start()

    def wait_forked(self, timeout: float | None = None) -> bool:
        """Wait until the cluster's workers are forked (at most ``timeout`` s; forked workers only):
        called by the thread running cells right after the start, before its next cell, so that
        the forks do not wait in :data:`FORK_GATE` for a whole cell (the workers start one cell
        earlier, for the 0.02–0.1 s the start takes to its forks at idle). Returns at once while
        ``dask.distributed`` is still being imported (the cells go on meanwhile; the forks then
        wait in the gate). ``timeout`` (s): default :data:`FORK_LEAD_SECONDS`. Whether the workers
        are forked; marks ``"forked"`` in the timeline."""
        if START_METHOD != "fork" or (self._importing and not self._forking.is_set()):
            return False
        timeout = FORK_LEAD_SECONDS if timeout is None else timeout
        deadline = time.perf_counter() + timeout
        if not self._forking.wait(timeout):
            return False
        while not self.up.is_set() and (left := deadline - time.perf_counter()) > 0:
            if FORK_GATE.wait_forked(self._forks_done, min(left, FORK_POLL_SECONDS)):
                self._mark("forked")
                return True
        return False

    def stop(self) -> None:
        """Close the cluster in the background, once its start is over (returns at once)."""
        self._stop.set()

    def join(self) -> None:
        """Stop the cluster (if not asked yet) and wait until it is closed and the thread ended.
        A Ctrl-C while waiting is raised once the cluster is closed, not before (no worker is
        left running)."""
        self.stop()
        interrupted = False
        while self._thread.is_alive():
            try:
                self._thread.join()
            except KeyboardInterrupt:
                interrupted = True
        if interrupted:
            raise KeyboardInterrupt

    def _mark(self, event: str) -> None:
        self.timeline.append((event, time.perf_counter()))

    def _run(self) -> None:
        cluster = client = None
        try:
            self._mark("cluster start")
            # first: starting the tracker unblocks SIGINT in the thread that starts it
            start_quiet_resource_tracker()
            if hasattr(signal, "pthread_sigmask"):
                signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
            from dask.distributed import Client

            FORK_GATE.install()
            self._forks_done = FORK_GATE.forked + self._n_workers
            self._forking.set()
            cluster = start_local_cluster(self._n_workers)
            self._mark("cluster up")
            client = Client(cluster)
            self._mark("client up")
            self.value = self._on_up(client)
            self._mark("on_up done")
        except BaseException as exc:  # noqa: BLE001 - handed to the thread that waits for `up`
            self.error = exc
        finally:
            self._forking.set()
            self.up.set()
            self._stop.wait()
            self._mark("close begin")
            # the workers' loggers first: a task the close cancels, a heartbeat to the closed
            # scheduler are not the user's errors (the records say what failed)
            with quiet_loggers(*DASK_LOGGERS):
                if client is not None:
                    with contextlib.suppress(Exception):
                        client.run(silence_dask_logs, wait=True)
                for part in (client, cluster):
                    if part is not None:
                        with contextlib.suppress(Exception):
                            part.close()
            self._mark("closed")


def silence_dask_logs() -> None:
    """Silence Dask's loggers in this process for good (run on a sweep's own workers before they close)."""
    for name in DASK_LOGGERS:
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)


@contextlib.contextmanager
def quiet_loggers(*names):
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
