"""The nonlinear form iterated to the NMPC optimum (gpc/nmpc.py): the paper's step unchanged at
iterations=1, the converged plan against CasADi + IPOPT on the same discrete problem (an
independent formulation and Jacobian, tests/nmpc_oracle.py), limits inside every iteration, the
time budget and the settings' checks."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

import mechanisms as mech
from parallel_gpc import ControllerState, GPCController, GPCSettings, Horizons, ParallelRobot, ReducedModel, Weights
from parallel_gpc.errors import InvalidParameterError
from parallel_gpc.gpc import settings as settings_module
from parallel_gpc.gpc.controller import LIMIT_MARGIN
from parallel_gpc.limits import Limits

TS = 0.002
QY, QU = 1.0, 1e-3


def _case(name):
    """(model, X, previous plan, reference rows) of a strongly nonlinear step: moving fast, the
    reference off the current pose."""
    robot = ParallelRobot.load(name)
    model = ReducedModel(robot)
    if name == "planar_4rrr":
        X = np.array([0.5, 0.4, 0.1, 0.8, -0.5, 1.0])
        plan = np.tile([1.0, -1.0, 0.5, 0.2], (20, 1))
        target = np.array([0.51, 0.39, 0.12])
    else:  # delta_3rus near its home, fast
        X = np.concatenate([robot.home_pose + [0.02, -0.01, 0.03], [0.4, -0.3, 0.5]])
        plan = np.tile([0.5, -0.3, 0.2], (20, 1))
        target = robot.home_pose + [0.03, -0.02, 0.035]
    return model, X, plan, target


def _step(model, X, plan, target, N, iterations, limits=Limits(), tolerance=1e-12, **kw):
    ctrl = GPCController.build(model, TS, Horizons(N), Weights(QY, QU), form="nonlinear", iterations=iterations,
                               tolerance=tolerance, limits=limits, disturbance_gain=0.0, **kw)
    ctrl.restore(ControllerState(plan[0], plan[:N], np.zeros(model.n_x)))
    return ctrl, ctrl.step(X, np.tile(target, (N, 1)))


def _true_cost(model, X, u0, v, target, N, qf=1.0):
    """J(v) of the discrete problem, rolled out step by step with the model's discrete map (the last
    output weighed qf·Qy)."""
    m = model.n_u
    u = u0 + np.cumsum(v.reshape(N, m), axis=0)
    J, x = float(QU ** 2 * v @ v), X
    for i in range(N):
        Ad, Bd, cd = model.discrete(x, TS)
        x = Ad @ x + Bd @ u[i] + cd
        J += float(np.sum(((qf if i == N - 1 else 1.0) * QY * (x[:model.n_y] - target)) ** 2))
    return J


def test_one_iteration_is_the_papers_step_bit_for_bit(robot4):
    model, X, plan, target = _case("planar_4rrr")
    _, paper = _step(ReducedModel(robot4), X, plan, target, 10, 1)
    ctrl = GPCController.build(ReducedModel(robot4), TS, Horizons(10), Weights(QY, QU), form="nonlinear",
                               disturbance_gain=0.0)  # the settings without the new fields
    ctrl.restore(ControllerState(plan[0], plan[:10], np.zeros(6)))
    today = ctrl.step(X, np.tile(target, (10, 1)))
    assert np.array_equal(paper.u, today.u) and np.array_equal(paper.result.v, today.result.v)
    assert paper.iterations == 1 and math.isnan(paper.residual) and not paper.budget_hit


def test_iterations_decrease_the_true_cost_to_a_stationary_point(robot4):
    model, X, plan, target = _case("planar_4rrr")
    N = 10
    u0 = np.vstack([plan[1:N], plan[N - 1:N]])
    costs, plans = [], []
    for it in (1, 2, 3, 50):
        _, info = _step(model, X, plan, target, N, it)
        costs.append(_true_cost(model, X, u0, info.result.v, target, N))
        plans.append(info.result.v)
        assert info.iterations <= it
    assert all(b <= a * (1 + 1e-12) for a, b in zip(costs, costs[1:]))
    assert costs[0] > costs[-1]  # the paper's single step is not the optimum here
    assert np.abs(plans[0] - plans[-1]).max() > 1e-4 * np.abs(plans[-1]).max()
    assert np.abs(plans[2] - plans[-1]).max() < np.abs(plans[0] - plans[-1]).max() / 10
    # converged by the step rule, or by a line search whose model decrease is below rounding
    # (1e-12 J: a step of ~1e-7 relative); the gradient below is the oracle of stationarity
    assert info.residual <= 1e-6 and info.result.cost == pytest.approx(costs[-1], rel=1e-9)
    # stationary: the gradient of the true cost (central differences of the rollout) vanishes
    v = info.result.v
    g = np.empty_like(v)
    for k in range(len(v)):
        e = np.zeros_like(v)
        e[k] = 1e-3
        g[k] = (_true_cost(model, X, u0, v + e, target, N) - _true_cost(model, X, u0, v - e, target, N)) / 2e-3
    g0 = abs(costs[0] - _true_cost(model, X, u0, np.zeros_like(v), target, N)) / max(np.abs(v).max(), 1e-12)
    assert np.abs(g).max() <= 1e-6 * max(g0, costs[-1])


def test_a_step_below_rounding_is_not_tried_shorter(robot4, monkeypatch):
    """A Gauss–Newton step whose model decrease is below rounding (tolerance 1e-12: the steps reach
    it) gets one trial, the full step: rejected, the iterations stop converged (J flat) without the
    halvings, each of which only measures rounding (before: 12 more rollouts of the same J)."""
    model, X, plan, target = _case("planar_4rrr")
    N = 10
    ctrl = GPCController.build(model, TS, Horizons(N), Weights(QY, QU), form="nonlinear", iterations=50,
                               tolerance=1e-12, disturbance_gain=0.0)
    ctrl.restore(ControllerState(plan[0], plan[:N], np.zeros(model.n_x)))
    rollouts, costs, rollout = [], [], ctrl._nmpc._rollout

    def counted(*args, **kw):
        out = rollout(*args, **kw)
        rollouts.append(args[4].copy())
        costs.append(out[3])
        return out
    monkeypatch.setattr(ctrl._nmpc, "_rollout", counted)
    info = ctrl.step(X, np.tile(target, (N, 1)))
    assert info.iterations > 2 and info.residual > 1e-12  # stopped by the flat line search, not the step rule
    assert info.residual <= 1e-6
    assert len(rollouts) == info.iterations  # one trial per line search: the last one's full step, rejected
    assert costs[-1] == pytest.approx(info.result.cost, rel=1e-10)  # the rejected trial's J is J(v) to rounding


def test_a_terminal_weight_enters_the_true_cost(robot4):
    """Qf weighs the last output in the cost the line search measures and the step reports, as in
    every Gauss–Newton subproblem: the converged plan's cost is the rolled-out J with it."""
    model, X, plan, target = _case("planar_4rrr")
    N, qf = 10, 3.0
    ctrl = GPCController.build(model, TS, Horizons(N), Weights(QY, QU, Qf=qf), form="nonlinear", iterations=50,
                               tolerance=1e-10, disturbance_gain=0.0)
    ctrl.restore(ControllerState(plan[0], plan[:N], np.zeros(model.n_x)))
    info = ctrl.step(X, np.tile(target, (N, 1)))
    u0 = np.vstack([plan[1:N], plan[N - 1:N]])
    J = _true_cost(model, X, u0, info.result.v, target, N, qf)
    assert info.residual <= 1e-6 and info.result.cost == pytest.approx(J, rel=1e-9)
    assert J > _true_cost(model, X, u0, info.result.v, target, N) * (1 + 1e-3)  # the weight matters here


