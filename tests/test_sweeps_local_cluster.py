"""A sweep's own local cluster (sweeps/local_cluster.py and run_sweep's path through it): started in
the background while cells keep running here, the cells left handed over once (none twice, none
lost, the serial records), stopped on success, on error and on Ctrl-C (no process or thread left),
forks kept out of a running cell, Ctrl-C kept from the workers."""

from __future__ import annotations

import math
import os
import signal
import sys
import threading
import time

import psutil
import pytest

from parallel_gpc.errors import InvalidParameterError
from parallel_gpc.sweeps import TIMING_COLUMNS, Cell, failed_record, run_sweep
from parallel_gpc.sweeps import local_cluster, runner
from parallel_gpc.sweeps.local_cluster import FORK_GATE, BackgroundCluster

#: Tiny runs: hold of the home pose, 0.1 s at Ts = 5 ms, N = 4.
TINY = {"robot": "planar_3rrr", "reference": "hold", "duration": 0.1, "Ts": 0.005, "N": 4, "Qu": 1e-4}
#: Set in this process before a cluster starts: a forked worker sees it, a spawned one does not.
_PARENT_MARK = []
#: The scripted hand-over: the cell (index) that, run here, lets the cluster come up and waits
#: until it took the cells left; the clusters started (see :func:`_scripted`).
_SCRIPT = {"at": None, "go": threading.Event(), "taken": threading.Event(), "clusters": []}


def _cells(n, **extra):
    return [Cell(i, {**TINY, "Qu": 1e-4 * (i + 1), **extra}) for i in range(n)]


def _where(cell):
    """A blank ok record whose error field says where the cell ran: 'pid thread-id'."""
    record = failed_record(cell, f"{os.getpid()} {threading.get_ident()}")
    record["status"] = "ok"
    return record


def _sleeping(cell):
    time.sleep(0.02)
    return _where(cell)


def _slow_cell(cell):
    """The real cell (its record) after 0.25 s: 12 of them outlast the cluster's start even on a loaded machine (a
    loaded run had all 12 tiny cells done here before the worker was up)."""
    time.sleep(0.25)
    return runner.run_cell(cell)


def _scripted(cell):
    """:func:`_where`; the cell ``_SCRIPT["at"]``, run in this process's main thread, releases the
    cluster's start and returns only once the cluster submitted its first batches, or found no cell
    left (or after 60 s)."""
    if cell.index == _SCRIPT["at"] and threading.current_thread() is threading.main_thread():
        _SCRIPT["go"].set()
        _SCRIPT["taken"].wait(60)
    return _where(cell)


def _threads_in_process_cluster(n_workers):
    """A cluster of ``n_workers`` worker threads in this process (cells visible by thread), started on ``go``."""
    _SCRIPT["go"].wait(60)
    from dask.distributed import LocalCluster

    return LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=False, dashboard_address=None)


@pytest.fixture
def scripted(monkeypatch):
    """run_sweep's own cluster made of threads of this process, coming up when the script says:
    a cluster is worth starting after the first cell; its start waits for ``_SCRIPT["go"]``; it
    says when it submitted its first batches, or found no cell left (``_SCRIPT["taken"]``)."""
    class Recorded(BackgroundCluster):
        def __init__(self, n_workers, on_up, timeline=None, **options):
            def then_taken(client):
                try:
                    return on_up(client)
                finally:
                    _SCRIPT["taken"].set()

            self.n_workers = n_workers
            _SCRIPT["clusters"].append(self)
            super().__init__(n_workers, then_taken, timeline, **options)

        def wait_forked(self, timeout=None):
            return False  # worker threads of this process: nothing forks (the script says when it is up)

    class FirstFill(runner._Dispatch):
        def fill(self):
            super().fill()
            _SCRIPT["taken"].set()

    monkeypatch.setattr(runner, "BackgroundCluster", Recorded)
    monkeypatch.setattr(runner, "_Dispatch", FirstFill)
    monkeypatch.setattr(runner, "local_cluster_cost", lambda: local_cluster.ClusterCost(0.0, 0.0))
    monkeypatch.setattr(local_cluster, "start_local_cluster", _threads_in_process_cluster)
    _SCRIPT["go"].clear()
    _SCRIPT["taken"].clear()
    _SCRIPT["clusters"].clear()
    yield _SCRIPT
    _SCRIPT["at"] = None


def _where_ran(result):
    main = threading.main_thread().ident
    return ["here" if r["error"] == f"{os.getpid()} {main}" else "cluster" for r in result.records]


def _no_sweep_thread():
    return not any(t.name == "sweep cluster" for t in threading.enumerate())


