#!/usr/bin/env python3
"""Benchmark sweeps: serial in-process vs Dask (a LocalCluster), 64 cells of ~0.2 s and 16 of ~0.1 s.

Usage: ``python benchmarks/bench_sweep.py [--workers 2] [--rounds 3] [--out DIR] [--fixed] [--overhead K]``
(PYTHONPATH=src or the package installed). Two sweeps on planar_3rrr (S-curve over 80 % of the run,
Ts = 5 ms): 64 cells (2 forms × 4 horizons × 4 input weights × 2 plant mass scales, 0.5 s runs,
~0.2 s each) and 16 cells (2 forms × 4 horizons × 2 input weights, 0.25 s runs, ~0.1 s each). Unless
``--fixed``, the runs' duration is first calibrated so that a cell costs ≈ 0.2 s resp. ≈ 0.1 s of CPU
on this machine (8 probe cells, :func:`calibrate`; printed and recorded). Each
round runs every sweep serially (``workers=0``), through ``run_sweep(workers=W)`` (this process and
its own LocalCluster of W − 1 workers: start-up and shutdown included) and on a
running LocalCluster (``start_local_cluster(W)``, ``scheduler=client``, workers warmed up), interleaved (the order of
the three rotates from round to round; every path runs the same cells, one cell runs in this
process before the first round so that no path pays the first imports), and checks that every
path gives the serial metrics. Then it times 64 no-op cells through ``run_sweep`` and 64 bare
``client.submit`` tasks. Prints a Markdown table (medians over the rounds, the speed-ups' range, the
speed-up per worker and the ideal one: serial / W, plus the measured cluster start-up for
``run_sweep``'s own cluster) and, from a trace of every cell (process, start and end, thread CPU),
where the parallel paths lose to the ideal (instrumentation table, medians over the rounds): CPU of
the cells against the same cells serially, Dask's own CPU (this process: scheduler, client,
nannies; the workers beyond their cells), each worker's idle time (before its first cell, between
cells, after its last), the tasks' sizes, the bytes of the records returned; and when the phases
of ``run_sweep``'s own cluster happened (``SweepResult.timeline``: the cluster's start in the
background, up, its first batches, this process's last cell, the cluster's last batch, the last
record, closed, done). The tables go to
DIR/bench_sweep.md (default benchmarks/results). ``--overhead K`` instead runs K sweeps of 64 and K of 16
cells that sleep 0.1 s through ``run_sweep``'s own cluster and prints the CPU spent outside the cells (this
process, the workers): what the cells lose to Dask on a machine with one core per stream, measured
in CPU seconds, which load does not stretch; and the speed-up over serial of these sleeping cells
(the scheduling alone: start, hand-over, tail), which load stretches little. See benchmarks/README.md.
"""

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"  # one BLAS thread per process: the workers are the parallelism

import argparse  # noqa: E402
import math  # noqa: E402
import pickle  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from parallel_gpc.sweeps import TIMING_COLUMNS, failed_record, load_spec, run_cell  # noqa: E402
from parallel_gpc.model import available_cores  # noqa: E402
from parallel_gpc.sweeps import run_sweep, start_local_cluster  # noqa: E402


#: Repetitions of the no-op timings (the median is reported).
REPEATS = 5
#: Columns the trace adds to a record (process, start and end on the wall clock in s, thread CPU in s).
TRACE_COLUMNS = ("trace_pid", "trace_start", "trace_end", "trace_cpu")
#: A gap between two cells of one worker counted as idle, s (below: the loop from cell to cell).
GAP_SECONDS = 0.005


def spec_64(duration: float = 0.5):
    """64 cells of ~0.2 s (0.5 s runs at Ts = 5 ms)."""
    return load_spec({
        "sweep": {"name": "bench64"},
        "base": {"robot": "planar_3rrr", "reference": "s-curve", "s_curve_duration": 0.8 * duration,
                 "duration": duration, "Ts": 0.005},
        "grid": {"form": ["absolute", "nonlinear"], "N": [4, 8, 12, 16], "Qu": [1e-5, 3e-5, 1e-4, 3e-4],
                 "mass_scale": [0.9, 1.1]},
    })


