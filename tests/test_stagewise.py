"""solver="riccati" with limits: the stage-wise active set and interior point (gpc/stagewise.py,
solvers/stagewise_active.py, solvers/stagewise_ipm.py) against DAQP on the controller's condensed problem, KKT conditions of
that condensed problem computed here, a dense QP of a random stage problem, and its clear refusals."""

from __future__ import annotations

import os
from dataclasses import replace

import numpy as np
import pytest
import qpsolvers

from parallel_gpc import GPCController, Horizons, ParallelRobot, ReducedModel, Weights
from parallel_gpc.errors import InvalidParameterError, SolverError
from parallel_gpc.gpc.fallback import limit_gap, limit_violation
from parallel_gpc.gpc.riccati import RiccatiPath
from parallel_gpc.gpc.stagewise import StagewiseSolver, input_bounds, step_bounds
from parallel_gpc.gpc.stages import FORM_CODES
from parallel_gpc.model.native import native_module
from parallel_gpc.gpc.references import SCurve, path_for
from parallel_gpc.limits import Limits
from parallel_gpc.model.plant import ConstrainedPlant
from parallel_gpc.solvers import (AS_MAX_ITER, AS_WARM_MAX_ITER, CROSSOVER, QRSolver, StageQP, StageStart, active_set_of, input_rows_of,
                                   shift_active_set, solve_active_set, solve_stage_qp, stopped_short)
from parallel_gpc.solvers.stagewise_ipm import costates
from closed_loop_states import closed_loop_states
from condensed_oracle import condensed, condensed_of_state, kkt_residual, objective

TS = 0.002
FORMS = ["absolute", "incremental", "incremental-delayed", "nonlinear"]


@pytest.fixture(scope="module", params=["planar_4rrr", "delta_3rus"])
def robot(request) -> ParallelRobot:
    return ParallelRobot.load(request.param)


def _x_of(full, v):
    """[v; s]: the slacks of the condensed problem at v (its optimum given v: the largest violation
    of each soft pair, in the problem's slack unit)."""
    if not full.n_slack:
        return v
    X = np.zeros(full.n_slack)
    n = len(v)
    L = full.L[:, :n]
    S = full.L[:, n:]
    viol = L @ v - full.hi
    for i in range(L.shape[0]):
        j = np.flatnonzero(S[i])
        if j.size:
            X[j[0]] = max(X[j[0]], viol[i] / -S[i, j[0]])
    return np.concatenate([v, X])


CASES = {  # name: Limits from the unconstrained plan's largest |u|, a box halving its motion, its speed
    "torque": lambda u, box, speed: Limits(torque=0.4 * u),
    "torque-inactive": lambda u, box, speed: Limits(torque=10.0 * u),
    "du": lambda u, box, speed: Limits(du=0.05 * u),
    "torque+du": lambda u, box, speed: Limits(torque=0.5 * u, du=0.1 * u),
    "box-soft": lambda u, box, speed: Limits(output_box=box, penalty=1e-3),
    "box-hard": lambda u, box, speed: Limits(output_box=box, soft=()),
    "velocity-soft": lambda u, box, speed: Limits(output_velocity=0.5 * speed, torque=2.0 * u, penalty=1e-3),
    "velocity-hard": lambda u, box, speed: Limits(output_velocity=0.5 * speed, soft=()),
}


def _setup(robot, form, case, N=12, No=0, Nu=None, cases=CASES):
    model = ReducedModel(robot)
    rng = np.random.default_rng(7)
    H = Horizons(N, No, Nu or N)
    weights = Weights(1.0, 1e-3)
    X = np.concatenate([robot.home_pose, np.zeros(robot.n_y)])
    step = np.zeros(robot.n_y)
    step[0] = 0.01
    w = np.tile(robot.home_pose + step, (N, 1))
    free = GPCController.build(model, TS, H, weights, form=form, solver="qr")
    free.step(X, w)
    u_free = np.abs(free.plan).max()
    free = GPCController.build(model, TS, H, weights, form=form, solver="qr")
    pred = free.predict(X)
    y_free = pred.outputs(QRSolver().solve(free._criterion.problem(pred, w[H.No:])).v).reshape(-1, robot.n_y)
    box = np.array([[-1.0, 1.0]] * robot.n_y) + robot.home_pose[:, None]
    box[0, 1] = 0.5 * (robot.home_pose[0] + y_free[:, 0].max())
    speed = np.abs(np.diff(np.vstack([robot.home_pose, y_free]), axis=0)).max(axis=0) / TS
    limits = cases[case](u_free, box, np.maximum(speed, 1e-3))
    if form == "absolute" and limits.du is not None:
        pytest.skip("du applies to the incremental forms")
    ctl = GPCController.build(model, TS, H, weights, form=form, solver="riccati", limits=limits)
    ctl.u_prev = 0.01 * u_free * rng.standard_normal(robot.n_u)
    return ctl, X, w


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("form", FORMS)
def test_stagewise_equals_daqp_on_the_condensed_problem(robot, form, case):
    ctl, X, w = _setup(robot, form, case)
    path = ctl._riccati
    result = path.solve(*path.stages(ctl, X, w[ctl.horizons.No:]))
    full, x_ref = condensed(ctl, X, w)
    assert result.status == "optimal", result.message
    x = _x_of(full, result.v)
    kkt = kkt_residual(full, x)
    assert kkt <= 1e-9, kkt
    if x_ref is not None:  # DAQP's answer passed its own KKT check
        v_ref = x_ref[:full.n_decision]
        err = np.abs(result.v - v_ref).max() / np.abs(v_ref).max()
        assert err <= 1e-8, err
        assert objective(full, x) == pytest.approx(objective(full, x_ref), rel=1e-10)
    active = case not in ("torque-inactive",)
    assert result.active_limits is active


@pytest.mark.parametrize("form", FORMS)
def test_stagewise_with_short_control_and_insensitivity_horizons(robot, form):
    ctl, X, w = _setup(robot, form, "torque", N=15, No=2, Nu=5)
    path = ctl._riccati
    result = path.solve(*path.stages(ctl, X, w[ctl.horizons.No:]))
    full, x_ref = condensed(ctl, X, w)
    v_ref = x_ref[:full.n_decision]
    assert result.status == "optimal" and result.active_limits
    assert np.abs(result.v - v_ref).max() <= 1e-8 * np.abs(v_ref).max()


def test_closed_loop_torque_limited_matches_the_condensed_default():
    robot = ParallelRobot.load("planar_4rrr")
    model = ReducedModel(robot)
    runs, fell_back = [], []
    for solver in ("riccati", None):
        ctl = GPCController.build(model, TS, Horizons(10), Weights(1.0, 1e-4), form="incremental", solver=solver,
                                  limits=Limits(torque=3.0))
        X = np.concatenate([robot.home_pose, np.zeros(robot.n_y)])
        us, fell = [], []
        for k in range(6):
            w = np.tile(robot.home_pose + np.array([0.01, 0.0, 0.0]), (10, 1))
            info = ctl.step(X, w)
            us.append(info.u)
            fell.append(info.fallback)
            X = X + np.concatenate([X[3:] * TS, np.zeros(3)])  # a coarse plant: what matters is the same X
        runs.append(np.array(us))
        fell_back.append(np.array(fell))
    assert not fell_back[0].any()  # the stage-wise path never falls back (the condensed DAQP did, here)
    assert np.abs(runs[0]).max() == pytest.approx(3.0 * (1 - 1e-6), rel=1e-6)  # the limit binds
    same = ~fell_back[1]
    assert same.sum() >= 3
    assert np.abs(runs[0][same] - runs[1][same]).max() <= 1e-7 * 3.0