def test_state_jacobians_match_a_finer_difference(robot4):
    model, X, plan, _ = _case("planar_4rrr")
    u = plan[:3]
    traj = model.simulate_factorized(X, u, TS)[3]
    J = model.stage_jacobians(traj, u, TS)
    Ad = model.simulate_factorized(X, u, TS)[0]
    for i in range(3):
        fine = np.empty((6, 6))
        for k in range(6):
            e = np.zeros(6)
            e[k] = 1e-3
            f = lambda x: (lambda A, B, c: A @ x + B @ u[i] + c)(*model.discrete(x, TS))  # noqa: E731
            x = traj[i]
            fine[:, k] = (-f(x + 2 * e) + 8 * f(x + e) - 8 * f(x - e) + f(x - 2 * e)) / 12e-3
        assert np.abs(J[i] - fine).max() <= 1e-8
        assert np.abs(J[i] - Ad[i]).max() > 1e-6  # the frozen A_d is not the Jacobian


def _moving(name):
    """(model, trajectory (6, n_x), inputs (5, n_u)) of a fast move: planar_4rrr and delta_3rus from
    _case, the hexapod (prismatic legs) from its home at 0.3 m/s, 0.5 rad/s."""
    if name == "hexapod_6ups":
        robot = ParallelRobot.load(name)
        model = ReducedModel(robot)
        X = np.concatenate([robot.home_pose, [0.3, -0.2, 0.1, 0.5, -0.3, 0.2]])
        u = np.tile(np.linspace(-20.0, 20.0, model.n_u), (5, 1))
    else:
        model, X, plan, _ = _case(name)
        u = plan[:5]
    return model, model.simulate_factorized(X, u, TS)[3], u


@pytest.mark.parametrize("native", [None, False])
@pytest.mark.parametrize("name", ["planar_4rrr", "delta_3rus", "hexapod_6ups"])
def test_stage_jacobians_equal_central_differences_of_the_stage_map(name, native):
    """The Fréchet-derivative Jacobian (exact ẏ part, y part by differences of the factor rows) against
    central differences of the whole stage map Φ = A_d X + B_d u + c_d (2·n_x discrete() per stage),
    compiled and Python model updates, revolute (planar, Delta) and prismatic (hexapod) legs."""
    model, traj, u = _moving(name)
    mech.assert_stage_jacobians_match_differences(ReducedModel(model.robot, native=native), traj, u, TS, 5)


@pytest.mark.parametrize("native", [None, False])
def test_stage_jacobians_of_a_light_robot_through_the_squarings(native):
    """planar_4rrr with its masses scaled by 1e-4 (light links: ‖Ts·[A B c]‖ ≈ 43, seven squarings of the ZOH
    exponential, so the Fréchet derivative goes through the squarings, discretization.frechet_by_squaring; along
    the vector it took 2^7 − 1 derivative actions a stage) against central differences of the stage map."""
    from parallel_gpc.model.discretization import frechet_by_squaring

    robot = ParallelRobot.load("planar_4rrr").with_mass_scale(1e-4)
    model = ReducedModel(robot, native=native)
    X = np.array([0.5, 0.4, 0.1, 0.08, -0.05, 0.1])
    u = 1e-4 * np.tile([1.0, -1.0, 0.5, 0.2], (5, 1))
    traj = model.simulate_factorized(X, u, TS)[3]
    A, B, c = model.factorize(traj[2])
    M_top = TS * np.hstack([A, B, c[:, None]])  # the top rows of the ZOH matrix
    s = int(np.ceil(np.log2(np.linalg.norm(M_top) / 0.5)))
    assert s >= 4 and frechet_by_squaring(s, 11)
    mech.assert_stage_jacobians_match_differences(model, traj, u, TS, 5)


