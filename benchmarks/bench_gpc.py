#!/usr/bin/env python3
"""Benchmark QR vs QP back ends, qpmpc and the full GPC step on the S-curve (DESIGN §9).

Usage: ``python benchmarks/bench_gpc.py [--quick] [--out DIR]`` (same as ``parallel-gpc bench``).
Writes DIR/bench_gpc.json and DIR/bench_gpc.png and prints the table; see benchmarks/README.md.
"""

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"  # before numpy loads: one BLAS thread for small-matrix timings
os.environ.setdefault("MPLBACKEND", "Agg")

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

from parallel_gpc.bench import run_benchmark  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short run (< 3 min on 2 cores)")
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"),
                        help="folder for bench_gpc.json and bench_gpc.png (default benchmarks/results)")
    args = parser.parse_args(argv)
    run_benchmark(quick=args.quick, out_dir=args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