@pytest.mark.parametrize("form", FORMS)
def test_warm_started_steps_reach_the_condensed_optimum(form):
    """A closed loop of limited riccati steps, each warm-started from the previous solution shifted
    by one stage: every step's plan is optimal for the condensed problem of the same controller
    state (DAQP's objective, a KKT residual at the rounding floor)."""
    robot = ParallelRobot.load("planar_4rrr")
    model = ReducedModel(robot)
    H, weights, limits = Horizons(10), Weights(1.0, 1e-4), Limits(torque=3.0)
    ric = GPCController.build(model, TS, H, weights, form=form, solver="riccati", limits=limits)
    chk = GPCController.build(model, TS, H, weights, form=form, limits=limits)
    X = np.concatenate([robot.home_pose, np.zeros(robot.n_y)])
    w = np.tile(robot.home_pose + np.array([0.01, 0.0, 0.0]), (10, 1))
    warm = active = 0
    for k in range(5):
        full, x_daqp = condensed_of_state(chk, ric, X, w)
        warm += ric._riccati.constrained._last is not None
        info = ric.step(X, w)
        assert info.result.solver == "riccati" and info.result.ok, info.result.message
        active += info.result.active_limits
        v = ric._v_prev
        scale = max(objective(full, np.zeros_like(v)), 1e-300)
        if x_daqp is not None:
            assert abs(objective(full, v) - objective(full, x_daqp)) <= 1e-9 * scale
        assert kkt_residual(full, v) <= 1e-8
        X = X + np.concatenate([X[3:] * TS, np.zeros(3)])
    assert warm == 4  # every step after the first started warm
    assert active >= 3  # the torque limit binds


def _random_stage_qp(seed, Fz_zero=False):
    rng = np.random.default_rng(seed)
    N, nz, m, k, nd = 8, 4, 2, 3, 6
    A = np.eye(nz) + 0.1 * rng.standard_normal((N, nz, nz))
    B, c = rng.standard_normal((N, nz, m)), 0.1 * rng.standard_normal((N, nz))
    Cm = rng.standard_normal((nz, nz))
    Q, q = np.array([Cm.T @ Cm] * (N + 1)), rng.standard_normal((N + 1, nz))
    Fz, Fv = rng.standard_normal((N, k, nz)), rng.standard_normal((N, k, m))
    Fv[nd:] = 0.0
    if Fz_zero:
        Fz[:] = 0.0
    f = 0.3 + 0.2 * rng.random((N, k))
    f[2, 1] = np.inf
    soft = rng.random((N, k)) < 0.4
    return StageQP(A, B, c, rng.standard_normal(nz), Q, q, 0.5 * np.eye(m), nd, Fz, Fv, f, soft, 5.0, 0.1)


def _dense(qp: StageQP):
    """The stage problem as one dense QP in [z(1..N), v, s], solved by DAQP through qpsolvers."""
    N, nz = qp.A.shape[:2]
    m, nd = qp.R.shape[0], qp.n_decide
    si = [tuple(ij) for ij in np.argwhere(qp.soft & np.isfinite(qp.f))]
    n = N * nz + nd * m + len(si)
    Z = lambda i: slice((i - 1) * nz, i * nz)  # noqa: E731
    V = lambda i: slice(N * nz + i * m, N * nz + (i + 1) * m)  # noqa: E731
    P, g = np.zeros((n, n)), np.zeros(n)
    for i in range(1, N + 1):
        P[Z(i), Z(i)] += qp.Q[i]
        g[Z(i)] += qp.q[i]
    for i in range(nd):
        P[V(i), V(i)] += qp.R
    for j in range(len(si)):
        P[N * nz + nd * m + j, N * nz + nd * m + j], g[N * nz + nd * m + j] = qp.kappa, qp.rho
    Aeq, beq = np.zeros((N * nz, n)), np.zeros(N * nz)
    for i in range(N):
        rows = slice(i * nz, (i + 1) * nz)
        Aeq[rows, Z(i + 1)] = -np.eye(nz)
        if i:
            Aeq[rows, Z(i)] = qp.A[i]
        else:
            beq[rows] -= qp.A[0] @ qp.z0
        if i < nd:
            Aeq[rows, V(i)] = qp.B[i]
        beq[rows] -= qp.c[i]
    G, h = [], []
    for i, j in np.argwhere(np.isfinite(qp.f)):
        row, rhs = np.zeros(n), qp.f[i, j]
        if i:
            row[Z(i)] = qp.Fz[i, j]
        else:
            rhs -= qp.Fz[i, j] @ qp.z0
        if i < nd:
            row[V(i)] = qp.Fv[i, j]
        if (i, j) in si:
            row[N * nz + nd * m + si.index((i, j))] = -1.0
        G.append(row)
        h.append(rhs)
    lb = np.full(n, -np.inf)
    lb[N * nz + nd * m:] = 0.0
    x = qpsolvers.solve_qp(P, g, np.array(G), np.array(h), Aeq, beq, lb=lb, solver="daqp")
    return x[N * nz:N * nz + nd * m].reshape(nd, m), x[:N * nz].reshape(N, nz)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_stage_problem_equals_a_dense_qp(seed):
    """Box rows on v (the input limits' kind): the interior point reaches the dense QP's solution."""
    qp = _random_stage_qp(seed, Fz_zero=True)
    sol = solve_stage_qp(qp)
    v, z = _dense(qp)
    assert sol.status == "optimal"
    assert np.abs(sol.v - v).max() <= 1e-8 * max(1.0, np.abs(v).max())
    assert np.abs(sol.z[1:] - z).max() <= 1e-8 * max(1.0, np.abs(z).max())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_any_warm_start_reaches_the_dense_qp(seed):
    """A warm start is only a guess: a random plan, multipliers and slacks (some far off, some 0)
    lead to the dense QP's solution as the cold start does."""
    qp = _random_stage_qp(seed, Fz_zero=True)
    rng = np.random.default_rng(seed + 10)
    v, z = _dense(qp)
    for guess in (StageStart(rng.standard_normal(v.shape), 10.0 * rng.random(qp.f.shape), np.zeros(qp.f.shape)),
                  StageStart(None, np.zeros(qp.f.shape), rng.random(qp.f.shape))):
        sol = solve_stage_qp(qp, start=guess)
        assert sol.status == "optimal"
        assert np.abs(sol.v - v).max() <= 1e-8 * max(1.0, np.abs(v).max())
        assert np.abs(sol.z[1:] - z).max() <= 1e-8 * max(1.0, np.abs(z).max())


def test_a_singular_input_weight_is_named_and_a_late_ill_conditioned_system_is_regularized():
    """R + BᵀPB not ≻ 0 on the unconstrained system: the message names the input weight. On an
    iterate (row weights λ/t ~ 1/μ), a Hessian positive semi-definite to working precision is
    shifted, not reported as a singular input weight."""
    qp = _random_stage_qp(0, Fz_zero=True)
    qp.R = np.diag([1.0, 0.0])
    qp.B[:, :, 1] = 0.0
    with pytest.raises(SolverError, match=r"R \+ BᵀPB .* not positive definite .*Qu must be nonsingular"):
        solve_stage_qp(qp)
    from parallel_gpc.solvers.stagewise_ipm import _cholesky
    a = np.array([1.0, 1e-9])
    H = np.outer(a, a) * 1e12 + np.diag([0.0, -1e-6])  # PSD up to rounding: 1e12 next to a 1e-6 defect
    W = np.full((1, 2), 1e12)
    with pytest.raises(SolverError, match="input weight Qu"):
        _cholesky(H, 3, W, regularize=False)
    c, lower = _cholesky(H, 3, W, regularize=True)
    assert np.all(np.isfinite(c))
    with pytest.raises(SolverError, match="singular to working precision .* not the input weight"):
        _cholesky(np.diag([1.0, -1.0]), 3, W, regularize=True)


def test_random_mixed_rows_reach_the_dense_qp_closely():
    """Dense random rows in z and v (harder than any controller's): agreement to 1e-6."""
    qp = _random_stage_qp(0)
    sol = solve_stage_qp(qp)
    v, _ = _dense(qp)
    assert sol.status == "optimal"
    assert np.abs(sol.v - v).max() <= 1e-6 * max(1.0, np.abs(v).max())


def test_infeasible_hard_limits_are_reported():
    """A hard output box the motion cannot reach in time: status infeasible, the message says why;
    in the controller a visible replacement by the condensed default."""
    robot = ParallelRobot.load("planar_4rrr")
    model = ReducedModel(robot)
    y0 = robot.home_pose
    box = np.array([[y0[0] + 0.02, y0[0] + 0.03]] + [[y - 1.0, y + 1.0] for y in y0[1:]])
    limits = Limits(output_box=box, torque=1.0, soft=())
    ctl = GPCController.build(model, TS, Horizons(5), Weights(1.0, 1e-3), solver="riccati", limits=limits)
    X = np.concatenate([y0, np.zeros(3)])
    w = np.tile(y0, (5, 1))
    path = ctl._riccati
    result = path.solve(*path.stages(ctl, X, w))
    assert result.status == "infeasible" and "infeasible" in result.message


