"""The compiled active set's partial re-sweep against the Python reference's full sweeps.

After the first sweep of a solve, the compiled ``_native.stagewise_active`` factorizes again only the
stages up to the last one whose set changed (the later stages' P, p and gains are those of the sweep
before); the Python reference (:func:`~parallel_gpc.solvers.solve_active_set`) redoes every stage on
every sweep. On the warm steps of a torque-limited closed loop at N = 80 — a set that moves by a stage
or a few near the limited arcs' edges, 2–4 sweeps a step — both must take the same sets and sweeps to
the same plan: a stage reused that the change invalidated (one stage too many) changes the plan.
"""

from __future__ import annotations

import numpy as np
import pytest

import parallel_gpc.gpc.stagewise as stagewise_module
import parallel_gpc.solvers.stagewise_active as active_module
from parallel_gpc import GPCController, Horizons, ParallelRobot, ReducedModel, Weights
from parallel_gpc.gpc.references import SCurve, path_for
from parallel_gpc.gpc.riccati import RiccatiPath
from parallel_gpc.limits import Limits
from parallel_gpc.model.native import native_module
from parallel_gpc.solvers import AS_WARM_MAX_ITER
from closed_loop_states import closed_loop_states

TS = 0.002
HAS_COMPILED = native_module() is not None and hasattr(native_module(), "stagewise_active")


def _recorded_warm_steps(form: str, N: int, samples: int) -> list[tuple]:
    """(qp, rows, start) of the warm limited steps of a closed loop (planar_4rrr, Qu = 1e-5, the torque
    limit at half the largest unconstrained |u| along the path), as the Python stage-wise path solved them."""
    robot = ParallelRobot.load("planar_4rrr")
    model = ReducedModel(robot)
    weights = Weights(1.0, 1e-5)
    ref = path_for("auto", robot.home_pose, robot.output_angular, SCurve().duration)
    states = closed_loop_states(robot, model, ref, N, weights, TS, samples)
    free = GPCController.build(model, TS, Horizons(N), weights, form=form, solver="riccati")
    limits = Limits(torque=0.5 * max(float(np.abs(free.step(X, w).u).max()) for X, w in states))
    ctl = GPCController.build(model, TS, Horizons(N), weights, form=form, solver="riccati", limits=limits)
    ctl._riccati = RiccatiPath(ctl._criterion, ctl.model.C, form, native=False, limits=ctl._qp_limits, Ts=TS)
    recorded = []
    solve = stagewise_module.solve_active_set

    def spy(qp, rows, start=None, **kwargs):
        if start is not None:
            recorded.append((qp, rows, start.copy()))
        return solve(qp, rows, start, **kwargs)

    stagewise_module.solve_active_set = spy
    try:
        for X, w in states:
            assert ctl.step(X, w).result.ok
    finally:
        stagewise_module.solve_active_set = solve
    return recorded


@pytest.mark.slow
@pytest.mark.skipif(not HAS_COMPILED, reason="the compiled core is not built")
@pytest.mark.parametrize("form", ["incremental", "nonlinear"])
def test_the_partial_resweep_gives_the_full_sweeps_plan_on_recorded_warm_steps(form, monkeypatch):
    """Every recorded warm step from its start: the compiled solve (partial re-sweeps) and the Python one
    (full sweeps) take the same sweeps to the same set and status (the first warm steps after a cold one
    may not settle in the warm cap: both then hand it on), the settled ones' plans ≤ 1e-7 relative; and
    the steps exercise the reuse: a sweep after a change ending before the last decision stage."""
    N = 80
    steps = _recorded_warm_steps(form, N, samples=8)
    sets = []
    sweep = active_module._sweep

    def spy(qp, rows, fixed):
        sets.append(fixed.copy())
        return sweep(qp, rows, fixed)

    monkeypatch.setattr(active_module, "_sweep", spy)
    c = np.ascontiguousarray
    reused = settled = 0
    for qp, rows, start in steps:
        sets.clear()
        full = active_module.solve_active_set(qp, rows, start)
        v, z, lam, fixed, iterations, ok, residual, message = native_module().stagewise_active(
            c(qp.A, float), c(qp.B, float), c(qp.c, float), c(qp.z0, float), c(qp.Q, float), c(qp.q, float),
            c(qp.R, float), qp.n_decide, c(qp.Fz, float), c(qp.f, float), c(rows.comp, np.int64),
            c(rows.sign, float), c(start, np.int64), AS_WARM_MAX_ITER)
        assert (ok, iterations) == (full.status == "optimal", full.iterations), (full.message, message)
        np.testing.assert_array_equal(fixed, full.fixed)
        if ok:
            settled += 1
            assert np.abs(v - full.v).max() <= 1e-7 * np.abs(full.v).max()  # rounding: 1.4e-8 (Qu = 1e-5, N = 80)
        for before, after in zip(sets, sets[1:]):  # the last stage each re-sweep factorizes again
            changed = np.flatnonzero((before != after).any(axis=1))
            reused += bool(changed.size) and changed.max() < qp.n_decide - 1
    assert settled >= 4 and reused >= 2, "the recorded steps did not exercise the partial re-sweep"