@pytest.mark.parametrize("name", ["planar_4rrr", "delta_3rus", "hexapod_6ups"])
def test_compiled_stage_jacobians_equal_the_python_reference(name):
    """The compiled Jacobian (one native call) against the Python loop of
    ReducedModel.stage_jacobians on the Python model update, along a moving trajectory."""
    from parallel_gpc.model.native import native_module
    if not hasattr(native_module(), "stage_jacobians"):
        pytest.skip("the compiled core has no stage_jacobians (PARALLEL_GPC_NATIVE=0 or an older build)")
    model, traj, u = _moving(name)
    reference = ReducedModel(model.robot, native=False)
    J = model.stage_jacobians(traj, u, TS)
    J_ref = reference.stage_jacobians(traj, u, TS)
    assert J.shape == J_ref.shape == (5, model.n_x, model.n_x)
    assert np.abs(J - J_ref).max() <= 1e-8 * np.abs(J_ref).max()  # differences of two rounding paths


def test_compiled_stage_jacobians_reuse_the_presimulations_factorization(robot4):
    """Along the last pre-simulation the compiled Jacobian takes each state's factorization from it;
    a model without that pre-simulation (every state assembled anew) gives the same Jacobians."""
    from parallel_gpc.model.native import native_module
    if not hasattr(native_module(), "stage_jacobians"):
        pytest.skip("the compiled core has no stage_jacobians (PARALLEL_GPC_NATIVE=0 or an older build)")
    model, traj, u = _moving("planar_4rrr")
    reused = model.stage_jacobians(traj, u, TS)
    fresh = ReducedModel(robot4).stage_jacobians(traj, u, TS)
    assert np.abs(reused - fresh).max() <= 1e-8 * np.abs(fresh).max()


@pytest.mark.parametrize("native", [None, False])
def test_stage_jacobians_from_a_later_stage_are_those_stages(native, robot4):
    """start = 1 (the iterations skip the fixed initial state's stage) gives the same Jacobians as
    the stages 1.. of the full call; a start beyond the stages is refused."""
    model, traj, u = _moving("planar_4rrr")
    model = ReducedModel(robot4, native=native)
    traj = model.simulate_factorized(traj[0], u, TS)[3]  # with the warm starts of its own states
    full = model.stage_jacobians(traj, u, TS)
    later = model.stage_jacobians(traj, u, TS, start=1)
    assert later.shape == (4, 6, 6)
    assert np.abs(later - full[1:]).max() <= 1e-12 * np.abs(full).max()
    assert model.stage_jacobians(traj, u, TS, start=5).shape == (0, 6, 6)
    with pytest.raises(InvalidParameterError, match=r"start = 6 .*valid: 0\.\.5"):
        model.stage_jacobians(traj, u, TS, start=6)



@pytest.mark.parametrize("native", [None, False])
@pytest.mark.parametrize("name", ["planar_4rrr", "delta_3rus"])
def test_a_line_search_rollout_warm_started_at_the_same_stages_is_a_fresh_simulation(name, native):
    """The rollouts of one step start where the last simulation did and visit nearly its states at
    the same index (not one later, as the next step's pre-simulation does): warm-started there, a
    trial's trajectory and stage maps equal those of a model without warm starts."""
    model, X, plan, _ = _case(name)
    model = ReducedModel(model.robot, native=native)
    rng = np.random.default_rng(3)
    model.simulate_factorized(X, plan, TS)  # the pre-simulation
    for scale in (1e-3, 1e-1):  # a short and a long trial step of the line search
        trial = plan + scale * rng.standard_normal(plan.shape)
        got = model.simulate_factorized(X, trial, TS)
        fresh = ReducedModel(model.robot, native=native).simulate_factorized(X, trial, TS)
        for a, b in zip(got, fresh):
            assert np.abs(a - b).max() <= 1e-10 * max(1.0, np.abs(b).max())

@pytest.mark.parametrize("name,limits", [
    ("planar_4rrr", None),
    ("planar_4rrr", "torque"),
    ("planar_4rrr", "du"),
    ("delta_3rus", None),
    ("delta_3rus", "torque"),
])
def test_converged_plan_equals_ipopts(name, limits):
    pytest.importorskip("casadi")
    from nmpc_oracle import ipopt_plan

    model, X, plan, target = _case(name)
    N = 10
    u0 = np.vstack([plan[1:N], plan[N - 1:N]])
    # limits that bind on this step (found from the unconstrained optimum)
    _, free = _step(model, X, plan, target, N, 50)
    u_free = u0 + np.cumsum(free.result.v.reshape(N, -1), axis=0)
    lim = Limits()
    if limits == "torque":
        lim = Limits(torque=0.8 * np.abs(u_free).max())
    elif limits == "du":
        lim = Limits(du=0.5 * np.abs(np.diff(np.vstack([plan[:1], u_free]), axis=0)).max())
    _, info = _step(model, X, plan, target, N, 50, limits=lim)
    tight = lim.for_drives(model.n_u).scaled(1.0 - LIMIT_MARGIN)
    v, J, status, _ = ipopt_plan(model, TS, X, u0, np.tile(target, (N, 1)), QY, QU, N,
                              torque=tight.torque, du=tight.du, u_prev=plan[0])
    assert status == "Solve_Succeeded"
    assert info.result.active_limits == (limits is not None)
    assert np.abs(info.result.v - v).max() <= 1e-6 * np.abs(v).max()
    assert info.result.cost == pytest.approx(J, rel=1e-9)
    assert info.residual <= 1e-6 and not info.fallback  # the QP back end's own tolerance