def test_iterations_stopped_short_say_whether_a_hard_row_is_broken():
    """The interior point stopped by its cap on a feasible problem: every hard row holds at its plan, so the
    status is unconverged and the message says the limits are not shown infeasible (it said infeasible
    with a largest violation of 0); a plan that breaks a hard row: infeasible, naming the row; the same
    rule on the compiled iterations' plan (stopped_short)."""
    qp = _random_stage_qp(0)
    optimum = solve_stage_qp(qp)
    assert optimum.status == "optimal"
    short = solve_stage_qp(qp, max_iter=5)  # stopped short (KKT residual ~9) at an iterate inside every hard row
    assert short.status == "unconverged" and short.residual > 1e-6 and "not shown infeasible" in short.message
    used = np.isfinite(qp.f) & ~qp.soft
    F = np.einsum("ikn,in->ik", qp.Fz, short.z[:-1])
    F[:qp.n_decide] += np.einsum("ikm,im->ik", qp.Fv[:qp.n_decide], short.v)
    broken = float(np.max(np.where(used, F - np.where(used, qp.f, 0.0), -np.inf)))
    assert (short.status == "infeasible") == (broken > 1e-6 * np.abs(qp.f[np.isfinite(qp.f)]).max())
    status, message = stopped_short(qp, optimum.z, optimum.v, 7, 1e-3)
    assert status == "unconverged" and "every hard row within its bound" in message and "not shown infeasible" in message
    i, j = np.argwhere(used)[0]
    F = np.einsum("ikn,in->ik", qp.Fz, optimum.z[:-1])
    F[:qp.n_decide] += np.einsum("ikm,im->ik", qp.Fv[:qp.n_decide], optimum.v)
    f = qp.f.copy()
    f[i, j] = F[i, j] - 0.1  # the optimum's row i, j now 0.1 beyond its bound
    status, message = stopped_short(replace(qp, f=f), optimum.z, optimum.v, 7, 1e-3)
    assert status == "infeasible" and f"at stage {i}, row {j}" in message and "cannot all hold" in message


def test_drive_limits_with_riccati_are_a_clear_error():
    robot = ParallelRobot.load("planar_4rrr")
    with pytest.raises(InvalidParameterError, match="drive limits"):
        GPCController.build(ReducedModel(robot), TS, Horizons(10), Weights(1.0, 1e-3), solver="riccati",
                            limits=Limits(drive_rate=1.0))


HAS_COMPILED = native_module() is not None and hasattr(native_module(), "stagewise_ipm")
if not HAS_COMPILED and os.environ.get("CI"):
    raise RuntimeError("CI must test the compiled stage-wise interior point (parallel_gpc._native.stagewise_ipm)")


@pytest.mark.skipif(not HAS_COMPILED, reason="the compiled core has no stagewise_ipm")
@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("form", FORMS)
def test_compiled_equals_the_python_reference(robot, form, case):
    ctl, X, w = _setup(robot, form, case)
    H = ctl.horizons
    stages = ctl._riccati.stages(ctl, X, w[H.No:])
    results = []
    for native in (False, True):
        path = RiccatiPath(ctl._criterion, ctl.model.C, form, native=native, limits=ctl._qp_limits, Ts=TS)
        path._extra = ctl._riccati._extra
        assert path.constrained.native is native
        results.append(path.solve(*stages))
    python, compiled = results
    assert python.status == compiled.status == "optimal", (python.message, compiled.message)
    assert np.abs(compiled.v - python.v).max() <= 1e-9 * np.abs(python.v).max()
    assert compiled.active_limits is python.active_limits


def _compiled_solve(qp: StageQP, start: StageStart | None = None):
    c = np.ascontiguousarray
    extra = () if start is None else (None if start.v is None else c(start.v, float), c(start.lam), c(start.s))
    return native_module().stagewise_ipm(c(qp.A), c(qp.B), c(qp.c), c(qp.z0), c(qp.Q), c(qp.q), c(qp.R), qp.n_decide,
                                         c(qp.Fz), c(qp.Fv), c(qp.f), c(qp.soft), qp.rho, qp.kappa, np.zeros(0),
                                         *extra)


@pytest.mark.skipif(not HAS_COMPILED, reason="the compiled core has no stagewise_ipm")
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compiled_warm_start_reaches_the_dense_qp(seed):
    qp = _random_stage_qp(seed, Fz_zero=True)
    rng = np.random.default_rng(seed + 10)
    v, _ = _dense(qp)
    for guess in (None, StageStart(rng.standard_normal(v.shape), 10.0 * rng.random(qp.f.shape), np.zeros(qp.f.shape)),
                  StageStart(None, np.zeros(qp.f.shape), rng.random(qp.f.shape))):
        v_c, _, _, _, _, ok, _ = _compiled_solve(qp, guess)
        assert ok
        assert np.abs(v_c - v).max() <= 1e-8 * max(1.0, np.abs(v).max())


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("incremental", [False, True])
def test_crossover_iterate_names_the_set_the_active_set_verifies(seed, incremental):
    """The interior point stopped at CROSSOVER (Python and compiled): status "crossover" with its merit at
    most that, fewer iterations than to the tolerance; the set its multipliers name (λ kept on the rows
    the iterate deems active) settles in the active set on DAQP's plan with its KKT conditions met."""
    # (no Δu rows with the incremental torque rows: binding together they pin the held input, a problem
    # with no set of one row per component, which the active set does not settle from any start)
    qp = _input_row_qp(seed, incremental, du=not incremental)
    rows = input_rows_of(qp)
    v_ref, _ = _dense(qp)
    full = solve_stage_qp(qp)
    runs = [solve_stage_qp(qp, crossover=CROSSOVER)]
    if HAS_COMPILED:
        c = np.ascontiguousarray
        v, z, s, lam, iterations, _, merit = native_module().stagewise_ipm(
            c(qp.A), c(qp.B), c(qp.c), c(qp.z0), c(qp.Q), c(qp.q), c(qp.R), qp.n_decide, c(qp.Fz), c(qp.Fv), c(qp.f),
            c(qp.soft), qp.rho, qp.kappa, np.zeros(0), None, None, None, CROSSOVER)
        assert merit <= CROSSOVER
        runs.append(replace(full, v=v, z=z, s=s, lam=lam, iterations=iterations, status="crossover", residual=merit))
    for cross in runs:
        assert cross.status == "crossover" and cross.residual <= CROSSOVER
        assert 0 < cross.iterations < full.iterations
        sol = solve_active_set(qp, rows, active_set_of(qp, rows, cross.lam))
        assert sol.status == "optimal" and sol.residual <= 1e-9, sol.message
        assert np.abs(sol.v - v_ref).max() <= 1e-8 * max(np.abs(v_ref).max(), 1.0)


@pytest.mark.skipif(not HAS_COMPILED, reason="the compiled core has no stagewise_ipm")
def test_compiled_singular_input_weight_is_named():
    qp = _random_stage_qp(0, Fz_zero=True)
    qp.R = np.diag([1.0, 0.0])
    qp.B[:, :, 1] = 0.0
    with pytest.raises(RuntimeError, match=r"R \+ BᵀPB .* not positive definite .*Qu must be nonsingular"):
        _compiled_solve(qp)


# ---------------------------------------------------------------- the active set on the input rows
INPUT_CASES = {  # torque and Δu limits tight enough to bind on many stages
    "torque": lambda u, box, speed: Limits(torque=0.2 * u),
    "du": CASES["du"],
    "torque+du": CASES["torque+du"],
}


