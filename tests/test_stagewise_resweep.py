"""The compiled active set's partial re-sweep and both paths' Schur updates against full sweeps.

After the first sweep of a solve, the compiled ``_native.stagewise_active`` factorizes again only the
stages up to the last one whose set changed (the later stages' P, p and gains are those of the sweep
before); the Python reference (:func:`~parallel_gpc.solvers.solve_active_set`) redoes every stage on
every full sweep. Both take a set that differs from the last full sweep's in at most ``SCHUR_MAX``
components from that sweep's factorization instead (``_sweep_update``: one response per changed
component and a small system). On the warm steps of a torque-limited closed loop at N = 80 — a set that
moves by a stage or a few near the limited arcs' edges, 2–4 sweeps a step — every path must take the
same sets and sweeps to the same plan as full sweeps alone: a stage reused that the change invalidated
(one stage too many), or a wrong response, changes the plan.
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

    def spy(qp, rows, fixed, keep=None):
        sets.append(fixed.copy())
        return sweep(qp, rows, fixed, keep)

    monkeypatch.setattr(active_module, "_sweep", spy)
    monkeypatch.setattr(active_module, "SCHUR_MAX", 0)  # the reference: full sweeps alone
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


@pytest.mark.slow
@pytest.mark.parametrize("form", ["incremental", "nonlinear"])
def test_schur_updates_give_the_full_sweeps_sets_and_plans_on_recorded_warm_steps(form, monkeypatch):
    """Every recorded warm step from its start, by the Python reference with its Schur updates and with full
    sweeps alone (SCHUR_MAX = 0): the same sweeps to the same set and status, the plans ≤ 1e-7 relative (as the compiled path's); and the
    steps exercise the updates (sweeps taken from a base set with a changed component of each kind)."""
    steps = _recorded_warm_steps(form, 80, samples=8)
    update = active_module._sweep_update
    kinds = set()

    def spy(qp, rows, base, fixed):
        out = update(qp, rows, base, fixed)
        if out is not None:
            for i, j in np.argwhere(fixed != base[0]):
                kinds.add(("fixed" if base[0][i, j] >= 0 else "free", "fixed" if fixed[i, j] >= 0 else "free"))
        return out

    monkeypatch.setattr(active_module, "_sweep_update", spy)
    for qp, rows, start in steps:
        monkeypatch.setattr(active_module, "SCHUR_MAX", 0)
        full = active_module.solve_active_set(qp, rows, start)
        monkeypatch.undo()
        monkeypatch.setattr(active_module, "_sweep_update", spy)
        updated = active_module.solve_active_set(qp, rows, start)
        assert (updated.status, updated.iterations) == (full.status, full.iterations)
        np.testing.assert_array_equal(updated.fixed, full.fixed)
        if full.status == "optimal":
            assert np.abs(updated.v - full.v).max() <= 1e-7 * np.abs(full.v).max()  # rounding: 5e-9 measured
    assert {("fixed", "free"), ("free", "fixed")} <= kinds, f"the updates met only {kinds}"


def _box_rows_qp(seed: int, state_rows: bool):
    """A random StageQP of input rows (N = 12, nz = 5, m = 3): each component between two rows σ v_j + Fz z ≤ f
    (σ = ±1; Fz random with ``state_rows``, zero otherwise: the box of the absolute form)."""
    from parallel_gpc.solvers import StageQP

    rng = np.random.default_rng(seed)
    N, nz, m = 12, 5, 3
    A = np.eye(nz) + 0.1 * rng.standard_normal((N, nz, nz))
    B, c = rng.standard_normal((N, nz, m)), 0.1 * rng.standard_normal((N, nz))
    Cm = rng.standard_normal((nz, nz))
    Q, q = np.array([Cm.T @ Cm] * (N + 1)), rng.standard_normal((N + 1, nz))
    Fz = 0.3 * rng.standard_normal((N, 2 * m, nz)) if state_rows else np.zeros((N, 2 * m, nz))
    Fv = np.zeros((N, 2 * m, m))
    for j in range(m):
        Fv[:, j, j], Fv[:, m + j, j] = 1.0, -1.0
    f = 0.3 + 0.2 * rng.random((N, 2 * m))
    return StageQP(A, B, c, rng.standard_normal(nz), Q, q, 0.5 * np.eye(m), N, Fz, Fv, f,
                   np.zeros((N, 2 * m), bool), 5.0, 0.1)


@pytest.mark.parametrize("state_rows", [False, True])
def test_a_schur_update_equals_the_full_sweep_of_the_new_set(state_rows, monkeypatch):
    """From a random base set, sets with 1 … SCHUR_MAX components changed — freed, fixed, or moved to the other
    row — taken from the base's sweep (_sweep_update) give the full sweep's plan to 1e-10 relative; more changes
    than SCHUR_MAX, or more than 2·SCHUR_MAX responses against one base, are left to a full sweep (None)."""
    from parallel_gpc.solvers import input_rows_of

    kinds = set()
    for seed in range(12):
        qp = _box_rows_qp(seed, state_rows)
        rows = input_rows_of(qp)
        rng = np.random.default_rng(seed + 100)
        N, m = qp.f.shape[0], qp.R.shape[0]
        base_set = np.where(rng.random((N, m)) < 0.5, rng.integers(0, 2, (N, m)) * m + np.arange(m), -1)
        base = []
        active_module._sweep(qp, rows, base_set, base)
        for n_changes in range(1, active_module.SCHUR_MAX + 1):
            new = base_set.copy()
            for i, j in zip(rng.choice(N, n_changes, replace=False), rng.integers(0, m, n_changes)):
                choices = [r for r in (-1, j, m + j) if r != base_set[i, j]]
                new[i, j] = rng.choice(choices)
                kinds.add((base_set[i, j] >= 0, new[i, j] >= 0))
            z, v = active_module._sweep(qp, rows, new)
            base[-1].clear()  # the responses computed against the base (at most 2·SCHUR_MAX)
            zu, vu = active_module._sweep_update(qp, rows, base, new)
            assert np.abs(vu - v).max() <= 1e-10 * max(1.0, np.abs(v).max())
            assert np.abs(zu - z).max() <= 1e-10 * max(1.0, np.abs(z).max())
        many = np.where(base_set >= 0, -1, np.arange(m))  # every component changed
        assert active_module._sweep_update(qp, rows, base, many) is None
        base[-1].clear()
        taken = 0  # one component freed or fixed at a time, each a new response: 2·SCHUR_MAX of them (6 < N)
        with monkeypatch.context() as patch:
            patch.setattr(active_module, "SCHUR_MAX", 3)
            for i in range(N):
                one = base_set.copy()
                one[i, 0] = -1 if base_set[i, 0] >= 0 else 0
                taken += active_module._sweep_update(qp, rows, base, one) is not None
        assert taken == 6
    assert kinds == {(True, True), (True, False), (False, True)}