def test_the_cluster_coming_up_mid_cell_shares_the_cells_left(scripted):
    """The cluster (one worker: this process is the other stream of workers=2) comes up while the
    third cell runs here: it submits its first batches from the queue's left, sized by the time
    measured here; this process finishes its cell and goes on with the cells after them while the
    batches run; every cell runs once, here or there, records in order."""
    cells = _cells(20)
    scripted["at"] = 2
    result = run_sweep(cells, workers=2, progress=False, func=_scripted)
    assert result.ran == 20 and result.local + sum(result.batches) == 20
    assert [r["key"] for r in result.records] == [c.key for c in cells]
    assert [r["index"] for r in result.records] == list(range(20))
    where = _where_ran(result)
    first = sum(result.batches[:runner.IN_FLIGHT])  # the batches of the first fill, a worker's share
    assert all(size > 1 for size in result.batches[:runner.IN_FLIGHT])  # sized by the time measured here
    assert where[:3 + first] == ["here"] * 3 + ["cluster"] * first
    assert where.count("here") == result.local
    assert len({r["error"] for r in result.records if where[r["index"]] == "cluster"}) == 1  # one worker
    assert [cluster.n_workers for cluster in scripted["clusters"]] == [1]
    events = list(result.timeline)
    assert events.index("cluster start") < events.index("first batches") < events.index("local done")
    assert events.index("on_up done") < events.index("closed") < events.index("done") == len(events) - 1
    assert _no_sweep_thread()


def _until_closed(cell):
    """:func:`_where`; cell 2, run in this process's main thread, releases the cluster's start and
    returns only once that cluster is closed (or after 30 s)."""
    if cell.index == 2 and threading.current_thread() is threading.main_thread():
        _SCRIPT["go"].set()
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not any(
                "closed" in [event for event, _ in cluster.timeline] for cluster in _SCRIPT["clusters"]):
            time.sleep(0.01)
    return _where(cell)


def test_the_cluster_closes_once_its_last_batch_returned_while_a_cell_runs_here(scripted):
    """The cluster takes every cell after the third while the third runs here, and is closed as
    soon as its last batch returned, while that cell still runs: its close does not wait for it."""
    cells = _cells(20)
    result = run_sweep(cells, workers=2, progress=False, func=_until_closed)
    assert (result.ran, result.local, sum(result.batches)) == (20, 3, 17)
    assert _where_ran(result) == ["here"] * 3 + ["cluster"] * 17
    events = list(result.timeline)
    assert events.index("on_up done") < events.index("closed") < events.index("local done")
    assert _no_sweep_thread()


def test_a_cluster_up_after_the_last_cell_gets_none_and_is_stopped(scripted):
    cells = _cells(5)
    scripted["at"] = 4  # the cluster comes up while the last cell runs here: nothing is left for it
    result = run_sweep(cells, workers=2, progress=False, func=_scripted)
    assert (result.ran, result.local, result.batches) == (5, 5, [])
    assert _where_ran(result) == ["here"] * 5
    assert [r["key"] for r in result.records] == [c.key for c in cells]
    assert "closed" in result.timeline and _no_sweep_thread()


@pytest.mark.parametrize("workers, cores", [(3, None), (None, 4)])
def test_n_streams_are_this_process_and_n_minus_1_workers_by_default_the_cores_it_may_use(
        scripted, monkeypatch, workers, cores):
    """workers=3, or workers=None on a process that may use 4 cores (available_cores, the
    project's one count of cores): the cluster started has 2, resp. 3 workers, their first fill
    IN_FLIGHT batches each, each batch at most the cells left / (SHARES · streams)."""
    import parallel_gpc.model as model

    if cores is not None:
        monkeypatch.setattr(model, "available_cores", lambda: cores)
    streams = workers or cores
    scripted["at"] = 1
    result = run_sweep(_cells(60), workers=workers, progress=False, func=_scripted)
    assert result.ran == 60 and result.local + sum(result.batches) == 60
    assert [cluster.n_workers for cluster in scripted["clusters"]] == [streams - 1]
    left = 60 - 2
    for size in result.batches[:runner.IN_FLIGHT * (streams - 1)]:  # the first fill, sized from cells 0 and 1
        assert 1 < size <= math.ceil(left / (runner.SHARES * streams))
        left -= size
    assert _where_ran(result)[:2] == ["here"] * 2 and _no_sweep_thread()


def test_a_cluster_that_fails_to_start_is_one_error_and_the_cells_run_here_are_kept(monkeypatch, tmp_path):
    """The start of the sweep's own cluster raises: run_sweep raises that error (no cell waits for a
    cluster that will not come), the cells run here meanwhile are in the store, no thread is left."""
    def no_ports(n_workers):
        raise OSError("no free port on 127.0.0.1")

    monkeypatch.setattr(runner, "local_cluster_cost", lambda: local_cluster.ClusterCost(0.0, 0.0))
    monkeypatch.setattr(local_cluster, "start_local_cluster", no_ports)
    with pytest.raises(OSError, match="no free port"):
        run_sweep(_cells(200), workers=2, progress=False, func=_sleeping, store=tmp_path)
    saved = run_sweep(_cells(200), workers=0, progress=False, func=_where, store=tmp_path)
    assert 1 <= saved.skipped < 200 and _no_sweep_thread()


