#!/usr/bin/env python3
"""Benchmark a 64-cell sweep: serial in-process vs a LocalCluster, and the per-task overhead.

Usage: ``python benchmarks/bench_sweep.py [--workers 2] [--duration 0.5] [--out DIR]``
(PYTHONPATH=src or the package installed). Runs the same 64 cells (2 forms × 4 horizons × 4 input
weights × 2 plant mass scales, S-curve over 80 % of the run, Ts = 5 ms) serially (``workers=0``) and on a
``LocalCluster`` of ``--workers`` processes, checks that both give the same metrics, then times 64
no-op tasks through the same runner and through bare ``client.submit``. Prints a Markdown table
and writes it to DIR/bench_sweep.md (default benchmarks/results). See benchmarks/README.md.
"""

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"  # one BLAS thread per process: the workers are the parallelism

import argparse  # noqa: E402
import logging  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from parallel_gpc.sweeps import TIMING_COLUMNS, failed_record, load_spec  # noqa: E402
from parallel_gpc.sweeps import run_sweep  # noqa: E402


#: Repetitions of the no-op timings (the median is reported).
REPEATS = 5


def spec_64(duration: float):
    return load_spec({
        "sweep": {"name": "bench64"},
        "base": {"robot": "planar_3rrr", "reference": "s-curve", "s_curve_duration": 0.8 * duration,
                 "duration": duration, "Ts": 0.005},
        "grid": {"form": ["absolute", "nonlinear"], "N": [4, 8, 12, 16], "Qu": [1e-5, 3e-5, 1e-4, 3e-4],
                 "mass_scale": [0.9, 1.1]},
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


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=os.cpu_count())
    parser.add_argument("--duration", type=float, default=0.5, help="length of each run in s (default 0.5)")
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"))
    args = parser.parse_args()
    from dask.distributed import Client, LocalCluster, as_completed

    spec = spec_64(args.duration)
    cells = spec.cells()
    load_before = os.getloadavg()
    t_serial, serial = timed(lambda: run_sweep(cells, workers=0, progress=False))
    t_cold, cold = timed(lambda: run_sweep(cells, workers=args.workers, progress=False))
    t_start, (cluster, client) = timed(lambda: _start(LocalCluster, Client, args.workers))
    try:
        t_warm, warm = timed(lambda: run_sweep(cells, scheduler=client, progress=False))
        run_sweep(cells[:4], scheduler=client, progress=False, func=noop)  # warm-up: functions shipped once
        t_noop = sorted(timed(lambda: run_sweep(cells, scheduler=client, progress=False, func=noop))[0]
                        for _ in range(REPEATS))[REPEATS // 2]
        t_bare = sorted(timed(lambda: [f.result() for f in as_completed(
            [client.submit(_bare, i, pure=False) for i in range(len(cells))])])[0] for _ in range(REPEATS))[REPEATS // 2]
    finally:
        client.close()
        cluster.close()
    keep = [c for c in serial.frame().columns if c not in TIMING_COLUMNS]
    same = all(r.frame()[keep].equals(serial.frame()[keep]) for r in (cold, warm))
    n = len(cells)
    cell_time = serial.frame()["wall_time_s"]
    rows = [
        ("cells", f"{n} ({serial.failed} failed)"),
        ("mean / max time of one cell, serial", f"{cell_time.mean():.3f} s / {cell_time.max():.3f} s"),
        ("serial (workers=0)", f"{t_serial:.2f} s"),
        (f"LocalCluster({args.workers}), incl. start-up and shutdown", f"{t_cold:.2f} s  (speed-up {t_serial / t_cold:.2f}×)"),
        (f"LocalCluster({args.workers}), running cluster", f"{t_warm:.2f} s  (speed-up {t_serial / t_warm:.2f}×)"),
        ("cells running at once in the running cluster (Σ cell wall time / elapsed)",
         f"{warm.frame()['wall_time_s'].sum() / t_warm:.2f}"),
        ("cluster start-up", f"{t_start:.2f} s"),
        (f"{n} no-op cells through run_sweep (median of {REPEATS})", f"{t_noop:.3f} s = {1e3 * t_noop / n:.2f} ms per task"),
        (f"{n} no-op client.submit + as_completed (median of {REPEATS})",
         f"{t_bare:.3f} s = {1e3 * t_bare / n:.2f} ms per task"),
        ("serial and cluster metrics identical", str(same)),
        ("machine", f"{platform.machine()}, {os.cpu_count()} cores, 1-min load avg {load_before[0]:.2f} before, "
                    f"{os.getloadavg()[0]:.2f} after"),
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
