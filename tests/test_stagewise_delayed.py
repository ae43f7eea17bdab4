"""The delayed incremental form's torque/Δu-limited step stage-wise (gpc/stagewise.py, the compiled
``_native.RiccatiActive``): eq. (8)–(9) as printed, state [X(k); u(k)], u(k) decided at k − 1, the plan
u(k+1 …) decided at k. Oracles: the condensed problem solved by DAQP (another solver, another layout),
the KKT conditions of the QP written here from the controller's prediction ŷ = f + G v (stationarity
with multipliers ≥ 0 by NNLS, complementarity, feasibility), the condensed QR without active limits,
and a closed loop on the full plant against the condensed default."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import nnls

from parallel_gpc import GPCController, Horizons, ParallelRobot, ReducedModel, Weights
from parallel_gpc.gpc.controller import DEFAULT_LIMITED_SOLVER, LIMIT_MARGIN
from parallel_gpc.gpc.criterion import Criterion
from parallel_gpc.gpc.references import SCurve, path_for
from parallel_gpc.gpc.settings import stagewise_compiled
from parallel_gpc.limits import Limits
from parallel_gpc.model.plant import ConstrainedPlant

TS = 0.002
FORM = "incremental-delayed"
WEIGHTS = Weights(1.0, 1e-3)


@pytest.fixture(scope="module", params=["planar_4rrr", "delta_3rus"])
def robot(request) -> ParallelRobot:
    return ParallelRobot.load(request.param)


@pytest.fixture(scope="module")
def model(robot) -> ReducedModel:
    return ReducedModel(robot)


def _start(robot):
    """(X at rest at the home pose, a reference window 1 cm away in the first output, u(−1) = u(k))."""
    X = np.concatenate([robot.home_pose, np.zeros(robot.n_y)])
    target = robot.home_pose.copy()
    target[0] += 0.01
    u0 = 0.05 * np.random.default_rng(3).standard_normal(robot.n_u)
    return X, target, u0


def _free_plan(model, robot, H: Horizons) -> np.ndarray:
    """The unconstrained delayed plan (N, m) of the first step (condensed QR), to size the limits."""
    X, target, u0 = _start(robot)
    ctl = GPCController.build(model, TS, H, WEIGHTS, form=FORM, solver="qr", u0=u0)
    ctl.step(X, np.tile(target, (H.N, 1)))
    return ctl.plan


LIMITS = {  # name: limits from the unconstrained plan's largest |u| and |Δu|, binding
    "torque": lambda u, du: Limits(torque=0.4 * u),
    "du": lambda u, du: Limits(du=0.3 * du),
    "torque+du": lambda u, du: Limits(torque=0.5 * u, du=0.5 * du),
}
HORIZONS = {"N=16": Horizons(16), "N=16,No=2,Nu=6": Horizons(16, 2, 6)}


def _limits(model, robot, H: Horizons, case: str) -> Limits:
    plan = _free_plan(model, robot, H)
    return LIMITS[case](float(np.abs(plan).max()), float(np.abs(np.diff(plan, axis=0)).max()))


def _oracle(ctl: GPCController, X, w):
    """The delayed step's QP written from the controller's prediction (eq. (8)–(9): ŷ = f + G v, u(k+1+i)
    = u(k) + Σ_{j≤i} Δu(k+1+j) = u_base + u_map v): (J(v), its gradient, rows L v ≤ b). The criterion (5)
    with scalar square-root weights, J = Qy² ‖f + G v − w‖² + Qu² ‖v‖²; the limits the QP gets (tightened
    by LIMIT_MARGIN): |u| ≤ τ on the decided inputs, |Δu| ≤ δ."""
    pred = ctl.predict(X)
    H = ctl.horizons
    r = np.asarray(w, float)[H.No:].reshape(-1)
    qy, qu = float(WEIGHTS.Qy), float(WEIGHTS.Qu)

    def J(v):
        e = pred.f + pred.G @ v - r
        return qy ** 2 * float(e @ e) + qu ** 2 * float(v @ v)

    def grad(v):
        """∇J(v) and its scale: the largest entry of its terms 2Qy²GᵀG v, 2Qy²Gᵀ(f − w), 2Qu² v."""
        terms = (2.0 * qy ** 2 * pred.G.T @ (pred.G @ v), 2.0 * qy ** 2 * pred.G.T @ (pred.f - r), 2.0 * qu ** 2 * v)
        return sum(terms), max(float(np.max(np.abs(t))) for t in terms)

    qp_limits = ctl.limits.scaled(1.0 - LIMIT_MARGIN)
    n, m = pred.G.shape[1], ctl.n_u
    rows, bounds = [], []
    if qp_limits.torque is not None:
        tau = np.tile(qp_limits.torque, n // m)
        rows += [pred.u_map, -pred.u_map]
        bounds += [tau - pred.u_base, tau + pred.u_base]
    if qp_limits.du is not None:
        delta = np.tile(qp_limits.du, n // m)
        rows += [np.eye(n), -np.eye(n)]
        bounds += [delta, delta]
    return J, grad, np.vstack(rows), np.concatenate(bounds), pred


def _kkt(grad, L, b, v) -> tuple[float, float, float, int]:
    """(stationarity, complementarity, feasibility, binding rows) of v: ∇J(v) + Lᵀ μ = 0 with μ ≥ 0 on the
    rows within 1e-9 of their bound (NNLS), μ_i (b_i − L_i v) summed, the largest row excess; the first
    two relative to the gradient's scale (its largest term, :func:`_oracle`), the third to the largest bound."""
    slack = b - L @ v
    bound = float(np.max(np.abs(b)))
    active = slack <= 1e-9 * bound
    g, scale = grad(v)
    if not active.any():
        return float(np.max(np.abs(g))) / scale, 0.0, float(max(0.0, -slack.min())) / bound, 0
    mu, residual = nnls(L[active].T, -g, maxiter=50 * int(active.sum()))
    complementarity = float(np.sum(mu * np.abs(slack[active]))) / (scale * bound)
    return residual / scale, complementarity, float(max(0.0, -slack.min())) / bound, int(np.sum(mu > 1e-6 * mu.max()))