def test_forks_wait_for_the_cell_running_in_the_gate_and_go_before_the_next():
    """The at-fork hook: two threads that fork while the main thread holds FORK_GATE (a cell) fork
    once the gate is released, both before the main thread's next cell takes it again."""
    if not hasattr(os, "register_at_fork"):
        pytest.skip("no fork on this platform")
    FORK_GATE.install()
    forked = []

    def fork():
        pid = os.fork()
        if pid == 0:
            os._exit(0)
        forked.append(time.monotonic())
        os.waitpid(pid, 0)

    with FORK_GATE:
        threads = [threading.Thread(target=fork) for _ in range(2)]
        for thread in threads:
            thread.start()
        time.sleep(0.3)
        released = time.monotonic()
    with FORK_GATE:  # the next cell, a long one: the forks waiting do not wait for it
        time.sleep(2.0)
        next_cell_end = time.monotonic()
    for thread in threads:
        thread.join(30)
    assert len(forked) == 2 and all(released <= t < next_cell_end for t in forked)
    with FORK_GATE:  # re-entrant: a cell that itself forks does not wait for itself
        fork()
    assert len(forked) == 3


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="forked workers and /proc: Linux")
def test_a_background_cluster_forks_workers_that_block_ctrl_c_and_is_gone_after_join():
    me = psutil.Process()
    mask_before = signal.pthread_sigmask(signal.SIG_BLOCK, [])
    _PARENT_MARK.append(os.getpid())
    try:
        cluster = BackgroundCluster(2, lambda client: client.run(lambda: (os.getpid(), list(_PARENT_MARK))))
        assert cluster.up.wait(120) and cluster.error is None
        seen = dict(cluster.value.values())
        blocked = {pid: int(_proc_status(pid)["SigBlk"], 16) >> (signal.SIGINT - 1) & 1 for pid in seen}
        children = {p.pid for p in me.children(recursive=True)}
    finally:
        _PARENT_MARK.clear()
        cluster.join()
    assert len(seen) == 2 and all(mark == [os.getpid()] for mark in seen.values())  # forked from here
    assert blocked == {pid: 1 for pid in seen}  # Ctrl-C reaches this process only
    assert set(seen) <= children
    assert signal.pthread_sigmask(signal.SIG_BLOCK, []) == mask_before  # this thread's mask untouched
    assert not set(seen) & {p.pid for p in me.children(recursive=True)} and _no_sweep_thread()
    assert [event for event, _ in cluster.timeline] == ["cluster start", "cluster up", "client up", "on_up done",
                                                        "close begin", "closed"]


def _proc_status(pid):
    with open(f"/proc/{pid}/status") as status:
        return dict(line.rstrip("\n").split(":\t", 1) for line in status if ":\t" in line)


def _leftovers(before_children, before_threads):
    """Child processes and threads started since (Dask's shared offload thread and
    multiprocessing's resource tracker live as long as the process: not counted)."""
    time.sleep(0.1)
    from multiprocessing import resource_tracker

    tracker = getattr(resource_tracker._resource_tracker, "_pid", None)
    children = {p.pid for p in psutil.Process().children(recursive=True)} - before_children - {tracker}
    # Dask's offload pool and tqdm's monitor (started by any tqdm, a disabled closed-loop bar included; it ends itself
    # 10 s after the last bar) are process-wide daemons of those libraries, not a sweep's
    threads = {t for t in threading.enumerate() if not t.name.startswith(("Dask-Offload", "tqdm_monitor"))} - before_threads
    return children, threads


def _interrupt_at(n, exc):
    seen = []

    def on_record(record):
        seen.append(record["key"])
        if len(seen) == n:
            raise exc
    return on_record