@pytest.mark.parametrize("soft", [False, True])
def test_converged_plan_with_an_active_output_box_equals_ipopts(soft):
    """The output box rebuilt along every iteration's trajectory: the converged plan is IPOPT's
    with the box on the nonlinear outputs (hard; soft with its slack and exact penalty)."""
    pytest.importorskip("casadi")
    from nmpc_oracle import ipopt_plan

    model, X, plan, target = _case("planar_4rrr")
    N = 10
    u0 = np.vstack([plan[1:N], plan[N - 1:N]])
    _, free = _step(model, X, plan, target, N, 50)
    x_free = model.simulate_factorized(X, u0 + np.cumsum(free.result.v.reshape(N, -1), axis=0), TS)[3][1:, 0]
    hi = X[0] + 0.5 * (x_free.max() - X[0])  # cuts the free motion of x in half
    box = np.array([[-np.inf, hi], [-np.inf, np.inf], [-np.inf, np.inf]])
    penalty = 1.0  # soft: small enough that the slack is used
    lim = Limits(output_box=box, soft=("output_box",) if soft else (), penalty=penalty)
    _, info = _step(model, X, plan, target, N, 50, limits=lim)
    v, J, status, _ = ipopt_plan(model, TS, X, u0, np.tile(target, (N, 1)), QY, QU, N, output_box=box,
                                 box_penalty=penalty if soft else None, tol=1e-10)
    assert status == "Solve_Succeeded"
    assert np.abs(info.result.v - v).max() <= 1e-6 * np.abs(v).max()
    assert info.result.cost == pytest.approx(J, rel=1e-8)
    assert info.residual <= 1e-6 and not info.fallback and info.iterations > 1
    assert info.constraints.active == ("output_box",)
    x = model.simulate_factorized(X, u0 + np.cumsum(info.result.v.reshape(N, -1), axis=0), TS)[3][1:, 0]
    if soft:  # the box is broken by the slack the report gives, the paper's single step differs
        assert info.constraints.slack["output_box"] == pytest.approx(x.max() - hi, rel=1e-6) and x.max() > hi + 1e-4
    else:  # held on the nonlinear trajectory, touched
        assert x.max() <= hi + 1e-9 and x.max() >= hi - 1e-9
    _, paper = _step(model, X, plan, target, N, 1, limits=lim)
    assert np.abs(paper.result.v - v).max() > 1e-4 * np.abs(v).max()


@pytest.mark.parametrize("soft", [(), ("drive_position",)])
def test_drive_position_limit_holds_on_the_nonlinear_trajectory(soft):
    """A drive range rebuilt along every iteration (linearized at each plan's poses): the
    converged plan keeps it on the drive positions of its nonlinear trajectory (assembled
    independently), touching it."""
    from parallel_gpc.gpc.constraints import DriveKinematics

    model, X, plan, target = _case("planar_4rrr")
    N = 10
    u0 = np.vstack([plan[1:N], plan[N - 1:N]])
    drives = DriveKinematics(model.robot)

    def drive_positions(v):
        Y = model.simulate_factorized(X, u0 + np.cumsum(v.reshape(N, -1), axis=0), TS)[3][1:, :model.n_y]
        return np.array([drives(y)[0] for y in Y])

    _, free = _step(model, X, plan, target, N, 50)
    q0, q = drives(X[:model.n_y])[0], drive_positions(free.result.v)
    j = int(np.argmax(np.abs(q - q0).max(axis=0)))  # the drive that moves most
    moved = q[:, j] - q0[j]
    bounds = np.tile([-np.inf, np.inf], (model.n_u, 1))
    side = 1 if moved.max() > -moved.min() else 0
    bounds[j, side] = q0[j] + 0.5 * (moved.max() if side else moved.min())
    _, info = _step(model, X, plan, target, N, 50, limits=Limits(drive_position=bounds, soft=soft), tolerance=1e-8)
    assert info.residual <= 1e-6 and not info.fallback and info.iterations > 1
    assert info.constraints.active == ("drive_position",) and info.constraints.max_slack <= 1e-9
    qj = drive_positions(info.result.v)[:, j]
    reach = qj.max() if side else -qj.min()
    assert reach == pytest.approx(bounds[j, side] if side else -bounds[j, side], abs=1e-9)


def test_time_budget_stops_and_says_so(robot4):
    model, X, plan, target = _case("planar_4rrr")
    _, info = _step(model, X, plan, target, 10, 50, time_budget=1e-6)
    assert info.budget_hit and info.iterations == 1 and not info.fallback  # the paper's step, applied
    _, info = _step(model, X, plan, target, 10, 50, time_budget=60.0)
    # converged: the stop is rounding-limited near 1e-8 at tolerance 1e-12 (measured 1e-9 to 4e-8)
    assert not info.budget_hit and 1 < info.iterations < 50 and info.residual <= 1e-6