def _first_step(model, robot, H: Horizons, limits: Limits, solver):
    X, target, u0 = _start(robot)
    w = np.tile(target, (H.N, 1))
    ctl = GPCController.build(model, TS, H, WEIGHTS, form=FORM, solver=solver, limits=limits, u0=u0)
    return ctl, X, w


@pytest.mark.parametrize("horizons", list(HORIZONS))
@pytest.mark.parametrize("case", list(LIMITS))
def test_delayed_limited_step_equals_daqp_and_meets_the_kkt_conditions(model, robot, case, horizons):
    H = HORIZONS[horizons]
    limits = _limits(model, robot, H, case)
    staged, X, w = _first_step(model, robot, H, limits, "riccati")
    J, grad, L, b, pred = _oracle(staged, X, w)
    info = staged.step(X, w)
    assert info.result.solver == "riccati" and info.result.status == "optimal" and not info.replaced
    assert info.result.active_limits
    v = info.result.v
    condensed, _, _ = _first_step(model, robot, H, limits, "daqp-direct")
    reference = condensed.step(X, w)
    assert reference.result.ok and not reference.replaced
    v_ref = reference.result.v
    assert np.abs(v - v_ref).max() <= 1e-8 * np.abs(v_ref).max()
    assert J(v) == pytest.approx(J(v_ref), rel=1e-10)
    stationarity, complementarity, excess, binding = _kkt(grad, L, b, v)
    assert stationarity <= 1e-8 and complementarity <= 1e-10 and excess <= 1e-12
    assert binding >= 1  # the limits bind: the unconstrained minimizer is not feasible
    free = np.linalg.solve(pred.G.T @ pred.G + (float(WEIGHTS.Qu) / float(WEIGHTS.Qy)) ** 2 * np.eye(len(v)),
                           pred.G.T @ (np.asarray(w, float)[H.No:].reshape(-1) - pred.f))
    assert np.max(L @ free - b) > 1e-3 * np.max(np.abs(b))
    # the plan the controller keeps: u(k) decided at k − 1, then u(k+1 …) = u_base + u_map v
    u_plan = (pred.u_base + pred.u_map @ v).reshape(-1, staged.n_u)
    assert np.array_equal(staged.plan[0], info.u)
    assert np.abs(staged.plan[1:1 + len(u_plan)] - u_plan[:H.N - 1]).max() <= 1e-12 * np.abs(u_plan).max()


def test_inactive_limits_and_no_limits_give_the_condensed_qr_plan(model, robot):
    H = Horizons(16)
    plan = _free_plan(model, robot, H)
    qr, X, w = _first_step(model, robot, H, Limits(), "qr")
    v_qr = qr.step(X, w).result.v
    for limits in (Limits(), Limits(torque=10.0 * np.abs(plan).max())):
        ctl, _, _ = _first_step(model, robot, H, limits, None)
        if stagewise_compiled(limits.needs_qp):
            assert ctl.solver == "riccati"
        info = ctl.step(X, w)
        assert info.result.ok and not info.result.active_limits and not info.replaced
        assert np.abs(info.result.v - v_qr).max() <= 1e-8 * np.abs(v_qr).max()


