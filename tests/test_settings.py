"""The controller's default solver (gpc/settings.py: default_solver, the one place of the policy):
which back end ``solver=None`` resolves to, that the stage-wise default gives the QR reference's
inputs (oracle: the same controller with solver="qr", stepped side by side in closed loop), that
a default is chosen again when the limits change, and that a failed or limit-breaking stage-wise
step is replaced visibly by the condensed default."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from parallel_gpc import ConstrainedPlant, DiscreteLinearModel, GPCController, Horizons, Limits, ParallelRobot
from parallel_gpc import ReducedModel, Weights
from parallel_gpc.errors import InvalidParameterError
from parallel_gpc.gpc import settings as settings_module
from parallel_gpc.gpc.settings import (DEFAULT_BOX_SOLVER, DEFAULT_LIMITED_SOLVER, RICCATI_QU_MARGIN,
                                       STAGEWISE_LIMITED_MIN_N, GPCSettings, weight_margin)

TS = 0.002
QU = 1e-5  # the benchmark's weight: margin 2.5 at Ts = 2 ms
A = np.array([[1.0, 0.1, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0.1], [0, 0, 0, 1.0]])
B = np.array([[0.005, 0.0], [0.1, 0.0], [0.0, 0.005], [0.0, 0.1]])


@pytest.fixture(autouse=True)
def compiled_stagewise(monkeypatch):
    """The policy's rules with the compiled stage-wise solve present, also under
    PARALLEL_GPC_NATIVE=0 (where the stage-wise path then runs its Python reference):
    :func:`test_without_the_compiled_core_the_default_is_the_condensed_one` covers its absence."""
    monkeypatch.setattr(settings_module, "stagewise_compiled", lambda limited: True)


def resolved(**kwargs) -> GPCSettings:
    kwargs.setdefault("horizons", Horizons(20))
    kwargs.setdefault("weights", Weights(1.0, QU))
    return GPCSettings(Ts=TS, **kwargs)


@pytest.mark.parametrize("kwargs, expected", [
    (dict(), "riccati"),
    (dict(form="incremental"), "riccati"),
    (dict(form="incremental-delayed"), "riccati"),
    (dict(form="nonlinear"), "riccati"),
    (dict(weights=Weights(1.0, 0.0)), "qr"),  # the paper's Qu = 0: QR's minimum-norm answer
    (dict(weights=Weights(1.0, [QU, QU, 0.0])), "qr"),  # singular in one drive
    (dict(weights=Weights(1.0, 0.5 * RICCATI_QU_MARGIN * TS ** 2)), "qr"),  # below the measured margin
    (dict(weights=Weights(1.0, QU, 2.0)), "qr"),  # a terminal weight
    (dict(terminal="pose"), DEFAULT_LIMITED_SOLVER),
    (dict(form="nonlinear", iterations=3), "qr"),
    (dict(limits=Limits(torque=5.0)), "riccati"),  # input rows only: the stage-wise active set
    (dict(form="incremental", limits=Limits(torque=5.0)), "riccati"),
    (dict(horizons=Horizons(STAGEWISE_LIMITED_MIN_N - 1), form="incremental", limits=Limits(torque=5.0)),
     DEFAULT_LIMITED_SOLVER),  # below the measured horizons: the condensed default
    (dict(horizons=Horizons(STAGEWISE_LIMITED_MIN_N), limits=Limits(torque=5.0)), "riccati"),
    (dict(horizons=Horizons(STAGEWISE_LIMITED_MIN_N), form="incremental", limits=Limits(torque=5.0, du=1.0)),
     "riccati"),
    (dict(horizons=Horizons(STAGEWISE_LIMITED_MIN_N - 1), limits=Limits(torque=5.0)), DEFAULT_BOX_SOLVER),
    (dict(horizons=Horizons(STAGEWISE_LIMITED_MIN_N), form="nonlinear", limits=Limits(torque=5.0)), "riccati"),
    (dict(horizons=Horizons(STAGEWISE_LIMITED_MIN_N), form="nonlinear", limits=Limits(torque=5.0, du=1.0)),
     "riccati"),
    (dict(horizons=Horizons(STAGEWISE_LIMITED_MIN_N), form="incremental-delayed", limits=Limits(torque=5.0)),
     "riccati"),
    (dict(horizons=Horizons(STAGEWISE_LIMITED_MIN_N), form="incremental-delayed", limits=Limits(torque=5.0, du=1.0)),
     "riccati"),
    (dict(horizons=Horizons(STAGEWISE_LIMITED_MIN_N - 1), form="incremental-delayed", limits=Limits(du=1.0)),
     DEFAULT_LIMITED_SOLVER),
    (dict(horizons=Horizons(STAGEWISE_LIMITED_MIN_N - 1), form="nonlinear", limits=Limits(torque=5.0)),
     DEFAULT_LIMITED_SOLVER),
    (dict(horizons=Horizons(STAGEWISE_LIMITED_MIN_N), limits=Limits(output_box=[[-1, 1]])), DEFAULT_LIMITED_SOLVER),
    (dict(limits=Limits(drive_rate=2.0)), DEFAULT_LIMITED_SOLVER),
])
def test_the_default_policy(kwargs, expected):
    s = resolved(**kwargs)
    assert s.solver == expected and s.solver_is_default
    assert not resolved(**kwargs, solver=DEFAULT_LIMITED_SOLVER).solver_is_default


def test_without_the_compiled_core_the_default_is_the_condensed_one(monkeypatch):
    """The pure-Python stage-wise solve was measured slower than QR on every form (docs/controller.md):
    with PARALLEL_GPC_NATIVE=0 each stage-wise default is the condensed default of its settings; the
    compiled core, where it is built, gives the stage-wise path back."""
    monkeypatch.undo()  # the real availability
    cases = [(dict(), "qr"), (dict(form="nonlinear"), "qr"), (dict(limits=Limits(torque=5.0)), DEFAULT_BOX_SOLVER),
             (dict(form="incremental", limits=Limits(torque=5.0)), DEFAULT_LIMITED_SOLVER)]
    monkeypatch.setenv("PARALLEL_GPC_NATIVE", "0")
    assert not settings_module.stagewise_compiled(False) and not settings_module.stagewise_compiled(True)
    for kwargs, condensed in cases:
        s = resolved(**kwargs)
        assert s.solver == condensed and s.solver_is_default, kwargs
        assert resolved(**kwargs, solver="riccati").solver == "riccati"  # still selectable: the reference
    monkeypatch.delenv("PARALLEL_GPC_NATIVE")
    if settings_module.stagewise_compiled(True):  # a build with the compiled core
        assert all(resolved(**kwargs).solver == "riccati" for kwargs, _ in cases)


def test_the_margin_compares_qu_with_the_output_weight_over_ts_squared():
    assert weight_margin(Weights(2.0, 1e-5), 1e-3) == pytest.approx(1e-5 / (2.0 * 1e-6))
    full = np.array([[2.0, 1.0], [1.0, 2.0]])  # singular values 3 and 1
    assert weight_margin(Weights(full, 0.5 * full), 0.1) == pytest.approx(0.5 / (3.0 * 0.01))
    assert weight_margin(Weights(0.0, 1.0), 0.1) == np.inf


def test_each_riccati_refusal_is_stated_once_by_its_owner():
    for kwargs, needle in ((dict(terminal="pose"), "riccati.*cannot enforce the terminal equality"),
                           (dict(weights=Weights(1.0, QU, 2.0)), "riccati.*terminal weight Qf"),
                           (dict(form="nonlinear", iterations=3), "riccati.*iterations = 3"),
                           (dict(limits=Limits(joint_position={"a": (0.0, 1.0)})), "riccati.*joint_position")):
        with pytest.raises(InvalidParameterError, match=needle):
            resolved(solver="riccati", **kwargs)


@pytest.mark.parametrize("form", ["absolute", "incremental", "nonlinear"])
def test_the_stagewise_default_applies_the_qr_references_inputs_in_closed_loop(form):
    """planar_4rrr has a redundant drive (the case where the two drift apart as Qu shrinks): at
    twice the margin the default's inputs are QR's to 1e-8 relative, step after step."""
    robot = ParallelRobot.load("planar_4rrr")
    model = ReducedModel(robot)
    qu = 2.0 * RICCATI_QU_MARGIN * TS ** 2
    default = GPCController.build(model, TS, Horizons(20), Weights(1.0, qu), form=form)
    qr = GPCController.build(model, TS, Horizons(20), Weights(1.0, qu), form=form, solver="qr")
    assert default.solver == "riccati" and default.settings.solver_is_default
    X = np.concatenate([robot.home_pose, np.zeros(robot.n_y)])
    plant = ConstrainedPlant(robot, X, Ts=TS)
    w = np.tile(robot.home_pose + np.array([0.004, -0.003, 0.01]), (20, 1))
    for _ in range(10):
        a, b = default.step(plant.X, w), qr.step(plant.X, w)
        assert a.result.solver == "riccati" and b.result.solver == "qr"
        np.testing.assert_allclose(a.u, b.u, rtol=0, atol=1e-8 * np.abs(b.u).max())
        plant.step(b.u)


def test_a_default_is_chosen_again_when_the_limits_change():
    robot = ParallelRobot.load("planar_4rrr")
    ctl = GPCController.build(ReducedModel(robot), TS, Horizons(20), Weights(1.0, QU))
    assert ctl.solver == "riccati"
    ctl.limits = Limits(drive_rate=2.0)  # not stage-wise: the condensed default, not an error
    assert ctl.solver == DEFAULT_LIMITED_SOLVER and ctl.settings.solver_is_default
    ctl.limits = Limits(torque=5.0)  # input rows only, N ≥ the threshold: stage-wise again
    assert ctl.solver == "riccati" and ctl.settings.solver_is_default
    ctl.limits = Limits(torque=5.0, output_box=[[-1.0, 1.0]])  # a state row: not a box, the condensed QP
    assert ctl.solver == DEFAULT_LIMITED_SOLVER
    ctl.limits = Limits()
    assert ctl.solver == "riccati" and ctl._backend is None
    explicit = GPCController.build(ReducedModel(robot), TS, Horizons(20), Weights(1.0, QU), solver="riccati")
    with pytest.raises(InvalidParameterError, match="riccati.*drive_rate"):  # a named solver stays named
        explicit.limits = Limits(drive_rate=2.0)


@pytest.mark.parametrize("limited", [False, True])
def test_a_failed_default_stagewise_step_is_replaced_visibly(monkeypatch, limited):
    """Forced failure (R + BᵀPB not positive definite) of the default: the step is solved by the
    condensed default of the same settings (QR; with limits at N ≥ the threshold, bvls), and the
    result names that back end and the reason."""
    N = STAGEWISE_LIMITED_MIN_N if limited else 10
    limits = Limits(torque=0.05) if limited else Limits()
    model = DiscreteLinearModel(A, B, np.eye(4), Ts=0.1)
    ctl = GPCController.build(model, 0.1, Horizons(N), Weights(1.0, 0.1), limits=limits)
    ref = GPCController.build(model, 0.1, Horizons(N), Weights(1.0, 0.1), limits=limits,
                              solver=DEFAULT_BOX_SOLVER if limited else "qr")
    assert ctl.solver == "riccati"
    X, w = np.array([0.1, 0.0, -0.2, 0.05]), np.zeros((N, 4))
    failed = replace(ref.step(X, w).result, v=np.full(2 * N, np.nan), status="failed", solver="riccati",
                     message="R + BᵀPB is not positive definite")
    ref.reset()
    monkeypatch.setattr(ctl._riccati, "solve", lambda *args, **kwargs: failed)
    info, expected = ctl.step(X, w), ref.step(X, w)
    assert not info.fallback and info.result.solver == expected.result.solver
    assert "riccati failed (R + BᵀPB is not positive definite)" in info.result.message
    np.testing.assert_allclose(info.u, expected.u, rtol=1e-12, atol=1e-15)


def test_a_stagewise_plan_beyond_the_torque_limit_is_never_applied(monkeypatch):
    """A stage-wise result that says "optimal" but whose first move breaks |u| ≤ τ, and whose rows its
    solver did not verify within the limits' gap (``excess`` inf: an interior point's, or a plan other
    than the one the active set verified), is treated as a failed solve: the condensed default replaces
    it, the message says why."""
    N = STAGEWISE_LIMITED_MIN_N
    model = DiscreteLinearModel(A, B, np.eye(4), Ts=0.1)
    ctl = GPCController.build(model, 0.1, Horizons(N), Weights(1.0, 0.1), limits=Limits(torque=0.05))
    X, w = np.array([0.1, 0.0, -0.2, 0.05]), np.zeros((N, 4))
    good = ctl._riccati.solve(*ctl._riccati.stages(ctl, X, w))
    assert good.ok

    def beyond(*args, **kwargs):
        ctl._riccati.constrained.excess = np.inf  # not the plan its solver verified
        return replace(good, v=good.v + 1.0)

    monkeypatch.setattr(ctl._riccati, "solve", beyond)
    info = ctl.step(X, w)
    assert not info.fallback and info.result.solver == DEFAULT_BOX_SOLVER
    assert "but |u[" in info.result.message and "> torque limit" in info.result.message
    assert np.all(np.abs(info.u) <= 0.05 * (1 + 1e-9))
