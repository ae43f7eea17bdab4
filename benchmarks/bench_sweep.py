#!/usr/bin/env python3
"""Benchmark sweeps: serial in-process vs Dask (a LocalCluster), 64 cells of ~0.2 s and 16 of ~0.1 s.

Usage: ``python benchmarks/bench_sweep.py [--workers 2] [--rounds 3] [--out DIR]``
(PYTHONPATH=src or the package installed). Two sweeps on planar_3rrr (S-curve over 80 % of the run,
Ts = 5 ms): 64 cells (2 forms × 4 horizons × 4 input weights × 2 plant mass scales, 0.5 s runs,
~0.2 s each) and 16 cells (2 forms × 4 horizons × 2 input weights, 0.25 s runs, ~0.1 s each). Each
round runs every sweep serially (``workers=0``), through ``run_sweep(workers=W)`` (its own
LocalCluster: start-up, in-process probe and shutdown included) and on a running LocalCluster
(``scheduler=client``, workers warmed up), interleaved, and checks that every path gives the
serial metrics. Then it times 64 no-op cells through ``run_sweep`` and 64 bare ``client.submit``
tasks. Prints a Markdown table (medians over the rounds, the speed-ups' range, the speed-up per
worker and the ideal one: serial / W, plus the measured cluster start-up for ``run_sweep``'s own
cluster) and writes it to
DIR/bench_sweep.md (default benchmarks/results). See benchmarks/README.md.
"""

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"  # one BLAS thread per process: the workers are the parallelism

import argparse  # noqa: E402
import logging  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from parallel_gpc.sweeps import TIMING_COLUMNS, failed_record, load_spec  # noqa: E402
from parallel_gpc.sweeps import run_sweep  # noqa: E402


#: Repetitions of the no-op timings (the median is reported).
REPEATS = 5


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


def noop(cell):
    """A task that does nothing but return a (blank) record: measures the scheduling cost."""
    record = failed_record(cell, "")
    record["status"] = "ok"
    return record


def _bare(x):
    return x


def timed(fn):
    start = time.perf_counter()
    out = fn()
    return time.perf_counter() - start, out


def metrics(result):
    frame = result.frame()
    return frame[[c for c in frame.columns if c not in TIMING_COLUMNS]]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=os.cpu_count())
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds (default 3)")
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"))
    args = parser.parse_args()
    from dask.distributed import Client, LocalCluster, as_completed

    sweeps = {"64 cells of ~0.2 s": spec_64().cells(), "16 cells of ~0.1 s": spec_16().cells()}
    load_before = os.getloadavg()
    t_start, (cluster, client) = timed(lambda: _start(LocalCluster, Client, args.workers))
    times = {name: {"serial": [], "own": [], "running": []} for name in sweeps}
    cell_means, same, failed = {}, True, {}
    try:
        run_sweep(spec_16().cells()[:4], scheduler=client, progress=False)  # warm-up: first run of each worker
        for _ in range(args.rounds):
            for name, cells in sweeps.items():
                t, serial = timed(lambda: run_sweep(cells, workers=0, progress=False))
                times[name]["serial"].append(t)
                t, own = timed(lambda: run_sweep(cells, workers=args.workers, progress=False))
                times[name]["own"].append(t)
                t, running = timed(lambda: run_sweep(cells, scheduler=client, progress=False))
                times[name]["running"].append(t)
                same &= metrics(own).equals(metrics(serial)) and metrics(running).equals(metrics(serial))
                cell_means[name] = serial.frame()["wall_time_s"].mean()
                failed[name] = serial.failed
        cells = sweeps["64 cells of ~0.2 s"]
        run_sweep(cells[:4], scheduler=client, progress=False, func=noop)  # warm-up: functions shipped once
        t_noop = statistics.median(timed(lambda: run_sweep(cells, scheduler=client, progress=False, func=noop))[0]
                                   for _ in range(REPEATS))
        t_bare = statistics.median(timed(lambda: [f.result() for f in as_completed(
            [client.submit(_bare, i, pure=False) for i in range(len(cells))])])[0] for _ in range(REPEATS))
    finally:
        client.close()
        cluster.close()
    w = args.workers
    rows = []
    for name, t in times.items():
        serial = statistics.median(t["serial"])
        rows.append((f"{name} ({failed[name]} failed; mean cell {cell_means[name]:.3f} s serial)", ""))
        rows.append(("  serial (workers=0)", f"{serial:.2f} s"))
        for key, label in (("own", f"run_sweep(workers={w}): own LocalCluster, start-up and shutdown included"),
                           ("running", f"running LocalCluster({w})")):
            ratios = [s / d for s, d in zip(t["serial"], t[key])]
            speedup = statistics.median(ratios)
            # the best a cluster of w workers can do: serial / w, plus its start-up when run_sweep starts its own
            ideal = serial / (serial / w + (t_start if key == "own" else 0.0))
            rows.append((f"  {label}", f"{statistics.median(t[key]):.2f} s: speed-up {speedup:.2f}× "
                                       f"({min(ratios):.2f}–{max(ratios):.2f}×), {speedup / w:.2f} per worker; "
                                       f"ideal {ideal:.2f}× ({speedup / ideal:.0%} of it)"))
    rows += [
        ("cluster start-up (incl. imports on the workers)", f"{t_start:.2f} s"),
        (f"64 no-op cells through run_sweep (median of {REPEATS})",
         f"{t_noop:.3f} s = {1e3 * t_noop / 64:.2f} ms per cell"),
        (f"64 no-op client.submit + as_completed (median of {REPEATS})",
         f"{t_bare:.3f} s = {1e3 * t_bare / 64:.2f} ms per task"),
        ("every path gives the serial metrics", str(same)),
        ("machine", f"{platform.machine()}, {os.cpu_count()} cores, 1-min load avg {load_before[0]:.2f} before, "
                    f"{os.getloadavg()[0]:.2f} after; {args.rounds} interleaved rounds"),
    ]
    width = max(len(r[0]) for r in rows)
    lines = [f"| {'quantity':<{width}} | value |", f"|{'-' * (width + 2)}|-------|"]
    lines += [f"| {k:<{width}} | {v} |" for k, v in rows]
    text = "\n".join(lines)
    print(text)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_sweep.md").write_text(text + "\n")
    return 0 if same else 1


def _start(LocalCluster, Client, workers):
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address="127.0.0.1:0", silence_logs=logging.WARNING)
    client = Client(cluster)
    client.run(lambda: __import__("parallel_gpc.sweeps"))  # imports done before the timing
    return cluster, client


if __name__ == "__main__":
    raise SystemExit(main())