@pytest.mark.parametrize("kw,word", [
    (dict(iterations=0), "iterations"), (dict(iterations=2.0), "iterations"), (dict(iterations=True), "iterations"),
    (dict(iterations=3, form="incremental"), "nonlinear"), (dict(iterations=3, solver="riccati"), "riccati"),
    (dict(tolerance=0.0), "tolerance"), (dict(time_budget=-1.0), "time_budget"),
])
def test_bad_iteration_settings_are_refused(kw, word):
    kw = {"form": "nonlinear", **kw}
    with pytest.raises(InvalidParameterError, match=word):
        GPCSettings(TS, Horizons(10), **kw)


class _Fenced:
    """The reduced model whose simulation fails beyond an input bound (a plan leaving the domain)."""

    def __init__(self, model, bound):
        self._model, self.bound = model, bound

    def __getattr__(self, name):
        return getattr(self._model, name)

    def simulate_factorized(self, X0, u_seq, Ts, offset=None):
        from parallel_gpc.errors import UnreachablePoseError
        if np.abs(u_seq).max() > self.bound:
            raise UnreachablePoseError(f"inputs beyond {self.bound} N·m")
        return self._model.simulate_factorized(X0, u_seq, Ts, offset)

    def simulate_linearized(self, X0, u_seq, Ts, offset=None, start=0):
        traj = self.simulate_factorized(X0, u_seq, Ts, offset)  # the fence first, as the fused call's rollout
        return *traj, self._model.stage_jacobians(traj[3], u_seq, Ts, start=start)


def test_a_trial_beyond_the_models_domain_shortens_the_step(robot4):
    model, X, plan, target = _case("planar_4rrr")
    _, paper = _step(model, X, plan, target, 10, 1)
    u0 = np.vstack([plan[1:10], plan[9:10]])
    peak = np.abs(u0 + np.cumsum(paper.result.v.reshape(10, -1), axis=0)).max()
    bound = 0.5 * (peak + np.abs(u0).max())  # the paper's full step goes beyond it, v = 0 stays within
    assert peak > bound
    _, info = _step(_Fenced(model, bound), X, plan, target, 10, 5)
    u = u0 + np.cumsum(info.result.v.reshape(10, -1), axis=0)
    assert np.abs(u).max() <= bound and not info.fallback and info.iterations >= 1


@pytest.fixture
def compiled_stagewise(monkeypatch):
    """The rule with the compiled recursion present, also under PARALLEL_GPC_NATIVE=0 (the steps then
    run the Python reference recursion):
    :func:`test_without_the_compiled_core_the_steps_go_to_the_condensed_back_end` covers its absence."""
    monkeypatch.setattr(settings_module, "stagewise_compiled", lambda limited: True)


def _between_converged(a, b) -> float:
    """The largest difference (N·m) two converged plans a, b (StepInfo) of one problem may show: each is within its
    last Gauss–Newton step, residual·(1 + ‖v‖∞), of the optimum (a rounding-limited stop ends above the
    tolerance), plus 1e-8 relative for the two solvers' rounding (issue 23's agreement with the condensed problem).
    Measured: delta_3rus 5.2e-9 relative with residuals ~1e-12; Nu < N, No > 0 1.1e-7 with residuals 3.7e-8."""
    scale = float(np.abs(b.result.v).max())
    return (a.residual + b.residual) * (1.0 + scale) + 1e-8 * scale


@pytest.mark.parametrize("name", ["planar_4rrr", "delta_3rus"])
def test_riccati_steps_converge_to_the_condensed_back_ends_plan(name, compiled_stagewise):
    """The steps by the Riccati recursion (the default without state limits, Qu nonsingular: the
    paper's and the exact ones) and by the condensed QR back end (an explicit solver) reach the
    same plan."""
    model, X, plan, target = _case(name)
    ctrl, fast = _step(model, X, plan, target, 10, 50, tolerance=1e-10)
    _, condensed = _step(ReducedModel(model.robot), X, plan, target, 10, 50, tolerance=1e-10, solver="qr")
    assert ctrl._nmpc.riccati is not None and fast.result.solver == "riccati" and condensed.result.solver == "qr"
    assert ctrl.solver == ctrl.settings.step_solver == "riccati"  # what the steps report, not the condensed back end
    assert ctrl.settings.solver != "riccati"  # the condensed back end of a limit-breaking minimizer
    assert fast.residual <= 1e-6 and condensed.residual <= 1e-6 and not fast.fallback  # (rounding-limited stop)
    np.testing.assert_allclose(fast.result.v, condensed.result.v, rtol=0, atol=_between_converged(fast, condensed))
    np.testing.assert_allclose(fast.u, condensed.u, rtol=0, atol=_between_converged(fast, condensed))


def _limited_case(kind):
    """(model, X, plan, target, limits) of the planar step with a torque or Δu limit that binds at
    the unconstrained optimum (80 % of its peak torque, half its largest increment)."""
    model, X, plan, target = _case("planar_4rrr")
    _, free = _step(model, X, plan, target, 10, 50)
    u_free = np.vstack([plan[1:10], plan[9:10]]) + np.cumsum(free.result.v.reshape(10, -1), axis=0)
    if kind == "torque":
        return model, X, plan, target, Limits(torque=0.8 * np.abs(u_free).max())
    return model, X, plan, target, Limits(du=0.5 * np.abs(np.diff(np.vstack([plan[:1], u_free]), axis=0)).max())


