"""Plot modules: importing them leaves the caller's matplotlib backend alone, and every plot
function returns a ``matplotlib.figure.Figure`` that ``save_figure`` writes."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from matplotlib.figure import Figure

from parallel_gpc.plots import save_figure
from parallel_gpc.plots import plot_results

ROOT = Path(__file__).resolve().parents[1]
PLOT_MODULES = ["common", "tracking", "planning", "robustness", "bench", "sweep"]


@pytest.mark.parametrize("module", PLOT_MODULES)
def test_importing_a_plot_module_keeps_the_backend(module):
    """In a fresh interpreter the user picks the SVG backend, then imports the module."""
    probe = ("import matplotlib\nmatplotlib.use('svg')\n"
             f"import parallel_gpc.plots.{module}\n"
             "print(matplotlib.get_backend())\n")
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    env["PYTHONPATH"] = str(ROOT / "src")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "svg"


def test_bench_plot_returns_a_figure(tmp_path):
    rows = [{"section": s, "method": m, "robot": "planar_4rrr", "N": n, "median_us": 10.0 * n}
            for s in ("unconstrained", "limited", "step", "loop", "qpmpc") for m in ("qr", "daqp") for n in (5, 10)]
    fig = plot_results(rows)
    assert isinstance(fig, Figure) and len(fig.axes) == 6
    assert [len(ax.lines) for ax in fig.axes[:5]] == [2] * 5
    assert save_figure(fig, tmp_path / "a" / "b.png").stat().st_size > 10_000