@pytest.mark.parametrize("horizons", [dict(N=12), dict(N=15, No=2, Nu=5)], ids=["Nu=N", "No=2,Nu=5"])
@pytest.mark.parametrize("case", list(INPUT_CASES))
@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("name", ["planar_4rrr", "hexapod_6ups", "delta_3rus"])  # redundant; prismatic; spatial
def test_input_limits_take_the_active_set_and_reach_daqp(name, form, case, horizons):
    """Torque and Δu limits: the active set (not the interior point) reaches DAQP's plan and objective
    on the condensed problem to 1e-8, its KKT residual (NNLS on the active rows) at the rounding
    floor, the limits binding on several stages. Every form, the nonlinear one's torque rows after Nu
    (on the held input: stage Nu − 1's tightest, input_bounds) included."""
    robot = ParallelRobot.load(name)
    ctl, X, w = _setup(robot, form, case, cases=INPUT_CASES, **horizons)
    path = ctl._riccati
    result = path.solve(*path.stages(ctl, X, w[ctl.horizons.No:]))
    expected = "active-set"
    assert path.constrained.method == expected
    assert result.status == "optimal" and result.message == "", result.message
    full, x_ref = condensed(ctl, X, w)
    assert kkt_residual(full, result.v) <= 1e-9
    assert x_ref is not None
    v_ref = x_ref[:full.n_decision]
    assert np.abs(result.v - v_ref).max() <= 1e-8 * np.abs(v_ref).max()
    scale = max(objective(full, np.zeros_like(result.v)), 1e-300)
    assert abs(objective(full, result.v) - objective(full, v_ref)) <= 1e-10 * scale
    if expected == "active-set":
        binding = (path.constrained._fixed >= 0).any(axis=1)
        assert binding.sum() >= 2, binding
    H = ctl.horizons
    if form == "nonlinear" and H.Nu < H.N and case == "torque":  # rows after Nu bind here (moved to stage Nu − 1)
        pred = path.input_map(ctl, path.stages(ctl, X, w[H.No:]))
        U = (pred.u_base + pred.u_map @ result.v).reshape(-1, ctl.n_u)
        assert np.isclose(np.abs(U[H.Nu:]), ctl._qp_limits.torque, rtol=1e-9).any()


@pytest.mark.parametrize("Nu", [1, 4, 12])
@pytest.mark.parametrize("kinds", [("torque",), ("du",), ("torque", "du")])
def test_step_bounds_are_input_bounds_in_the_stage_layout(kinds, Nu):
    """step_bounds (the compiled nonlinear step's bounds, every step) against its reference input_bounds:
    the columns [hi, −lo] per kind, torque then du, the rows after Nu on stage Nu − 1, inf where unused;
    the du rows need u(k−1) (a clear error without it)."""
    rng = np.random.default_rng(Nu)
    m, H = 4, Horizons(12, 0, Nu)
    values = {"torque": 3.0 + rng.random(m), "du": 0.5 + rng.random(m)}
    limits = Limits(**{kind: values[kind] for kind in kinds}).for_drives(m)
    for _ in range(3):
        u_sim, u_prev = rng.standard_normal((H.N, m)), rng.standard_normal(m)
        want = np.concatenate([b for _, lo, hi in input_bounds("nonlinear", limits, H, m, u_sim, u_prev)
                               for b in (hi, -lo)], axis=1)
        got = step_bounds(limits, H, u_sim, u_prev)
        assert got.shape == want.shape == (H.N, 2 * m * len(kinds))
        assert np.array_equal(np.isfinite(got), np.isfinite(want)) and np.isfinite(got[:Nu]).all()
        used = np.isfinite(want)
        assert np.abs(got[used] - want[used]).max() <= 1e-15 * np.abs(want[used]).max()
    if "du" in kinds:
        with pytest.raises(InvalidParameterError, match="pass u_prev"):
            step_bounds(limits, H, u_sim)