def _kkt_residual(model, X, plan, target, limits, v, N=10, h=1e-3):
    """The KKT conditions of the limited discrete problem (the module docstring of gpc/nmpc.py) at v,
    computed here: ∇J by central differences of the model's rollout, the multipliers of the active
    torque/Δu rows by NNLS (λ ≥ 0). Returns (‖∇J + Lᵀλ‖∞ / ‖∇J‖∞, the rows' largest excess (N·m),
    number of active rows)."""
    from scipy.optimize import nnls

    m = model.n_u
    u0 = np.vstack([plan[1:N], plan[N - 1:N]])
    tight = limits.for_drives(m).scaled(1.0 - LIMIT_MARGIN)
    w = np.tile(target, (N, 1))

    def outputs(vv):
        u = u0 + np.cumsum(vv.reshape(N, m), axis=0)
        return model.simulate_factorized(X, u, TS)[3][1:] @ model.C.T

    y = outputs(v)
    jac = np.empty((y.size, v.size))
    for k in range(v.size):
        e = np.zeros_like(v)
        e[k] = h
        jac[:, k] = (outputs(v + e) - outputs(v - e)).reshape(-1) / (2 * h)
    grad = 2.0 * QY ** 2 * jac.T @ (y - w).reshape(-1) + 2.0 * QU ** 2 * v
    u = u0 + np.cumsum(v.reshape(N, m), axis=0)
    value, rows, bound = [], [], []  # each limit row: its value, d(value)/dv, its bound
    cum = np.kron(np.tril(np.ones((N, N))), np.eye(m))  # u = u0 + cum v
    if tight.torque is not None:
        for i in range(N * m):
            for sign in (1.0, -1.0):
                value.append(sign * u.reshape(-1)[i]), rows.append(sign * cum[i]), bound.append(tight.torque[i % m])
    if tight.du is not None:
        du = np.diff(np.vstack([plan[:1], u]), axis=0).reshape(-1)
        for i in range(N * m):
            for sign in (1.0, -1.0):
                value.append(sign * du[i]), rows.append(sign * np.eye(N * m)[i]), bound.append(tight.du[i % m])
    value, rows, bound = np.array(value), np.array(rows), np.array(bound)
    active = value >= bound * (1.0 - 1e-9)
    lam, _ = nnls(rows[active].T, -grad)
    residual = np.abs(grad + rows[active].T @ lam).max() / np.abs(grad).max()
    return residual, float(np.max(value - bound)), int(active.sum())


@pytest.mark.parametrize("kind", ["torque", "du"])
def test_limited_iterations_take_the_stagewise_active_set(kind, compiled_stagewise, monkeypatch):
    """A torque or Δu limit binding in every Gauss–Newton step: each step is the stage-wise active
    set's (the condensed back end is never called), the converged plan is the condensed path's
    (the same settings with the back end named: every step condensed, DAQP) within 1e-8, and a KKT
    point of the limited problem (gradient of the rollout, multipliers ≥ 0 on the active rows)."""
    model, X, plan, target, limits = _limited_case(kind)
    N = 10
    ctrl = GPCController.build(model, TS, Horizons(N), Weights(QY, QU), form="nonlinear", iterations=50,
                               tolerance=1e-12, limits=limits, disturbance_gain=0.0)
    ctrl.restore(ControllerState(plan[0], plan[:N], np.zeros(model.n_x)))

    def condensed(*args):
        raise AssertionError("a limited step went to the condensed back end")

    monkeypatch.setattr(ctrl._backend, "solve", condensed)
    info = ctrl.step(X, np.tile(target, (N, 1)))
    assert ctrl._nmpc.stagewise is not None and ctrl._nmpc.stagewise.method == "active-set"
    assert info.result.solver == "riccati" and info.result.active_limits and not info.fallback
    assert info.iterations > 2 and info.residual <= 1e-6
    _, dense = _step(model, X, plan, target, N, 50, limits=limits, solver=ctrl.settings.solver)
    assert dense.result.solver == ctrl.settings.solver != "riccati" and dense.result.active_limits
    # the stop is rounding-limited (J flat to 1e-17 there): measured 7e-11 (torque), 1.5e-8 (du) relative with
    # the compiled core (4e-9 before its small solves became plain loops: the same plans to rounding, another
    # stop); the Python reference's (PARALLEL_GPC_NATIVE=0) stop earlier, 3e-8
    rtol = 1e-7
    np.testing.assert_allclose(info.result.v, dense.result.v, rtol=0, atol=rtol * np.abs(dense.result.v).max())
    assert info.result.cost == pytest.approx(dense.result.cost, rel=1e-10)
    residual, excess, n_active = _kkt_residual(model, X, plan, target, limits, info.result.v)
    assert n_active > 0 and residual <= 1e-6 and excess <= 1e-9  # measured 1e-8 (torque), 3e-9 (du)
    _, paper = _step(model, X, plan, target, N, 1, limits=limits)  # the oracle can fail: the paper's step is not it
    assert _kkt_residual(model, X, plan, target, limits, paper.result.v)[0] > 1e-4  # measured 6e-3, 1e-3


def test_a_limited_step_the_active_set_does_not_verify_goes_to_the_condensed_problem(compiled_stagewise,
                                                                                     monkeypatch):
    """The condensed back end stays the fallback: a stage-wise step not verified within the limits'
    margin (here every one after the paper's) is solved condensed, to the same converged plan."""
    model, X, plan, target, limits = _limited_case("torque")
    N = 10
    ctrl = GPCController.build(model, TS, Horizons(N), Weights(QY, QU), form="nonlinear", iterations=50,
                               tolerance=1e-12, limits=limits, disturbance_gain=0.0)
    ctrl.restore(ControllerState(plan[0], plan[:N], np.zeros(model.n_x)))
    monkeypatch.setattr(ctrl._nmpc, "_gap", -1.0)  # no excess is within it
    info = ctrl.step(X, np.tile(target, (N, 1)))
    assert info.result.solver == ctrl.settings.solver != "riccati" and info.iterations > 2 and not info.fallback
    _, staged = _step(model, X, plan, target, N, 50, limits=limits)
    np.testing.assert_allclose(info.result.v, staged.result.v, rtol=0, atol=1e-7 * np.abs(staged.result.v).max())


