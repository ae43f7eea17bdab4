#!/usr/bin/env python3
"""Benchmark QR vs QP back ends, qpmpc and the full GPC step on the S-curve.

Usage: ``python benchmarks/bench_gpc.py [--quick] [--out DIR]`` (the same as ``parallel-gpc bench``;
default DIR: benchmarks/results). Writes DIR/bench_gpc.json, DIR/bench_gpc.md and DIR/bench_gpc.png
and prints the table; see benchmarks/README.md.
"""

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"  # before numpy loads: one BLAS thread for small-matrix timings
os.environ.setdefault("MPLBACKEND", "Agg")

import sys  # noqa: E402
from pathlib import Path  # noqa: E402

from parallel_gpc.cli.bench import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main(default_out=str(Path(__file__).resolve().parent / "results")))