def _input_row_qp(seed: int, incremental: bool, du: bool = True):
    """A random stage problem with torque-like rows on v(i) (incremental: on z[n:] + v(i), the held
    input in the state) and (``du``) Δu-like boxes on v(i), for the active set and a dense QP."""
    qp = _random_stage_qp(seed, Fz_zero=True)
    N, nz = qp.A.shape[:2]
    m, nd = qp.R.shape[0], qp.n_decide
    qp.A[:, nz - m:] = 0.0
    qp.A[:, nz - m:, nz - m:] = np.eye(m)  # the held input: z[n:](i+1) = z[n:](i) + v(i)
    qp.B[:, nz - m:] = np.eye(m)
    qp.c[:, nz - m:] = 0.0
    k = (4 if du else 2) * m
    Fz, Fv, f = np.zeros((N, k, nz)), np.zeros((N, k, m)), np.full((N, k), np.inf)
    I = np.eye(m)
    Fv[:nd] = np.concatenate([I, -I, I, -I][:k // m])
    if incremental:
        Fz[:nd, :2 * m, nz - m:] = np.concatenate([I, -I])
    rng = np.random.default_rng(seed)
    f[:nd, :2 * m] = 0.4 + 0.2 * rng.random((nd, 2 * m))
    if du:
        f[:nd, 2 * m:] = 0.3 + 0.2 * rng.random((nd, 2 * m))
    f[1, 0] = np.inf
    return StageQP(qp.A, qp.B, qp.c, 0.1 * qp.z0, qp.Q, 5.0 * qp.q, qp.R, nd, Fz, Fv, f, np.zeros((N, k), bool))


@pytest.mark.parametrize("incremental", [False, True])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_active_set_of_a_random_problem_equals_a_dense_qp_from_any_start(seed, incremental):
    """Random input-row problems (absolute: torque and Δu boxes on v; incremental: torque rows on the
    held input plus v): cold, from a random set and from the optimal set shifted, the active set
    reaches the dense QP's plan (DAQP); KKT: rows held, λ ≥ 0 on the active rows, 0 elsewhere,
    complementarity, the Lagrangian's v-gradient (R v + Bᵀν + Fvᵀλ, ν from the costates) zero."""
    qp = _input_row_qp(seed, incremental, du=not incremental)
    rows = input_rows_of(qp)
    assert rows is not None
    v_ref, _ = _dense(qp)
    rng = np.random.default_rng(seed)
    cold = solve_active_set(qp, rows)
    nd, m = v_ref.shape
    guess = rng.integers(-1, qp.f.shape[1], (nd, m))  # rows of other components and unused rows among them
    for start in (None, guess, shift_active_set(cold.fixed)):
        # a random set is no warm start: it may need more sweeps than the warm cap (one per wrong row
        # once the cautious update takes over)
        sol = solve_active_set(qp, rows, start, max_iter=AS_MAX_ITER if start is guess else None)
        assert sol.status == "optimal", sol.message
        assert np.abs(sol.v - v_ref).max() <= 1e-9 * max(1.0, np.abs(v_ref).max())
        used = np.isfinite(qp.f)
        Fx = np.einsum("ikn,in->ik", qp.Fz, sol.z[:-1])
        Fx[:nd] += np.einsum("ikm,im->ik", qp.Fv[:nd], sol.v)
        assert np.all(Fx[used] <= qp.f[used] + 1e-12)
        assert np.all(sol.lam >= 0.0) and np.all(sol.lam[~used] == 0.0)
        assert np.all(np.abs(sol.lam * (Fx - np.where(used, qp.f, 0.0)))[used] <= 1e-10)
        nu, rv = costates(qp, sol.z, sol.v, sol.lam)
        assert np.abs(rv).max() <= 1e-10 * max(1.0, np.abs(sol.lam).max())
    assert (cold.fixed >= 0).sum() >= 3  # the rows bind


def test_two_rows_binding_one_component_are_left_to_the_interior_point():
    """Torque and Δu rows of the incremental form binding together on one component (here at stage 2:
    the held input then sits on a torque bound, a row on the state alone) are no set of one row per
    component: the active set reports it unconverged, the interior point solves it."""
    qp = _input_row_qp(0, True)
    sol = solve_active_set(qp, input_rows_of(qp))
    assert sol.status == "unconverged" and "active set" in sol.message
    v_ref, _ = _dense(qp)
    assert np.abs(solve_stage_qp(qp).v - v_ref).max() <= 1e-8 * np.abs(v_ref).max()


def test_rows_other_than_input_rows_are_not_the_active_sets():
    qp = _random_stage_qp(0)
    assert input_rows_of(qp) is None  # soft, dense rows
    qp = _input_row_qp(0, True)
    qp.Fv[2, 1, 0] = 0.5
    assert input_rows_of(qp) is None  # not a unit entry


def test_conflicting_torque_and_du_limits_fall_back_visibly():
    """|u(k−1)| beyond the torque limit plus the Δu limit: no plan holds both rows; the active set
    cycles between them, the interior point takes over and reports the problem infeasible."""
    robot = ParallelRobot.load("planar_4rrr")
    ctl = GPCController.build(ReducedModel(robot), TS, Horizons(6), Weights(1.0, 1e-3), form="incremental",
                              solver="riccati", limits=Limits(torque=1.0, du=0.1))
    ctl.u_prev = np.array([2.0, 0.0, 0.0, 0.0])
    X = np.concatenate([robot.home_pose, np.zeros(3)])
    path = ctl._riccati
    result = path.solve(*path.stages(ctl, X, np.tile(robot.home_pose, (6, 1))))
    assert path.constrained.method == "interior-point after active set"
    assert result.status == "infeasible"
    assert "active set" in result.message and "interior point" in result.message


HAS_COMPILED_ACTIVE = native_module() is not None and hasattr(native_module(), "stagewise_active")
if not HAS_COMPILED_ACTIVE and os.environ.get("CI"):
    raise RuntimeError("CI must test the compiled stage-wise active set (parallel_gpc._native.stagewise_active)")


@pytest.mark.skipif(not HAS_COMPILED_ACTIVE, reason="the compiled core has no stagewise_active")
@pytest.mark.parametrize("incremental", [False, True])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compiled_active_set_equals_the_python_reference(seed, incremental):
    """The same sweeps, sets, plan and multipliers (≤ 1e-9), cold and from a start; the cycling
    problem of two rows on one component is reported unconverged by both."""
    c = np.ascontiguousarray
    for qp, start_of in ((_input_row_qp(seed, incremental, du=not incremental), shift_active_set),
                         (_input_row_qp(0, True), None)):
        rows = input_rows_of(qp)
        cold = solve_active_set(qp, rows)
        for start in (None, None if start_of is None else start_of(cold.fixed)):
            py = solve_active_set(qp, rows, start)
            v, z, lam, fixed, iterations, ok, residual, message = native_module().stagewise_active(
                c(qp.A), c(qp.B), c(qp.c), c(qp.z0), c(qp.Q), c(qp.q), c(qp.R), qp.n_decide, c(qp.Fz), c(qp.f),
                c(rows.comp, np.int64), c(rows.sign), None if start is None else c(start, np.int64),
                AS_MAX_ITER if start is None else AS_WARM_MAX_ITER)
            assert ok is (py.status == "optimal") and iterations == py.iterations, (message, py.message)
            assert np.array_equal(fixed, py.fixed)
            if ok:
                assert np.abs(v - py.v).max() <= 1e-9 * max(1.0, np.abs(py.v).max())
                assert np.abs(z - py.z).max() <= 1e-9 * max(1.0, np.abs(py.z).max())
                assert np.abs(lam - py.lam).max() <= 1e-9 * max(1.0, np.abs(py.lam).max())
            else:
                assert message == py.message


@pytest.mark.skipif(not (HAS_COMPILED and HAS_COMPILED_ACTIVE), reason="the compiled core has no stage-wise solvers")
@pytest.mark.parametrize("case", list(INPUT_CASES))
@pytest.mark.parametrize("form", FORMS)
def test_compiled_active_set_path_equals_the_python_path(form, case):
    """The controller's input-row problems (planar_4rrr, No = 2, Nu = 5): compiled and Python paths
    take the same method and sweeps and give the same plan (≤ 1e-9)."""
    ctl, X, w = _setup(ParallelRobot.load("planar_4rrr"), form, case, N=15, No=2, Nu=5, cases=INPUT_CASES)
    stages = ctl._riccati.stages(ctl, X, w[ctl.horizons.No:])
    results, methods = [], []
    for native in (False, True):
        path = RiccatiPath(ctl._criterion, ctl.model.C, form, native=native, limits=ctl._qp_limits, Ts=TS)
        path._extra = ctl._riccati._extra
        results.append(path.solve(*stages))
        methods.append((path.constrained.method, path.constrained.iterations))
    assert methods[0] == methods[1]
    python, compiled = results
    assert python.status == compiled.status == "optimal"
    assert np.abs(compiled.v - python.v).max() <= 1e-9 * np.abs(python.v).max()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_interior_points_active_rows_settle_the_active_set_in_one_sweep(seed):
    """After a step the interior point took, its multipliers start the next step's set
    (active_set_of): on the same problem that set is the optimal one, verified by one sweep."""
    qp = _input_row_qp(seed, True, du=False)
    rows = input_rows_of(qp)
    start = active_set_of(qp, rows, solve_stage_qp(qp).lam)
    sol = solve_active_set(qp, rows, start)
    assert sol.status == "optimal" and sol.iterations == 1
    assert np.array_equal(sol.fixed, start) and (start >= 0).sum() >= 3


HAS_COMPILED_STEP = native_module() is not None and hasattr(native_module(), "RiccatiActive")
if not HAS_COMPILED_STEP and os.environ.get("CI"):
    raise RuntimeError("CI must test the compiled limited step (parallel_gpc._native.RiccatiActive)")


@pytest.mark.skipif(not (HAS_COMPILED_STEP and HAS_COMPILED), reason="the compiled core has no RiccatiActive")
@pytest.mark.parametrize("horizons", [dict(N=15), dict(N=15, No=2, Nu=5)], ids=["Nu=N", "No=2,Nu=5"])
@pytest.mark.parametrize("case", ["torque", "du", "torque+du"])
@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("name", ["planar_4rrr", "delta_3rus"])
def test_compiled_limited_step_equals_the_python_path_along_warm_steps(name, form, case, horizons):
    """The compiled limited step (``_native.RiccatiActive``: stage models, criterion, active set and J
    in one call; the nonlinear form's bounds passed each step) against the Python reference
    (stage_models, stage_problem, solve_active_set) over five warm-started steps at moving states:
    the same method and sweeps on every step, plans ≤ 1e-9 and J ≤ 1e-9 relative."""
    robot = ParallelRobot.load(name)
    ctl, X, w = _setup(robot, form, case, cases=INPUT_CASES, **horizons)
    paths = [RiccatiPath(ctl._criterion, ctl.model.C, form, native=native, limits=ctl._qp_limits, Ts=TS)
             for native in (False, True)]
    rng = np.random.default_rng(3)
    for k in range(5):
        stages = ctl._riccati.stages(ctl, X, w[ctl.horizons.No:])
        for path in paths:
            path._extra = ctl._riccati._extra  # y(k) (the rows' extra arguments) of these stages
        results = [path.solve(*stages, warm=k > 0) for path in paths]
        methods = [(path.constrained.method, path.constrained.iterations) for path in paths]
        if methods[0][0] == "active-set":
            assert methods[0] == methods[1]  # a set that settles: the same sweeps
        else:  # handed to the interior point: its iteration count may differ by rounding, not the answer
            assert methods[0][0] == methods[1][0], methods
        python, compiled = results
        assert python.status == compiled.status == "optimal", (python.message, compiled.message)
        assert np.abs(compiled.v - python.v).max() <= 1e-9 * np.abs(python.v).max()
        assert compiled.cost == pytest.approx(python.cost, rel=1e-9)
        X = X + np.concatenate([X[robot.n_y:] * TS, 0.02 * rng.standard_normal(robot.n_y)])
    assert paths[1].constrained._step is not None  # the compiled step, not the generic compiled active set


def test_nearly_saturated_warm_steps_settle_in_the_active_set():
    """planar_4rrr, absolute, N = 160, the torque limit at half the largest unconstrained |u(k)| along
    the path: ~99 % of the 640 inputs on a limit. The full (HIK) update of the set swings there without
    settling (20 of 24 steps went to the interior point); with the cautious update every warm step
    settles in the active set, its plan DAQP's on the condensed problem (≤ 1e-8) with a KKT residual
    (NNLS on the active rows) at the rounding floor."""
    robot = ParallelRobot.load("planar_4rrr")
    model = ReducedModel(robot)
    N, weights = 160, Weights(1.0, 1e-5)
    ref = path_for("auto", robot.home_pose, robot.output_angular, SCurve().duration)
    free = GPCController.build(model, TS, Horizons(N), weights, solver="riccati")
    plant = ConstrainedPlant(robot, ref.initial_state(), Ts=TS)
    states, u_max = [], 0.0
    for k in range(4):
        w = ref.window(k * TS, TS, N)
        states.append((plant.X.copy(), w))
        u = free.step(plant.X, w).u
        u_max = max(u_max, float(np.abs(u).max()))
        plant.step(u)
    limits = Limits(torque=0.5 * u_max)
    ric = GPCController.build(model, TS, Horizons(N), weights, solver="riccati", limits=limits)
    chk = GPCController.build(model, TS, Horizons(N), weights, solver="qr-first:bvls", limits=limits)
    for k, (X, w) in enumerate(states):
        full, x_daqp = condensed_of_state(chk, ric, X, w)
        info = ric.step(X, w)
        stagewise = ric._riccati.constrained
        assert info.result.ok, info.result.message
        if k:
            assert stagewise.method == "active-set", info.result.message
        v = ric._v_prev
        assert kkt_residual(full, v) <= 1e-9
        assert x_daqp is not None
        assert np.abs(v - x_daqp).max() <= 1e-8 * np.abs(x_daqp).max()
    assert (stagewise._fixed >= 0).mean() > 0.95


@pytest.mark.skipif(not (HAS_COMPILED_STEP and HAS_COMPILED), reason="the compiled core has no RiccatiActive")
def test_a_compiled_step_that_does_not_settle_goes_to_the_interior_point(monkeypatch):
    """A warm step whose set does not settle within the cap (here a cap of one sweep) is handed to the
    interior point (started cold, to its crossover; the active set then verifies the set its iterate
    names: more sweeps counted), visibly (method and message), and reaches DAQP's plan on the
    condensed problem."""
    import parallel_gpc.gpc.stagewise as stagewise_module

    robot = ParallelRobot.load("planar_4rrr")
    ctl, X, w = _setup(robot, "incremental", "torque", cases=INPUT_CASES)
    path = ctl._riccati
    first = path.solve(*path.stages(ctl, X, w), warm=False)
    assert first.status == "optimal" and path.constrained.method == "active-set"
    assert path.constrained._step is not None and path.constrained._last.s is None
    monkeypatch.setattr(stagewise_module, "AS_WARM_MAX_ITER", 1)
    X = X + np.concatenate([X[robot.n_y:] * TS, np.full(robot.n_y, 0.05)])
    result = path.solve(*path.stages(ctl, X, w), warm=True)
    assert path.constrained.method == "interior-point after active set"
    assert result.status == "optimal" and "solved by the interior point" in result.message
    assert path.constrained.iterations[0] > 1 and path.constrained.iterations[1] > 0
    full, x_ref = condensed(ctl, X, w)
    assert x_ref is not None
    v_ref = x_ref[:full.n_decision]
    assert np.abs(result.v - v_ref).max() <= 1e-8 * np.abs(v_ref).max()


def _row_excess(ctl: GPCController, stages: tuple, v) -> float:
    """The largest excess (N·m) of the plan v's torque and Δu rows over the QP's (tightened) limits,
    recomputed here from the inputs u = u_base + u_map v of the form's input map (the nonlinear form's
    every pre-simulated step), Δu(i) = u(i) − u(i−1) on the Nu decided steps from u(k−1) (the delayed
    form: from u(k), the input it holds)."""
    lim, m = ctl._qp_limits, ctl.n_u
    pred = ctl._riccati.input_map(ctl, stages)
    U = (pred.u_base + pred.u_map @ np.ravel(v)).reshape(-1, m)
    excess = [np.max(np.abs(U) - lim.torque)] if lim.torque is not None else []
    if lim.du is not None:
        first = ctl.u_prev if stages[4] is None else stages[4]
        excess.append(np.max(np.abs(np.diff(np.vstack([first, U]), axis=0)[:ctl.horizons.Nu]) - lim.du))
    return float(max(excess))


@pytest.mark.parametrize("native", [False, True], ids=["python", "compiled"])
@pytest.mark.parametrize("case", list(INPUT_CASES))
@pytest.mark.parametrize("form", FORMS)
def test_the_active_sets_verified_excess_keeps_the_true_limits(form, case, native):
    """What lets the controller skip its own first-move check of a limited stage-wise step: the active
    set's verified row excess (its KKT residual × the largest bound) bounds every row's excess
    recomputed here from the plan, is within the gap between the QP's tightened limits and the true
    ones on every warm step, and the controller's check (:func:`limit_violation`) then indeed finds
    nothing."""
    if native and not (HAS_COMPILED_STEP and HAS_COMPILED):
        pytest.skip("the compiled core has no RiccatiActive")
    robot = ParallelRobot.load("planar_4rrr")
    ctl, X, w = _setup(robot, form, case, cases=INPUT_CASES)
    path = RiccatiPath(ctl._criterion, ctl.model.C, form, native=native, limits=ctl._qp_limits, Ts=TS)
    gap = limit_gap(ctl._limits, ctl._qp_limits)
    assert 0.0 < gap < np.inf
    rng = np.random.default_rng(5)
    binding = 0
    for k in range(5):
        stages = ctl._riccati.stages(ctl, X, w)
        path._extra = ctl._riccati._extra
        result = path.solve(*stages, warm=k > 0)
        assert result.status == "optimal" and path.constrained.method == "active-set", result.message
        scale = float(np.max(np.abs(ctl._qp_limits.torque if ctl._qp_limits.torque is not None else ctl._qp_limits.du)))
        assert _row_excess(ctl, stages, result.v) <= path.excess + 1e-13 * scale
        assert path.excess <= gap  # certified: the controller does not check it again
        assert limit_violation(ctl._riccati.input_map(ctl, stages), result.v, form, ctl.u_prev, ctl._limits) == ""
        binding += result.active_limits
        X = X + np.concatenate([X[robot.n_y:] * TS, 0.02 * rng.standard_normal(robot.n_y)])
    assert binding  # the limits bind: the certificate is about rows that matter


@pytest.mark.skipif(not (HAS_COMPILED_STEP and HAS_COMPILED), reason="the compiled core has no RiccatiActive")
@pytest.mark.parametrize("case", list(INPUT_CASES))
@pytest.mark.parametrize("form", ["absolute", "incremental"])
def test_the_compiled_steps_residual_bounds_the_broken_rows(form, case):
    """The bound the certificate rests on, where rows are broken: one sweep of the compiled limited step
    from a cold start (the unconstrained plan: rows broken) reports a KKT residual whose product with the
    largest bound is at least the largest row excess recomputed here."""
    robot = ParallelRobot.load("planar_4rrr")
    ctl, X, w = _setup(robot, form, case, cases=INPUT_CASES)
    ctl.step(X, w)  # builds the compiled step
    sw = ctl._riccati.constrained
    assert sw._step is not None
    A, B, c, x0, u0, r = ctl._riccati.stages(ctl, X, w)
    n, m = ctl.n_x, ctl.n_u
    v, _, _, _, _, ok, residual, _ = sw._step.solve(
        np.asarray(A, float).reshape(-1, n), np.asarray(B, float).reshape(-1, m), np.asarray(c, float).reshape(-1),
        X, np.zeros(m) if u0 is None else u0, r, None, 1)
    excess = _row_excess(ctl, (A, B, c, x0, u0, r), v)
    assert excess > 0.0 and not ok  # one sweep leaves rows broken
    assert excess <= residual * sw._step.f_scale * (1.0 + 1e-12)


@pytest.mark.skipif(not (HAS_COMPILED_STEP and HAS_COMPILED), reason="the compiled core has no RiccatiActive")
@pytest.mark.parametrize("form", ["absolute", "incremental"])
def test_a_reused_compiled_step_answers_as_a_fresh_one(form):
    """The compiled limited step keeps its workspace from call to call (a controller's steps allocate
    nothing once the first has sized it); nothing it carries may leak into the next answer. One
    RiccatiActive through cold calls, warm ones from the last set, one-sweep calls that do not settle,
    and calls with and without c, at moving states, answers each as a freshly built one: the same set,
    sweeps and status, plan, multipliers and J ≤ 1e-12 relative."""
    robot = ParallelRobot.load("planar_4rrr")
    ctl, X, w = _setup(robot, form, "torque", cases=INPUT_CASES)
    ctl.step(X, w)  # builds the compiled step
    sw, H, n, m = ctl._riccati.constrained, ctl.horizons, ctl.n_x, ctl.n_u
    qp = sw._template[0]
    rows = sw._input_rows(qp)

    def fresh():
        return native_module().RiccatiActive(sw.C, sw.Wy, sw.Wu, H.N, H.No, H.Nu, FORM_CODES[form], qp.Fz, qp.f,
                                             np.ascontiguousarray(rows.comp, np.int64), rows.sign)

    reused, rng, last, unsettled, binding = fresh(), np.random.default_rng(11), None, 0, 0
    for k in range(4):
        A, B, c, x0, u0, r = ctl._riccati.stages(ctl, X, w)
        c = np.asarray(c, float).reshape(-1) + 1e-3 * rng.standard_normal(np.size(c))  # c ≠ 0 (a disturbance)
        args = [np.asarray(A, float).reshape(-1, n), np.asarray(B, float).reshape(-1, m), c, x0,
                np.zeros(m) if u0 is None else u0, r]
        no_c = args[:2] + [np.zeros(0)] + args[3:]
        for call_args, start, cap in [(args, None, 30), (args, last, 12), (args, None, 1), (no_c, last, 12)]:
            got, want = reused.solve(*call_args, start, cap), fresh().solve(*call_args, start, cap)
            v, J, lam, fixed, iterations, ok, residual, message = got
            assert (np.array_equal(fixed, want[3]), iterations, ok, message) == (True, *want[4:6], want[7])
            assert np.abs(v - want[0]).max() <= 1e-12 * np.abs(want[0]).max()
            assert np.abs(lam - want[2]).max() <= 1e-12 * max(np.abs(want[2]).max(), 1.0)
            assert J == pytest.approx(want[1], rel=1e-12) and residual == pytest.approx(want[6], rel=1e-9, abs=1e-15)
            unsettled += not ok
            binding += int((fixed >= 0).any())
            if ok and call_args is args:
                last = fixed
        X = X + np.concatenate([X[robot.n_y:] * TS, 0.02 * rng.standard_normal(robot.n_y)])
    assert unsettled and binding  # the calls cover sets that bind and sweeps that stop unsettled


@pytest.mark.skipif(not (HAS_COMPILED_STEP and HAS_COMPILED), reason="the compiled core has no RiccatiActive")
@pytest.mark.parametrize("form", ["absolute", "incremental"])
def test_the_compiled_step_takes_the_steps_arrays_as_they_are(form):
    """What the controller hands the compiled step unchanged answers as the flattened arrays it was
    given before: one model per stage as (N, n, n) / (N, n, m) / (N, n) or as (N·n, n) / (N·n, m) /
    (N·n,), another layout converted on the way in, c and u0 absent as zeros, a kept set (keep)
    shifted by a warm call as by shift_active_set, the plan, multipliers and set written into the
    caller's arrays: the same set, sweeps, plan, multipliers and J, bit for bit; the set's `active` and
    the bounds' `f_scale` as recomputed here. An array of another size is one clear error naming it
    and the shapes that are valid."""
    robot = ParallelRobot.load("planar_4rrr")
    ctl, X, w = _setup(robot, form, "torque", cases=INPUT_CASES)
    ctl.step(X, w)  # builds the compiled step
    sw, H, n, m = ctl._riccati.constrained, ctl.horizons, ctl.n_x, ctl.n_u
    step = sw._step
    Ad, Bd, _, _, _, r = ctl._riccati.stages(ctl, X, w)
    rng = np.random.default_rng(5)
    A = np.asarray(Ad, float) * (1.0 + 1e-3 * rng.standard_normal((H.N, n, n)))  # a model per stage
    B = np.asarray(Bd, float) * (1.0 + 1e-2 * rng.standard_normal((H.N, n, m)))
    c = 1e-3 * rng.standard_normal((H.N, n))
    flat = (A.reshape(-1, n), B.reshape(-1, m), c.reshape(-1), X, np.zeros(m), r)

    def same(got, want):
        assert np.array_equal(got[3], want[3]) and got[4:] == want[4:]
        for a, b in zip(got[:3], want[:3]):
            assert np.array_equal(a, b)

    cold = step.solve(*flat, None, AS_MAX_ITER)
    assert cold[5] and (cold[3] >= 0).any()  # settled, limits bind
    assert step.active == bool((cold[3] >= 0).any())
    assert step.f_scale == float(np.max(np.abs(sw._template[0].f[np.isfinite(sw._template[0].f)])))
    same(step.solve(A, B, c, X, None, r, None, AS_MAX_ITER), cold)
    same(step.solve(np.asfortranarray(A.reshape(-1, n)), np.asfortranarray(B), c, X, None, r, None, AS_MAX_ITER), cold)
    same(step.solve(*flat[:2], None, *flat[3:], None, AS_MAX_ITER), step.solve(*flat[:2], np.zeros(0), *flat[3:],
                                                                               None, AS_MAX_ITER))
    X2 = X + np.concatenate([X[robot.n_y:] * TS, np.full(robot.n_y, 0.02)])
    warm = (A, B, c, X2, None, r)
    step.keep(cold[3], False)
    same(step.solve(*warm, None, AS_WARM_MAX_ITER, warm=True),
         step.solve(*warm, shift_active_set(cold[3]), AS_WARM_MAX_ITER))
    for bad, name in [((A[:-1], B, c), "A"), ((A, B[..., :-1], c), "B"), ((A, B, c[:, :-1]), "c")]:
        with pytest.raises(ValueError, match=f"RiccatiActive.solve: {name} must be one model or one per stage.*got"):
            step.solve(*bad, X, None, r, None, AS_MAX_ITER)
    with pytest.raises(ValueError, match="warm starts from the kept set"):
        step.solve(*warm, cold[3], AS_WARM_MAX_ITER, warm=True)
    step.keep(None, False)
    with pytest.raises(ValueError, match="warm starts from the kept set"):
        step.solve(*warm, None, AS_WARM_MAX_ITER, warm=True)
    outs = (np.full((H.Nu, m), np.nan), np.full(sw._template[0].f.shape, np.nan), np.full((H.Nu, m), -7, np.int64))
    got = step.solve(*flat, None, AS_MAX_ITER, None, False, *outs)  # written into the caller's arrays
    same(got, cold)
    assert got[0] is outs[0] and got[2] is outs[1] and got[3] is outs[2]
    with pytest.raises(ValueError, match="go together"):
        step.solve(*flat, None, AS_MAX_ITER, v_out=outs[0])


@pytest.mark.parametrize("claimed", [np.inf, 1e3], ids=["unverified", "residual-too-large"])
def test_a_stagewise_plan_the_solver_did_not_verify_is_checked_by_the_controller(claimed, monkeypatch):
    """One verification, never none: a stage-wise plan whose first move breaks the torque limit and
    whose solver did not verify its rows within the limits' gap (an interior point's: inf; a residual
    too large) is caught by the controller's check and replaced by the condensed default, visibly."""
    robot = ParallelRobot.load("planar_4rrr")
    ctl, X, w = _setup(robot, "absolute", "torque", cases=INPUT_CASES)
    path = ctl._riccati
    solve = path.solve

    def beyond(*args, **kwargs):
        result = solve(*args, **kwargs)
        path.constrained.excess = claimed * ctl._limit_gap
        return replace(result, v=3.0 * result.v)  # the first move beyond ±τ

    monkeypatch.setattr(path, "solve", beyond)
    info = ctl.step(X, w)
    assert info.replaced and "torque limit" in info.result.message and info.result.ok
    assert np.all(np.abs(info.u) <= ctl._limits.torque)


@pytest.mark.skipif(not (HAS_COMPILED_STEP and HAS_COMPILED), reason="the compiled core has no RiccatiActive")
@pytest.mark.parametrize("horizons", [dict(N=12), dict(N=15, No=2, Nu=5)], ids=["Nu=N", "No=2,Nu=5"])
def test_a_compiled_nonlinear_step_given_new_bounds_answers_as_one_built_with_them(horizons):
    """The nonlinear form's bounds move with the pre-simulated inputs: RiccatiActive.solve takes each step's
    (input_bounds). A step built with the first state's bounds and given the next state's answers as one
    built with those (set, sweeps, plan, multipliers, J ≤ 1e-12 relative), and the bounds then stay; a
    used row given a non-finite bound is a clear error, not a silently dropped limit."""
    robot = ParallelRobot.load("planar_4rrr")
    ctl, X, w = _setup(robot, "nonlinear", "torque+du", cases=INPUT_CASES, **horizons)
    ctl.step(X, w)  # builds the compiled step
    sw, H, n, m = ctl._riccati.constrained, ctl.horizons, ctl.n_x, ctl.n_u
    qp = sw._template[0]
    rows = sw._input_rows(qp)

    def built(f):
        return native_module().RiccatiActive(sw.C, sw.Wy, sw.Wu, H.N, H.No, H.Nu, FORM_CODES["nonlinear"], qp.Fz, f,
                                             np.ascontiguousarray(rows.comp, np.int64), rows.sign)

    step = built(qp.f)
    X2 = X + np.concatenate([X[robot.n_y:] * TS, np.full(robot.n_y, 0.05)])
    A, B, _, _, _, r = ctl._riccati.stages(ctl, X2, w[H.No:])
    extra = ctl._riccati._extra
    f2 = sw._step_bounds(extra["u_sim"], extra["u_prev"])
    assert not np.allclose(f2[np.isfinite(f2)], qp.f[np.isfinite(qp.f)])  # the bounds did move
    args = (np.asarray(A, float).reshape(-1, n), np.asarray(B, float).reshape(-1, m), np.zeros(0), X2, np.zeros(m), r)
    for got in (step.solve(*args, None, 30, f2), step.solve(*args, None, 30)):  # then kept
        want = built(f2).solve(*args, None, 30)
        assert (np.array_equal(got[3], want[3]), got[4], got[5]) == (True, want[4], want[5]) and got[5]
        assert (got[3] >= 0).any()  # limits bind
        assert np.abs(got[0] - want[0]).max() <= 1e-12 * np.abs(want[0]).max()
        assert np.abs(got[2] - want[2]).max() <= 1e-12 * max(np.abs(want[2]).max(), 1.0)
        assert got[1] == pytest.approx(want[1], rel=1e-12)
    used = np.argwhere(rows.comp >= 0)[0]
    bad = f2.copy()
    bad[tuple(used)] = np.inf
    with pytest.raises(ValueError, match="not finite"):
        step.solve(*args, None, 30, bad)


@pytest.mark.skipif(not (HAS_COMPILED_STEP and HAS_COMPILED), reason="the compiled core has no RiccatiActive")
@pytest.mark.parametrize("with_c", [True, False], ids=["c", "no-c"])
def test_the_compiled_step_reads_per_stage_models_in_place(with_c):
    """The benchmark's LTV row: the absolute form (Nu = N: the stage models are the step's A_i, B_i, c_i,
    read in place) with a model per stage, warm-started over moving states: the compiled limited step
    gives the Python reference's sweeps and plan (≤ 1e-9), and a controller's own one-model step after
    it still its own answer (the stages re-read, nothing of the per-stage arrays kept)."""
    robot = ParallelRobot.load("planar_4rrr")
    ctl, X, w = _setup(robot, "absolute", "torque", cases=INPUT_CASES)
    H, n, m = ctl.horizons, ctl.n_x, ctl.n_u
    solvers = [StagewiseSolver(*ctl._criterion.weights.blocks(robot.n_y, m), ctl.model.C, H, "absolute",
                               ctl._qp_limits, TS, native=native) for native in (False, True)]
    rng = np.random.default_rng(13)
    for k in range(4):
        Ad, Bd, cd, base = ctl.linear_stages(X)
        A = Ad * (1.0 + 1e-3 * rng.standard_normal((H.N, n, n)))
        B = Bd * (1.0 + 1e-2 * rng.standard_normal((H.N, n, m)))
        c = (np.asarray(cd) + 1e-3 * rng.standard_normal((H.N, n))) if with_c else None
        results = [s.solve((A, B, c, X, None), w, ctl.model.C @ X, warm=k > 0)[0] for s in solvers]
        assert solvers[0].iterations == solvers[1].iterations and solvers[1].method == "active-set"
        python, compiled = results
        assert python.status == compiled.status == "optimal" and compiled.active_limits
        assert np.abs(compiled.v - python.v).max() <= 1e-9 * np.abs(python.v).max()
        X = X + np.concatenate([X[robot.n_y:] * TS, 0.02 * rng.standard_normal(robot.n_y)])
    assert solvers[1]._step is not None
    one = [s.solve((Ad, Bd, cd, X, None), w, ctl.model.C @ X)[0] for s in solvers]  # one model for every stage
    assert np.abs(one[1].v - one[0].v).max() <= 1e-9 * np.abs(one[0].v).max()


def test_shift_active_set_moves_again_the_edges_that_moved():
    """With the set of the step before, an edge that moved between the two steps (a run of stages
    changed to one value, next to stages that held it in both) moves again by the run's length in
    the same direction, only over stages holding what lay beyond it; other changes (a hole filled)
    are shifted and left; without it, the plain shift."""
    nd = 10
    before = np.full((nd, 3), -1)
    fixed = np.full((nd, 3), -1)
    before[7:, 0], fixed[4:, 0] = 3, 3  # an arc of row 3 starting at 6 once shifted, now at 4: grew earlier by 2
    before[:, 1], fixed[:, 1] = 5, 5
    before[:4, 1], fixed[:4, 1] = -1, -1  # the free stretch 0..2 once shifted, now 0..3: grew later by 1
    before[:, 2], fixed[:, 2] = 2, 2
    before[4:6, 2] = -1  # a hole at 3..4 once shifted, filled: an edge on neither side
    shifted = shift_active_set(fixed)
    np.testing.assert_array_equal(shifted, np.concatenate([fixed[1:], fixed[-1:]]))
    moved = shift_active_set(fixed, before)
    expected = shifted.copy()
    expected[1:3, 0] = 3  # the arc (at 3.. once shifted) starts 2 stages earlier again
    expected[3, 1] = -1  # the free stretch (0..2 once shifted) one stage longer again
    np.testing.assert_array_equal(moved, expected)
    other = fixed.copy()
    other[2, 0] = 7  # another value (stage 1 once shifted) on the arc's next move: the move stops there
    before_other = before.copy()
    before_other[3, 0] = 7
    expected_other = shift_active_set(other)
    expected_other[2, 0], expected_other[3, 1] = 3, -1
    np.testing.assert_array_equal(shift_active_set(other, before_other), expected_other)


def test_incremental_warm_steps_move_the_edges_and_keep_the_plan(monkeypatch):
    """planar_4rrr, incremental, N = 40, the torque limit at half the largest unconstrained |u| along
    the path: the held input reaches its limit earlier from step to step. Starting each step from the
    last one's moved edges, the warm steps take fewer sweeps in all than from the plain shift, and the
    plans are the same to 1e-8 (both sets' KKT conditions verified, to AS_ACCEPT: one optimum).
    From the states of an unlimited closed loop (absolute, the default solver), as in
    ``benchmarks/bench_riccati.py --limited``."""
    import parallel_gpc.gpc.stagewise as stagewise_module

    robot = ParallelRobot.load("planar_4rrr")
    model = ReducedModel(robot)
    N, weights = 40, Weights(1.0, 1e-5)
    ref = path_for("auto", robot.home_pose, robot.output_angular, SCurve().duration)
    states = closed_loop_states(robot, model, ref, N, weights, TS)
    free = GPCController.build(model, TS, Horizons(N), weights, form="incremental", solver="riccati")
    limits = Limits(torque=0.5 * max(float(np.abs(free.step(X, w).u).max()) for X, w in states))

    def run():
        ctl = GPCController.build(model, TS, Horizons(N), weights, form="incremental", solver="riccati",
                                  limits=limits)
        plans, sweeps = [], 0
        for k, (X, w) in enumerate(states):
            info = ctl.step(X, w)
            assert info.result.ok and ctl._riccati.constrained.method == "active-set", info.result.message
            plans.append(ctl.plan.copy())
            sweeps += ctl._riccati.constrained.iterations[0] if k else 0
        return np.array(plans), sweeps

    moved, moved_sweeps = run()
    monkeypatch.setattr(stagewise_module, "EDGE_FORMS", ())
    plain, plain_sweeps = run()
    assert moved_sweeps < plain_sweeps
    assert np.abs(moved - plain).max() <= 1e-8 * np.abs(plain).max()
