"""What the benchmark records: one entry per (section, robot, N, method) with its wall times,
solution errors, cost gaps, limit violations and failures, and its summary row (median and 99th
percentile in µs, largest relative errors)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..solvers import LeastSquaresProblem


@dataclass
class BenchEntry:
    """One row of the benchmark: wall times (s) and solution checks of one method on one (robot, N)."""

    section: str
    robot: str
    N: int
    method: str
    times: list = field(default_factory=list)
    errors: list = field(default_factory=list)
    cost_gaps: list = field(default_factory=list)
    violations: list = field(default_factory=list)
    failures: int = 0
    note: str = ""

    def summary(self) -> dict:
        t = np.asarray(self.times)
        err = np.asarray([e for e in self.errors if e is not None and np.isfinite(e)])
        gap = np.asarray([g for g in self.cost_gaps if g is not None and np.isfinite(g)])
        return {
            "section": self.section, "robot": self.robot, "N": self.N, "method": self.method,
            "samples": int(t.size),
            "median_us": float(np.median(t) * 1e6) if t.size else None,
            "p99_us": float(np.percentile(t, 99) * 1e6) if t.size else None,
            "mean_us": float(np.mean(t) * 1e6) if t.size else None,
            "max_rel_error": float(err.max()) if err.size else None,
            "median_rel_error": float(np.median(err)) if err.size else None,
            "max_rel_cost_gap": float(gap.max()) if gap.size else None,
            "max_violation_Nm": float(max(self.violations)) if self.violations else None,
            "failures": self.failures,
            "note": self.note,
        }


def log_solve(e: BenchEntry, dt: float, ok, v, v_ref, problem: LeastSquaresProblem | None = None) -> BenchEntry:
    """Record one timed solve in ``e``: wall time ``dt`` (s), a failure unless ``ok``, the relative
    error of ``v`` against ``v_ref`` and, given the problem, the relative cost gap."""
    e.times.append(dt)
    e.failures += int(not ok)
    e.errors.append(relative_error(v, v_ref))
    if problem is not None:
        e.cost_gaps.append(_cost_gap(problem, v, v_ref))
    return e


def relative_error(v, ref) -> float:
    """Relative error ‖v − ref‖ / ‖ref‖ (inf for a missing or non-finite v)."""
    if v is None or not np.all(np.isfinite(v)):
        return math.inf
    return float(np.linalg.norm(v - ref) / max(np.linalg.norm(ref), 1e-300))


class BenchRun:
    """The entries of one benchmark run, by (section, robot, N, method), and the torque limit τ (N·m)
    chosen per (robot, N)."""

    def __init__(self, cfg):
        """``cfg``: the run's :class:`~parallel_gpc.bench.problems.BenchConfig`."""
        self.cfg = cfg
        self.entries: dict[tuple, BenchEntry] = {}
        self.limits: dict[tuple, float] = {}

    def entry(self, section, robot, N, method, note="") -> BenchEntry:
        key = (section, robot, N, method)
        if key not in self.entries:
            self.entries[key] = BenchEntry(section, robot, N, method, note=note)
        return self.entries[key]


def _cost_gap(problem: LeastSquaresProblem, v, v_ref) -> float:
    """Relative cost gap (J(v) − J(v_ref)) / |J(v_ref)| (inf for a missing or non-finite v)."""
    if v is None or not np.all(np.isfinite(v)):
        return math.inf
    j, j_ref = problem.cost(v), problem.cost(v_ref)
    return float((j - j_ref) / max(abs(j_ref), 1e-300))