@pytest.mark.parametrize("kw", [dict(solver="qr"), dict(limits=Limits(output_box=[[0.0, 1.0], [0.0, 1.0], [-3.0, 3.0]])),
                                dict(weights=Weights(QY, QU, Qf=2.0)), dict(weights=Weights(QY, 1e-9))])
def test_riccati_steps_only_where_they_give_the_condensed_minimizer(kw, robot4):
    """An explicit back end, a state limit, a terminal weight or a nearly singular Qu: every exact
    step goes to the controller's back end."""
    settings = dict(form="nonlinear", iterations=5, weights=Weights(QY, QU)) | kw
    ctrl = GPCController.build(ReducedModel(robot4), TS, Horizons(10), settings.pop("weights"), **settings)
    assert ctrl._nmpc.riccati is None
    assert ctrl.solver == ctrl.settings.step_solver == ctrl.settings.solver != "riccati"  # the back end solves them


def test_without_the_compiled_core_the_steps_go_to_the_condensed_back_end(monkeypatch, robot4):
    """No compiled recursion (not built, PARALLEL_GPC_NATIVE=0): the Python one is slower than the
    condensed QR, so every step goes to the controller's back end, and the settings say so."""
    monkeypatch.setattr(settings_module, "stagewise_compiled", lambda limited: False)
    ctrl = GPCController.build(ReducedModel(robot4), TS, Horizons(10), Weights(QY, QU), form="nonlinear", iterations=5)
    assert ctrl._nmpc.riccati is None
    assert ctrl.solver == ctrl.settings.step_solver == ctrl.settings.solver != "riccati"


def test_the_reported_solver_follows_the_iterations_settings(compiled_stagewise):
    """``step_solver`` is derived from the settings (not a constructor argument) and chosen again by a
    changed copy: the iterated default says ``riccati``, the paper's single step its own default."""
    iterated = GPCSettings(TS, Horizons(10), Weights(QY, QU), form="nonlinear", iterations=5)
    assert iterated.step_solver == "riccati" and iterated.solver != "riccati"
    single = replace(iterated, iterations=1)
    assert single.step_solver == single.solver
    assert replace(iterated, solver="qr").step_solver == "qr"


def test_riccati_steps_with_short_control_and_insensitivity_horizons(robot4, compiled_stagewise):
    """No > 0 and Nu < N: the recursion's stage models hold Δu = 0 after Nu and skip the first No
    outputs like the condensed problem."""
    _, X, plan, target = _case("planar_4rrr")
    H = Horizons(10, 2, 4)
    infos = []
    for solver in (None, "qr"):
        ctrl = GPCController.build(ReducedModel(robot4), TS, H, Weights(QY, QU), form="nonlinear", iterations=50,
                                   tolerance=1e-10, disturbance_gain=0.0, solver=solver)
        ctrl.restore(ControllerState(plan[0], plan[:10], np.zeros(6)))
        infos.append(ctrl.step(X, np.tile(target, (10, 1))))
    fast, condensed = infos
    assert fast.result.solver == "riccati" and condensed.result.solver == "qr" and fast.residual <= 1e-6
    assert condensed.residual <= 1e-6
    np.testing.assert_allclose(fast.result.v, condensed.result.v, rtol=0, atol=_between_converged(fast, condensed))


def _limited_loop(steps, reuse=True, spy=None, replay=None):
    """Plans (steps, N, m) of the torque-limited planar controller of :func:`_limited_case` closing the loop
    on its own model (one ZOH step of a separate model instance per sample), the controller and what each
    step started from and gave, [(X, ControllerState, StepInfo)].

    reuse=False: every limited Gauss–Newton step solved as before the steps shared anything (cold
    active set, bounds recomputed): the reference. spy: called with (solver, keywords, sweeps, result) after
    each limited step. replay: another run's record: each step from its state and controller state instead."""
    model, X, plan, target, limits = _limited_case("torque")
    plant = ReducedModel(model.robot)
    N = 10
    ctrl = GPCController.build(ReducedModel(model.robot), TS, Horizons(N), Weights(QY, QU), form="nonlinear",
                               iterations=50, tolerance=1e-12, limits=limits, disturbance_gain=0.0)
    ctrl.restore(ControllerState(plan[0], plan[:N], np.zeros(model.n_x)))
    solver = ctrl._nmpc.stagewise
    solve = solver.solve

    def wrapped(*args, **kw):
        if not reuse:
            kw.update(warm=False, start=None, bounds=None)
        out = solve(*args, **kw)
        if spy is not None:
            spy(solver, kw, solver.iterations[0], out[0])
        return out

    solver.solve = wrapped
    plans, record = [], []
    for k in range(steps):
        if replay is not None:
            X = replay[k][0]
            ctrl.restore(replay[k][1])
        before = ctrl.state
        info = ctrl.step(X, np.tile(target, (N, 1)))
        assert info.result.solver == "riccati" and not info.fallback and info.residual <= 1e-6
        plans.append(ctrl.plan.copy())
        record.append((X, before, info))
        Ad, Bd, cd = plant.discrete(X, TS)
        X = Ad @ X + Bd @ info.u + cd
    return np.array(plans), ctrl, record


