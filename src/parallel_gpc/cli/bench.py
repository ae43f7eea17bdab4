"""``parallel-gpc bench [--quick] [--out DIR]``: the benchmark of :mod:`parallel_gpc.bench.harness`.

Timings need one BLAS thread, fixed before NumPy loads: without ``OPENBLAS_NUM_THREADS=1`` the
command runs itself again in a fresh interpreter with it set.
"""

from __future__ import annotations

import os
import sys


def add_bench_arguments(p, default_out: str = "bench-results") -> None:
    """--quick and --out (shared with ``benchmarks/bench_gpc.py``)."""
    p.add_argument("--quick", action="store_true", help="short run (< 1 min on 2 cores; the full run takes ~6 min)")
    p.add_argument("--out", default=default_out, help="folder for bench_gpc.json, bench_gpc.md and bench_gpc.png")


def cmd_bench(args) -> int:
    if os.environ.get("OPENBLAS_NUM_THREADS") != "1" and not os.environ.get("PARALLEL_GPC_BENCH_CHILD"):
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PARALLEL_GPC_BENCH_CHILD="1")
        argv = [sys.executable, "-m", "parallel_gpc", "bench", "--out", str(args.out)] + (["--quick"] if args.quick else [])
        sys.stdout.flush()
        os.execve(sys.executable, argv, env)
    from ..bench import format_table, run_benchmark, write_benchmark, format_targets
    from .outputs import prepare_out_dir

    out = prepare_out_dir(args.out)
    result = run_benchmark(quick=args.quick)
    print(format_table(result["results"]))
    print()
    print(format_targets(result["targets"]))
    written = write_benchmark(result, out)
    print("wrote " + ", ".join(str(p) for p in written)
          + (f" (interrupted: {len(result['results'])} finished rows)" if result["interrupted"] else ""))
    if result["interrupted"]:
        print("interrupted: partial results saved")
        return 130
    return 0


def register_bench(sub) -> None:
    """Add the ``bench`` sub-command."""
    p = sub.add_parser("bench", help="time QR vs QP back ends, qpmpc and the full GPC step along the S-curve")
    add_bench_arguments(p)
    p.set_defaults(func=cmd_bench)


def main(argv: list[str] | None = None, default_out: str = "bench-results") -> int:
    """``benchmarks/bench_gpc.py [--quick] [--out DIR]``: the bench command on its own."""
    import argparse

    parser = argparse.ArgumentParser(prog="bench_gpc", description=__doc__.splitlines()[0])
    add_bench_arguments(parser, default_out)
    return cmd_bench(parser.parse_args(argv))