@pytest.mark.slow
def test_the_own_cluster_gives_the_serial_records_and_leaves_nothing_on_success_error_and_ctrl_c(monkeypatch):
    """Real forked workers, the cluster worth starting after the first cell: the records equal the
    serial ones; after run_sweep returns — normally, with an error raised by the record callback
    (while the cluster starts, while it runs) or after Ctrl-C (idem) — no process or thread is left."""
    monkeypatch.setattr(runner, "local_cluster_cost", lambda: local_cluster.ClusterCost(0.0, 0.0))
    before = ({p.pid for p in psutil.Process().children(recursive=True)}, set(threading.enumerate()))
    cells = _cells(12)
    serial = run_sweep(cells, workers=0, progress=False, func=_slow_cell).frame()
    parallel = run_sweep(cells, workers=2, progress=False, func=_slow_cell)
    frame = parallel.frame()
    assert parallel.ran == 12 and parallel.local + sum(parallel.batches) == 12 and parallel.batches
    deterministic = [c for c in frame.columns if c not in TIMING_COLUMNS]
    assert frame[deterministic].equals(serial[deterministic])
    assert _leftovers(*before) == (set(), set())
    for at in (2, 25):  # 2: the cluster is starting (it starts after the first cell); 25: its batches run
        with pytest.raises(ValueError, match="callback failed"):
            run_sweep(_cells(30), workers=2, progress=False, func=_sleeping,
                      on_record=_interrupt_at(at, ValueError("callback failed")))
        assert _leftovers(*before) == (set(), set()), at
        stopped = run_sweep(_cells(30), workers=2, progress=False, func=_sleeping,
                            on_record=_interrupt_at(at, KeyboardInterrupt()))
        assert stopped.interrupted and stopped.ran == at and len(stopped.records) == at
        assert _leftovers(*before) == (set(), set()), at


@pytest.mark.slow
def test_one_worker_runs_every_cell_in_its_process():
    result = run_sweep(_cells(4), workers=1, progress=False, func=_where)
    assert (result.ran, result.local) == (4, 0) and sum(result.batches) == 4
    assert all(r["error"].split()[0] != str(os.getpid()) for r in result.records)


@pytest.mark.slow
def test_a_sweeps_local_cluster_has_its_settings_and_forks_on_linux():
    import dask
    from dask.distributed import Client

    _PARENT_MARK.append(os.getpid())
    try:
        with local_cluster.start_local_cluster(2) as cluster, Client(cluster) as client:
            seen = client.run(lambda: (dask.config.get("distributed.admin.tick.interval"),
                                       dask.config.get("distributed.worker.profile.enabled"),
                                       list(sys.modules[__name__]._PARENT_MARK)))
    finally:
        _PARENT_MARK.clear()
    assert len(seen) == 2
    forked = sys.platform.startswith("linux")
    assert local_cluster.START_METHOD == ("fork" if forked else "spawn")
    for tick, profile, mark in seen.values():
        assert (tick, profile) == ("1s", False)
        assert mark == ([os.getpid()] if forked else [])  # a forked worker has this process's state


@pytest.mark.parametrize("n", [0, -1, 1.5, True, "2"])
def test_start_local_cluster_refuses_a_worker_count_that_is_not_a_positive_integer(n):
    with pytest.raises(InvalidParameterError, match="n_workers"):
        local_cluster.start_local_cluster(n)


def test_a_process_without_dask_counts_its_import_into_the_cluster_cost(monkeypatch):
    import dask.distributed  # noqa: F401 - imported: the cost is the start-up alone

    start, cost, importing = (local_cluster.LOCAL_START_SECONDS, local_cluster.LOCAL_COST_SECONDS,
                              local_cluster.DASK_IMPORT_SECONDS)
    assert local_cluster.local_cluster_cost() == (start, cost)
    monkeypatch.delitem(sys.modules, "distributed")
    assert local_cluster.local_cluster_cost() == (start + importing, cost + importing)



#: When this process forked (time.perf_counter(), s), while :func:`_note_forks` is on.
_FORKS = []


def _note_forks():
    """Record this process's forks in :data:`_FORKS` (an at-fork hook, registered once)."""
    if not getattr(_note_forks, "on", False):
        _note_forks.on = True
        os.register_at_fork(after_in_parent=lambda: _FORKS.append(time.perf_counter()))


def _timed(cell):
    """:func:`_where` after 0.25 s, its start (time.perf_counter(), s) added to the error field."""
    start = time.perf_counter()
    time.sleep(0.25)
    record = _where(cell)
    record["error"] += f" {start}"
    return record


@pytest.mark.slow
def test_the_workers_fork_before_the_next_cell_here_not_after_it(monkeypatch):
    """Cells of 0.25 s, the cluster worth starting after the first: this process waits for its
    worker to fork before its second cell (the fork does not wait in FORK_GATE for a whole cell),
    and the sweep gives every cell once."""
    _note_forks()
    monkeypatch.setattr(runner, "local_cluster_cost", lambda: local_cluster.ClusterCost(0.0, 0.0))
    monkeypatch.setattr(local_cluster, "FORK_LEAD_SECONDS", 120.0)  # a loaded machine's slow start waits too
    _FORKS.clear()
    result = run_sweep(_cells(8), workers=2, progress=False, func=_timed)
    here = sorted(float(r["error"].split()[2]) for r in result.records if r["error"].split()[0] == str(os.getpid()))
    assert result.ran == 8 and result.local + sum(result.batches) == 8 and result.batches
    assert len(here) == result.local >= 2
    assert _FORKS and min(_FORKS) < here[1]  # forked between the first and the second cell here
    assert "forked" in result.timeline