def test_limited_iterations_reuse_the_step_bounds_and_the_last_active_set(compiled_stagewise, monkeypatch):
    """One stage-wise solver per controller: the paper's step (warm: the last control step's converged set,
    shifted) and the Gauss–Newton steps after it, which compute the input rows' bounds once (u_sim⁰ and u(k−1)
    do not change between them) and start each from the last solve's active set, not shifted (the first: the
    paper step's); the verifying step, whose set is the last one's, takes one Riccati sweep; cold starts (the
    reference) take more, to the same plans (each control step from the same state: as close as two converged
    plans are, :func:`_between_converged`; a rounding-limited stop ends a few 1e-7 from the optimum here, and the
    plans of one closed loop would carry that on to the next steps' states)."""
    from parallel_gpc.gpc import nmpc as nmpc_module
    from parallel_gpc.gpc import stagewise as stagewise_module

    counted = {"nmpc": 0, "solver": 0}

    def counting(where, f):
        def g(*args):
            counted[where] += 1
            return f(*args)
        return g

    monkeypatch.setattr(nmpc_module, "step_bounds", counting("nmpc", stagewise_module.step_bounds))
    monkeypatch.setattr(stagewise_module, "step_bounds", counting("solver", stagewise_module.step_bounds))
    calls = []

    def spy(solver, kw, sweeps, result):
        calls.append((kw, sweeps, result.active_limits, solver.active_set))

    steps = 4
    _, ctrl, record = _limited_loop(steps, spy=spy)
    assert ctrl._nmpc.stagewise is ctrl._riccati.constrained  # the paper step's solver
    firsts = [i for i, (kw, *_) in enumerate(calls) if kw.get("start") is None]  # the paper's steps
    assert len(firsts) == steps and firsts[0] == 0 and len(calls) >= 3 * steps  # ≥ 2 limited steps after each
    for first, end in zip(firsts, firsts[1:] + [len(calls)]):
        assert calls[first][0]["warm"] == (first > 0)  # the first control step's paper step: no set yet
        bounds = calls[first + 1][0]["bounds"]
        assert bounds is not None
        for i in range(first + 1, end):
            kw = calls[i][0]
            assert not kw["warm"] and kw["start"] is calls[i - 1][3] and kw["bounds"] is bounds
        assert calls[end - 1][1] == 1 and calls[end - 1][2]  # the verifying step: one sweep, the limit binding
    assert counted["nmpc"] == steps  # once per control step, handed to the paper step's solve and to the iterations
    assert counted["solver"] == 0  # the paper step's solver computes none of its own
    cold = []
    _, _, cold_record = _limited_loop(steps, reuse=False, replay=record,
                                      spy=lambda s, kw, sweeps, r: cold.append(sweeps))
    assert np.mean(cold) > 2.0 * np.mean([c[1] for c in calls])  # sweeps per limited step
    for (_, _, warm), (_, _, cold_info) in zip(record, cold_record):
        np.testing.assert_allclose(warm.result.v, cold_info.result.v, rtol=0, atol=_between_converged(warm, cold_info))


def test_the_paper_step_solves_with_the_iterations_bounds(compiled_stagewise):
    """The input rows' bounds of a control step are computed once (NMPCIterations.step_bounds): the paper's
    stage-wise step takes the very array the Gauss–Newton steps after it take (before, its solver computed them a
    second time), equal to step_bounds of the step's pre-simulated inputs and u(k−1) (the reference)."""
    from parallel_gpc.gpc.stagewise import step_bounds

    calls = []
    _, ctrl, _ = _limited_loop(3, spy=lambda solver, kw, sweeps, result: calls.append(kw))
    firsts = [i for i, kw in enumerate(calls) if kw.get("start") is None]  # the paper's steps (u_sim, u_prev given)
    assert len(firsts) == 3
    for first, end in zip(firsts, firsts[1:] + [len(calls)]):
        paper = calls[first]
        assert end > first + 1 and paper.get("bounds") is not None
        assert all(calls[i]["bounds"] is paper["bounds"] for i in range(first + 1, end))
        reference = step_bounds(ctrl._nmpc.stagewise.limits, ctrl.horizons, paper["u_sim"], paper["u_prev"])
        np.testing.assert_array_equal(paper["bounds"], reference)


def test_the_compiled_model_update_is_built_with_the_controller(robot4, monkeypatch):
    """The controller builds its robot model's compiled update (not its first step: the dearest step of
    a run paid for it); the steps use that one, none other is built."""
    from parallel_gpc.model import dynamics

    model = ReducedModel(robot4)
    if not model.native:
        pytest.skip(model.native_reason)
    built = []
    make = dynamics.compiled_model_update
    monkeypatch.setattr(dynamics, "compiled_model_update", lambda robot: built.append(make(robot)) or built[-1])
    ctrl = GPCController.build(model, TS, Horizons(10), Weights(QY, QU), form="nonlinear", iterations=5,
                               limits=Limits(torque=15.0))
    assert len(built) == 1 and model.compiled_update is built[0]
    X = np.array([0.5, 0.4, 0.1, 0.8, -0.5, 1.0])
    ctrl.step(X, np.tile([0.51, 0.39, 0.12], (10, 1)))
    assert len(built) == 1 and model.compiled_update is built[0]
