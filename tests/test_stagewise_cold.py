"""Long-horizon torque-limited steps (gpc/stagewise.py, solvers/stagewise_active.py): the cold first
step and the warm steps after it at N = 160 with nearly every input on its limit (the benchmark's
case: planar_4rrr, Qu = 1e-5, τ = half the unconstrained plan's peak; 639 of 640 components held)
reach DAQP's optimum of the condensed problem of the same controller state, its KKT conditions
(NNLS on the active rows) and its rows checked here, whichever stage-wise method solved them. The
active set does not settle the cold step (no update rule measured does at N = 160: see
solvers/stagewise_active.py): the interior point takes over, visibly in ``method`` and ``iterations``."""

from __future__ import annotations

import numpy as np
import pytest

from parallel_gpc import GPCController, Horizons, ParallelRobot, ReducedModel, Weights
from parallel_gpc.gpc.references import SCurve, path_for
from parallel_gpc.limits import Limits
from parallel_gpc.solvers import AS_MAX_ITER, AS_WARM_MAX_ITER
from parallel_gpc.solvers.problem import UNBOUNDED
from closed_loop_states import closed_loop_states
from condensed_oracle import condensed_of_state, kkt_residual, objective

TS = 0.002
N = 160
#: the incremental forms' plan is determined only to ~1e-6 relative here (Qu = 1e-5 at N = 160: a flat
#: criterion; DAQP's and the stage-wise plan agree in objective to 1e-12 and both meet the KKT conditions)
PLAN_TOL = {"absolute": 1e-8, "incremental": 1e-5, "nonlinear": 1e-5}


def _excess(full, v) -> float:
    """The largest excess of v over the condensed problem's rows and boxes, relative to the largest bound."""
    excess, bounds = [0.0], []
    if full.L is not None:
        Lv = full.L @ v
        for side, sign in ((full.hi, 1.0), (full.lo, -1.0)):
            used = np.abs(side) < UNBOUNDED
            excess.append(float(np.max(sign * (Lv - side)[used], initial=0.0)))
            bounds.append(np.abs(side[used]))
    for side, sign in ((full.ub, 1.0), (full.lb, -1.0)):
        if side is not None:
            used = np.abs(side) < UNBOUNDED
            excess.append(float(np.max(sign * (v - side)[used], initial=0.0)))
            bounds.append(np.abs(side[used]))
    return max(excess) / max(float(np.max(np.concatenate(bounds), initial=0.0)), 1e-300)


@pytest.mark.parametrize("form", ["absolute", "incremental", "nonlinear"])
def test_long_horizon_cold_and_warm_steps_reach_daqp(form):
    robot = ParallelRobot.load("planar_4rrr")
    model = ReducedModel(robot)
    ref = path_for("auto", robot.home_pose, robot.output_angular, SCurve().duration)
    X = ref.initial_state()
    H, weights = Horizons(N), Weights(1.0, 1e-5)
    free = GPCController.build(model, TS, H, weights, form=form, solver="riccati")
    tau = 0.5 * np.abs(free.step(X, ref.window(0.0, TS, N)).u).max()
    limits = Limits(torque=tau)
    ric = GPCController.build(model, TS, H, weights, form=form, solver="riccati", limits=limits)
    chk = GPCController.build(model, TS, H, weights, form=form, limits=limits)
    compared = 0
    for k in range(3):
        w = ref.window(k * TS, TS, N)
        full, x_daqp = condensed_of_state(chk, ric, X, w)
        info = ric.step(X, w)
        solver = ric._riccati.constrained
        assert info.result.solver == "riccati" and info.result.ok, info.result.message
        sweeps, ipm = solver.iterations
        if solver.method == "active-set":
            assert ipm == 0 and sweeps >= 1
        else:  # visible: the active set's sweeps up to its cap (or a cycle), then the interior point's iterations
            # and the sweeps of the active set verifying the set they name (the crossover)
            assert solver.method == "interior-point after active set", solver.method
            assert sweeps > (AS_MAX_ITER if k == 0 else AS_WARM_MAX_ITER) or "cycles" in info.result.message
            assert ipm >= 1
        if k == 0:  # the hard case: nearly every input on its limit (the cold step goes to the interior point today)
            assert (solver._fixed >= 0).sum() >= 0.9 * solver._fixed.size
        v = ric._v_prev
        assert _excess(full, v) <= 1e-9
        assert kkt_residual(full, v) <= 1e-9
        compared += x_daqp is not None
        if x_daqp is not None:  # DAQP's answer passed its own KKT check
            v_daqp = x_daqp[:full.n_decision]
            scale = max(objective(full, np.zeros_like(v)), 1e-300)
            assert abs(objective(full, v) - objective(full, v_daqp)) <= 1e-10 * scale
            # on the inputs' scale τ: the nonlinear form's v (increments over the pre-simulated plan) can be ~1e-14
            assert np.abs(v - v_daqp).max() <= PLAN_TOL[form] * max(np.abs(v_daqp).max(), tau)
    assert compared >= 1  # DAQP's own check fails on the nonlinear form's warm steps here (the KKT check stands)


def test_absolute_warm_steps_leave_limited_arcs_at_their_edges():
    """The absolute form's warm steps at N = 160 along a closed loop (the benchmark's states: the
    unconstrained controller on the full plant; τ = half the unconstrained riccati plans' peak) all
    settle in the active set: a component inside an arc of its box row stays fixed whatever its
    multiplier, only the arcs' edges leave (solvers/stagewise_active.py). Without that rule one of
    these 11 steps went to the interior point after 12 sweeps (the arc beyond a moved edge freed at
    once, 90–313 changes proposed per sweep). The last step equals DAQP's plan and meets the KKT
    conditions and rows of the condensed problem."""
    robot = ParallelRobot.load("planar_4rrr")
    model = ReducedModel(robot)
    ref = path_for("auto", robot.home_pose, robot.output_angular, SCurve().duration)
    H, weights = Horizons(N), Weights(1.0, 1e-5)
    states = closed_loop_states(robot, model, ref, N, weights, TS)
    free = GPCController.build(model, TS, H, weights, solver="riccati")
    limits = Limits(torque=0.5 * max(np.abs(free.step(X, w).u).max() for X, w in states))
    ric = GPCController.build(model, TS, H, weights, solver="riccati", limits=limits)
    chk = GPCController.build(model, TS, H, weights, limits=limits)
    sweeps = []
    for k, (X, w) in enumerate(states):
        if k == len(states) - 1:
            full, x_daqp = condensed_of_state(chk, ric, X, w)
        info = ric.step(X, w)
        solver = ric._riccati.constrained
        assert info.result.ok, info.result.message
        if k:
            assert solver.method == "active-set", (k, solver.iterations, info.result.message)
            sweeps.append(solver.iterations[0])
    assert (solver._fixed >= 0).sum() >= 0.9 * solver._fixed.size  # nearly every input on its limit
    v = ric._v_prev
    assert _excess(full, v) <= 1e-9 and kkt_residual(full, v) <= 1e-9
    assert x_daqp is not None
    v_daqp = x_daqp[:full.n_decision]
    assert np.abs(v - v_daqp).max() <= PLAN_TOL["absolute"] * np.abs(v_daqp).max()
    assert max(sweeps) < AS_WARM_MAX_ITER