def _closed_loop(model, robot, limits: Limits, solver, steps: int, check=None):
    """Applied inputs (steps, m) and the step records of a delayed controller on the full plant along
    the robot's default path; ``check(ctl, X, w)`` before each step returns what runs after it (or None).
    No disturbance estimate (gain 0): the step's prediction is then the one :meth:`predict` gives before it."""
    ref = path_for("auto", robot.home_pose, robot.output_angular, SCurve().duration)
    H = Horizons(16)
    ctl = GPCController.build(model, TS, H, WEIGHTS, form=FORM, solver=solver, limits=limits, disturbance_gain=0.0)
    plant = ConstrainedPlant(robot, ref.initial_state(), Ts=TS)
    us, infos = [], []
    for k in range(steps):
        X, w = plant.X.copy(), ref.window(k * TS, TS, H.N)
        after = None if check is None else check(ctl, X, w)
        info = ctl.step(X, w)
        if after is not None:
            after(info)
        us.append(info.u)
        infos.append(info)
        plant.step(info.u)
    return ctl, np.array(us), infos


#: the closed loop's limits, fractions of the unconstrained loop's largest |u| and |Δu|: binding on most
#: steps (delta_3rus, torque: u(k) sits on its limit and the plan holds it, v = 0, on several steps —
#: the condensed back ends' plan there must pass solvers.kkt's check, whose complementarity scale does
#: not vanish with v and the limit)
CLOSED_LOOP = {"torque": {"planar_4rrr": 0.4, "delta_3rus": 0.5}, "du": {"planar_4rrr": 0.3, "delta_3rus": 0.3}}


@pytest.mark.skipif(not stagewise_compiled(True), reason="the default limited step is stage-wise only compiled")
@pytest.mark.parametrize("case", list(CLOSED_LOOP))
def test_closed_loop_with_binding_limits_equals_the_condensed_default(model, robot, case):
    _, u_free, _ = _closed_loop(model, robot, Limits(), "qr", 30)
    fraction = CLOSED_LOOP[case][robot.name]
    if case == "torque":
        limits = Limits(torque=fraction * float(np.abs(u_free).max()))
    else:
        limits = Limits(du=fraction * float(np.abs(np.diff(u_free, axis=0)).max()))
    kkt = []

    def check(ctl, X, w):  # the KKT conditions of each step's QP, from the controller's prediction
        J, grad, L, b, pred = _oracle(ctl, X, w)

        def after(info):
            kkt.append(_kkt(grad, L, b, info.result.v))
        return after

    staged, u, infos = _closed_loop(model, robot, limits, None, 30, check)
    assert staged.settings.solver == "riccati" and staged.settings.solver_is_default
    assert all(i.result.solver == "riccati" and not i.fallback and not i.replaced for i in infos)
    kkt = np.array(kkt)
    assert kkt[:, 0].max() <= 1e-8 and kkt[:, 1].max() <= 1e-10 and kkt[:, 2].max() <= 1e-12
    assert np.count_nonzero(kkt[:, 3]) >= 8  # steps whose limits bind
    _, u_ref, infos_ref = _closed_loop(model, robot, limits, DEFAULT_LIMITED_SOLVER, 30)
    assert not any(i.fallback or not i.result.ok for i in infos_ref)
    assert np.abs(u - u_ref).max() <= 1e-8 * np.abs(u_ref).max()
    if limits.torque is not None:
        assert np.abs(u).max() <= float(limits.torque.max())


@pytest.mark.skipif(not stagewise_compiled(True), reason="the default limited step is stage-wise only compiled")
def test_the_default_limited_delayed_step_condenses_nothing(model, robot, monkeypatch):
    """The default (solver unset) takes the stage-wise path: with the condensed problem's builder
    replaced by one that raises, a limited step with its limits binding still solves (not replaced)."""
    H = Horizons(16)
    limits = _limits(model, robot, H, "torque+du")
    ctl, X, w = _first_step(model, robot, H, limits, None)
    assert ctl.solver == "riccati"

    def refuse(*args, **kwargs):
        raise AssertionError("the condensed problem was built")

    monkeypatch.setattr(Criterion, "problem", refuse)
    for _ in range(3):
        info = ctl.step(X, w)
        assert info.result.solver == "riccati" and info.result.status == "optimal"
        assert info.result.active_limits and not info.replaced and not info.fallback