def spec_16(duration: float = 0.25):
    """16 cells of ~0.1 s (0.25 s runs at Ts = 5 ms)."""
    return load_spec({
        "sweep": {"name": "bench16"},
        "base": {"robot": "planar_3rrr", "reference": "s-curve", "s_curve_duration": 0.8 * duration,
                 "duration": duration, "Ts": 0.005},
        "grid": {"form": ["absolute", "nonlinear"], "N": [4, 8, 12, 16], "Qu": [1e-5, 1e-4]},
    })


#: Cell CPU times the two sweeps are sized to, s (the issue's "64 cells of ~0.2 s", "16 cells of 0.1 s").
TARGET_64, TARGET_16 = 0.2, 0.1
#: Closed-loop step of the bench's cells, s (calibrated durations are whole multiples of it).
BENCH_TS = 0.005


def cell_cpu(cells) -> float:
    """Mean CPU time of ``cells`` run in this process, s (process CPU: load does not stretch it)."""
    start = time.process_time()
    for cell in cells:
        run_cell(cell)
    return (time.process_time() - start) / len(cells)


def calibrate(make_spec, duration: float, target: float, probes: int = 8, passes: int = 4) -> tuple:
    """The closed-loop duration (s) at which a cell of ``make_spec(duration)`` costs ≈ ``target`` s of CPU.

    Runs ``probes`` cells spread over the grid and scales the duration by target / measured mean (a
    cell's cost grows about linearly with its steps) until the mean is within 5 % of the target (at
    most ``passes`` measurements; the fixed part, setup and model, makes one pass short), rounded to
    whole steps of :data:`BENCH_TS`. Returns (duration s, mean CPU s of the probes at that duration)."""
    for measured in range(1, passes + 2):  # the last measurement: the mean at the duration returned
        cells = make_spec(duration).cells()
        mean = cell_cpu(cells[::max(1, len(cells) // probes)][:probes])
        if abs(mean / target - 1) <= 0.05 or measured > passes:
            break
        duration = round(max(10, round(duration * target / mean / BENCH_TS)) * BENCH_TS, 6)
    return duration, mean


def traced(cell):
    """:func:`run_cell` with its trace: the process, start and end (wall clock, s), thread CPU (s)."""
    start, cpu = time.time(), time.thread_time()
    record = run_cell(cell)
    record.update(trace_pid=os.getpid(), trace_start=start, trace_end=time.time(),
                  trace_cpu=time.thread_time() - cpu)
    return record


def noop(cell):
    """A task that does nothing but return a (blank) record: measures the scheduling cost."""
    record = failed_record(cell, "")
    record["status"] = "ok"
    return record


#: Length of a :func:`sleeping` cell, s, and the cells of the ``--overhead`` sweeps.
SLEEP_SECONDS, SLEEP_CELLS = 0.1, (64, 16)


def sleeping(cell):
    """A cell that sleeps :data:`SLEEP_SECONDS` (no CPU): in a sweep of these, every CPU-second is overhead."""
    time.sleep(SLEEP_SECONDS)
    return noop(cell)


def overhead(workers: int, repeats: int) -> list:
    """CPU outside the cells of sweeps of :data:`SLEEP_CELLS` sleeping cells through
    ``run_sweep(workers=…)`` (its own cluster), ``repeats`` times each, alternated: robust under
    load, where wall-clock speed-ups of computing cells are not. So is the speed-up over a serial
    run of sleeping cells (cells × :data:`SLEEP_SECONDS` / wall): it measures the scheduling alone —
    the cluster's start, the hand-over, the tail — since a sleeping cell needs no core.

    Returns:
        rows (sweep and run, CPU-s here, CPU-s of the workers (reaped children), their sum, tasks,
        cells here, the cluster's first batches since the start in s, the cluster's last batch
        after this process's last cell in s, wall s, speed-up over serial).
    """
    import resource

    from parallel_gpc.sweeps import Cell

    rows = []
    for run in range(repeats):
        for n in SLEEP_CELLS:
            cells = [Cell(i, {"sleep": SLEEP_SECONDS, "i": i}) for i in range(n)]
            before = [resource.getrusage(who) for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)]
            start = time.perf_counter()
            result = run_sweep(cells, workers=workers, progress=False, func=sleeping)
            wall = time.perf_counter() - start
            after = [resource.getrusage(who) for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)]
            here, kids = (a.ru_utime + a.ru_stime - b.ru_utime - b.ru_stime for a, b in zip(after, before))
            phases = result.timeline
            tail = phases.get("on_up done", math.nan) - phases.get("local done", math.nan)
            rows.append((f"{n} cells, {run + 1}", f"{here:.3f}", f"{kids:.3f}", f"{here + kids:.3f}",
                         str(len(result.batches)), str(result.local), f"{phases.get('first batches', math.nan):.2f}",
                         f"{tail:.2f}", f"{wall:.2f}", f"{n * SLEEP_SECONDS / wall:.2f}×"))
    return rows


def _bare(x):
    return x


def metrics(result):
    frame = result.frame()
    return frame[[c for c in frame.columns if c not in TIMING_COLUMNS and c not in TRACE_COLUMNS]]


def process_cpu(pids) -> float:
    """CPU time (user + system) of the processes ``pids`` so far, s."""
    import psutil

    return sum(sum(psutil.Process(pid).cpu_times()[:2]) for pid in pids)


def run_path(run, worker_pids=()):
    """Run one path of one sweep; its wall time and its trace.

    Returns:
        (wall time in s, the SweepResult, a dict: CPU of this process, of its reaped children
        (a cluster it started and closed) and of ``worker_pids`` (a running cluster), s).
    """
    here, children = time.process_time(), os.times()
    workers = process_cpu(worker_pids)
    start = time.perf_counter()
    start_clock = time.time()
    result = run()
    wall = time.perf_counter() - start
    after = os.times()
    cpu = {"here": time.process_time() - here,
           "children": after.children_user + after.children_system - children.children_user - children.children_system,
           "workers": process_cpu(worker_pids) - workers, "start": start_clock, "end": start_clock + wall}
    return wall, result, cpu


def instrument(result, cpu, serial_cpu):
    """Where a parallel run's time went, from its cells' trace (see the module docstring).

    Returns:
        dict of floats: cells' CPU / the same cells' CPU serially; Dask's CPU (s): this process
        minus its cells, and the workers beyond their cells; per worker (medians over workers):
        idle before the first cell, between cells (gaps ≥ :data:`GAP_SECONDS`) and after the
        last, s; cells run here; tasks; bytes of a record returned.
    """
    here_pid = os.getpid()
    records = [r for r in result.records if "trace_pid" in r]
    cells_cpu = sum(r["trace_cpu"] for r in records)
    here_cells = sum(r["trace_cpu"] for r in records if r["trace_pid"] == here_pid)
    out = {"cpu_ratio": cells_cpu / serial_cpu,
           "dask_here": cpu["here"] - here_cells,
           "dask_workers": cpu["children"] + cpu["workers"] - (cells_cpu - here_cells),
           "local": result.local, "tasks": len(result.batches), "timeline": result.timeline,
           "bytes": statistics.median(len(pickle.dumps(r)) for r in records)}
    pids = sorted({r["trace_pid"] for r in records} - {here_pid})
    before, between, after = [], [], []
    for pid in pids:
        mine = sorted((r for r in records if r["trace_pid"] == pid), key=lambda r: r["trace_start"])
        before.append(mine[0]["trace_start"] - cpu["start"])
        gaps = [b["trace_start"] - a["trace_end"] for a, b in zip(mine, mine[1:])]
        between.append(sum(g for g in gaps if g >= GAP_SECONDS))
        after.append(cpu["end"] - mine[-1]["trace_end"])
    for key, values in (("idle_before", before), ("idle_between", between), ("idle_after", after)):
        out[key] = statistics.median(values) if values else 0.0
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=available_cores())
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds (default 3)")
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"))
    parser.add_argument("--fixed", action="store_true",
                        help="cells at the fixed settings (0.5 s resp. 0.25 s runs) instead of sized to "
                             f"{TARGET_64} s resp. {TARGET_16} s of CPU on this machine")
    parser.add_argument("--overhead", type=int, default=0, metavar="K",
                        help=f"only: K sweeps of each of {SLEEP_CELLS} sleeping cells of {SLEEP_SECONDS} s through "
                             "the own cluster, their CPU outside the cells and their speed-up")
    args = parser.parse_args()
    from dask.distributed import Client, as_completed

    if args.overhead:
        import dask.distributed  # noqa: F401 - imported, as in a process's second sweep

        load = os.getloadavg()[0]
        text = table(("sweep, run", "CPU-s here", "CPU-s workers", "CPU-s outside cells", "tasks", "cells here",
                      "first batches, s", "last batch after this process's last cell, s", "wall, s",
                      "speed-up"), overhead(args.workers, args.overhead))
        print(f"{text}\n\n{' and '.join(map(str, SLEEP_CELLS))} sleeping cells of {SLEEP_SECONDS} s, "
              f"run_sweep(workers={args.workers}); 1-min load avg {load:.2f} before, {os.getloadavg()[0]:.2f} after")
        return 0

    traced(spec_16().cells()[0])  # the first imports and caches of this process, outside calibration and timing
    d64, d16 = 0.5, 0.25
    if not args.fixed:
        d64, c64 = calibrate(spec_64, d64, TARGET_64)
        d16, c16 = calibrate(spec_16, d16, TARGET_16)
        print(f"cells sized: 64 cells of {c64:.3f} s CPU ({d64:.3f} s runs), 16 cells of {c16:.3f} s CPU "
              f"({d16:.3f} s runs), means over 8 probe cells each")
    sweeps = {"64 cells of ~0.2 s": spec_64(d64).cells(), "16 cells of ~0.1 s": spec_16(d16).cells()}
    load_before = os.getloadavg()
    start = time.perf_counter()
    cluster = start_local_cluster(args.workers)
    client = Client(cluster)
    client.run(lambda: __import__("parallel_gpc.sweeps"))  # imports done before the timing
    t_start = time.perf_counter() - start
    worker_pids = list(client.run(os.getpid).values())
    paths = {
        "serial": lambda cells: run_path(lambda: run_sweep(cells, workers=0, progress=False, func=traced)),
        "own": lambda cells: run_path(lambda: run_sweep(cells, workers=args.workers, progress=False, func=traced)),
        "running": lambda cells: run_path(lambda: run_sweep(cells, scheduler=client, progress=False, func=traced),
                                          worker_pids),
    }
    times = {name: {path: [] for path in paths} for name in sweeps}
    probes = {name: {path: [] for path in ("own", "running")} for name in sweeps}
    cell_means, same, failed = {}, True, {}
    try:
        run_sweep(spec_16().cells()[:4], scheduler=client, progress=False, func=traced)  # warm-up of each worker
        for round_ in range(args.rounds):
            order = list(paths)[round_ % 3:] + list(paths)[:round_ % 3]  # rotate: no path always first
            for name, cells in sweeps.items():
                runs = {path: paths[path](cells) for path in order}
                serial = runs["serial"][1]
                serial_cpu = sum(r["trace_cpu"] for r in serial.records)
                for path, (t, result, cpu) in runs.items():
                    times[name][path].append(t)
                    same &= metrics(result).equals(metrics(serial))
                    if path != "serial":
                        probes[name][path].append(instrument(result, cpu, serial_cpu))
                cell_means[name] = serial.frame()["wall_time_s"].mean()
                failed[name] = serial.failed
        cells = sweeps["64 cells of ~0.2 s"]
        run_sweep(cells[:4], scheduler=client, progress=False, func=noop)  # warm-up: functions shipped once
        t_noop = statistics.median(run_path(lambda: run_sweep(cells, scheduler=client, progress=False, func=noop))[0]
                                   for _ in range(REPEATS))
        t_bare = statistics.median(run_path(lambda: [f.result() for f in as_completed(
            [client.submit(_bare, i, pure=False) for i in range(len(cells))])])[0] for _ in range(REPEATS))
    finally:
        client.close()
        cluster.close()
    t_import = dask_import_seconds()
    w = args.workers
    rows = []
    for name, t in times.items():
        serial = statistics.median(t["serial"])
        rows.append((f"{name} ({failed[name]} failed; mean cell {cell_means[name]:.3f} s serial)", ""))
        rows.append(("  serial (workers=0)", f"{serial:.2f} s"))
        for key, label in (("own", f"run_sweep(workers={w}): this process + own LocalCluster({w - 1}), start-up and "
                                   "shutdown included"),
                           ("running", f"running LocalCluster({w})")):
            ratios = [s / d for s, d in zip(t["serial"], t[key])]
            speedup = statistics.median(ratios)
            # the best a cluster of w workers can do: serial / w, plus its start-up when run_sweep starts its own
            ideal = serial / (serial / w + (t_start if key == "own" else 0.0))
            rows.append((f"  {label}", f"{statistics.median(t[key]):.2f} s: speed-up {speedup:.2f}× "
                                       f"({min(ratios):.2f}–{max(ratios):.2f}×), {speedup / w:.2f} per worker; "
                                       f"ideal {ideal:.2f}× ({speedup / ideal:.0%} of it)"))
    rows += [
        ("cluster start-up (start_local_cluster + imports on the workers)", f"{t_start:.2f} s"),
        ("import dask.distributed in a fresh process (the first own cluster of a process pays it; "
         "not in the times above)", f"{t_import:.2f} s"),
        (f"64 no-op cells through run_sweep (median of {REPEATS})",
         f"{t_noop:.3f} s = {1e3 * t_noop / 64:.2f} ms per cell"),
        (f"64 no-op client.submit + as_completed (median of {REPEATS})",
         f"{t_bare:.3f} s = {1e3 * t_bare / 64:.2f} ms per task"),
        ("cells' closed-loop duration (64 / 16 cells)",
         f"{d64:.3f} s / {d16:.3f} s ({'fixed' if args.fixed else 'sized by measured CPU'})"),
        ("every path gives the serial metrics", str(same)),
        ("machine", f"{platform.machine()}, {os.cpu_count()} cores, 1-min load avg {load_before[0]:.2f} before, "
                    f"{os.getloadavg()[0]:.2f} after; {args.rounds} interleaved rounds"),
    ]
    text = table(("quantity", "value"), rows)
    columns = ("sweep, path", "cells' CPU / serial", "Dask CPU here", "Dask CPU workers", "idle per worker: "
               "before / between / after", "cells here", "tasks", "record")
    probe_rows = []
    for name, by_path in probes.items():
        for path, runs in by_path.items():
            m = {key: statistics.median(run[key] for run in runs) for key in runs[0] if key != "timeline"}
            probe_rows.append((f"{name.split(' of')[0]}, {path}", f"{m['cpu_ratio']:.2f}", f"{m['dask_here']:.2f} s",
                               f"{m['dask_workers']:.2f} s",
                               f"{m['idle_before']:.2f} / {m['idle_between']:.2f} / {m['idle_after']:.2f} s",
                               f"{m['local']:.0f}", f"{m['tasks']:.0f}", f"{m['bytes']:.0f} B"))
    text += "\n\nInstrumentation (medians over the rounds):\n\n" + table(columns, probe_rows)
    phase_rows = []
    for name, by_path in probes.items():
        runs = by_path["own"]
        events = [e for e in runs[0]["timeline"] if all(e in run["timeline"] for run in runs)]
        phase_rows.append((name.split(" of")[0], "; ".join(
            f"{e} {statistics.median(run['timeline'][e] for run in runs):.2f}" for e in events)))
    text += ("\n\nrun_sweep's own cluster, its phases (`SweepResult.timeline`: s since run_sweep began, medians "
             "over the rounds):\n\n" + table(("sweep", "phases"), phase_rows))
    print(text)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_sweep.md").write_text(text + "\n")
    return 0 if same else 1


def dask_import_seconds() -> float:
    """Wall time of ``import dask.distributed`` in a fresh Python process that has imported the package, s."""
    import subprocess
    import sys

    code = ("import time, parallel_gpc.sweeps, parallel_gpc.studies; t = time.perf_counter(); "
            "import dask.distributed; print(time.perf_counter() - t)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=os.environ)
    return float(out.stdout.split()[-1])


def table(header, rows) -> str:
    """A Markdown table, columns padded to their widest cell."""
    widths = [max(len(str(r[i])) for r in (header, *rows)) for i in range(len(header))]
    lines = ["| " + " | ".join(f"{c:<{w}}" for c, w in zip(header, widths)) + " |",
             "|" + "|".join("-" * (w + 2) for w in widths) + "|"]
    lines += ["| " + " | ".join(f"{c:<{w}}" for c, w in zip(row, widths)) + " |" for row in rows]
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
