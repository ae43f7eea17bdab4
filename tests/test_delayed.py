"""The delayed incremental form (8)–(9) as printed, in closed loop: a controller whose increment
is realized one sample later, on a plant with a one-sample input delay."""

from __future__ import annotations

import numpy as np
import pytest

from parallel_gpc.limits import Limits
from parallel_gpc.errors import InvalidParameterError
from parallel_gpc.gpc import DiscreteLinearModel, GPCController, Horizons, Weights

TS = 0.01


def _system(seed=3):
    rng = np.random.default_rng(seed)
    A = np.eye(4) + 0.05 * rng.normal(size=(4, 4))
    B = rng.normal(size=(4, 2))
    C = rng.normal(size=(2, 4))
    c = 0.01 * rng.normal(size=4)
    return A, B, C, c


class DelayedInputPlant:
    """x(k+1) = A x(k) + B u_applied(k) + c with u_applied(k) = the command issued at k−1."""

    def __init__(self, A, B, c, x0, u0):
        self.A, self.B, self.c = A, B, c
        self.x = np.asarray(x0, dtype=float)
        self.pending = np.asarray(u0, dtype=float)  # the command realized at the next sample

    def step(self, command):
        applied = self.pending
        self.x = self.A @ self.x + self.B @ applied + self.c
        self.pending = np.asarray(command, dtype=float)
        return applied


def test_delayed_controller_on_a_one_sample_delay_plant_matches_its_own_prediction():
    """At every step the controller applies u(k) (decided at k−1) and issues u(k+1) = u(k) + Δu(k)
    for the next sample: exactly what a plant with a one-sample input delay realizes. The
    plant's next state equals the controller's one-step prediction, and the outputs of the plan
    followed open loop through the delay equal the prediction ŷ = f + G v."""
    A, B, C, c = _system()
    model = DiscreteLinearModel(A, B, C, c, Ts=TS)
    H = Horizons(12, 0, 12)
    ctrl = GPCController.build(model, TS, H, Weights(1.0, 0.05), form="incremental-delayed", disturbance_gain=0.0)
    x0 = np.zeros(4)
    plant = DelayedInputPlant(A, B, c, x0, np.zeros(2))
    w = np.tile([1.0, -0.5], (H.N, 1))
    for _ in range(15):
        info = ctrl.step(plant.x, w)
        command = ctrl.state.plan[1]  # u(k+1), to be realized at k+1
        applied = plant.step(command)
        np.testing.assert_array_equal(info.u, applied)  # the controller applied what the delay line holds
        np.testing.assert_allclose(plant.x, ctrl.state.x_next, rtol=0, atol=1e-12)
    # open loop: the plan, fed through the delay line, reproduces the predicted outputs
    X = plant.x.copy()
    pred = ctrl.predict(X)
    info = ctrl.step(X, w)
    plan = ctrl.state.plan  # u(k), u(k+1), …, u(k+N−1)
    sim = DelayedInputPlant(A, B, c, X, plan[0])
    ys = []
    for i in range(H.N):
        sim.step(plan[i + 1] if i + 1 < H.N else plan[-1])
        ys.append(C @ sim.x)
    np.testing.assert_allclose(pred.outputs(info.result.v), np.concatenate(ys), rtol=0, atol=1e-10)


def test_undelayed_controller_mismatches_a_one_sample_delay_plant():
    """The oracle above can fail: the undelayed form's one-step prediction is wrong on the
    delayed plant (it assumes u(k) acts at once)."""
    A, B, C, c = _system()
    ctrl = GPCController.build(DiscreteLinearModel(A, B, C, c, Ts=TS), TS, Horizons(12), Weights(1.0, 0.05),
                         form="incremental", disturbance_gain=0.0)
    plant = DelayedInputPlant(A, B, c, np.zeros(4), np.zeros(2))
    worst = 0.0
    for _ in range(10):
        info = ctrl.step(plant.x, np.tile([1.0, -0.5], (12, 1)))
        plant.step(info.u)
        worst = max(worst, float(np.max(np.abs(plant.x - ctrl.state.x_next))))
    assert worst > 1e-3


def test_delayed_form_needs_two_samples_of_horizon():
    A, B, C, c = _system()
    with pytest.raises(InvalidParameterError, match="N ≥ 2"):
        GPCController.build(DiscreteLinearModel(A, B, C, c, Ts=TS), TS, Horizons(1), form="incremental-delayed")


def test_delayed_controller_respects_increment_and_torque_limits():
    """|u(k+1) − u(k)| ≤ δ and |u| ≤ τ on the applied sequence, with no fallback (measured: the
    increment limit binds at 0.05 N·m per sample)."""
    A, B, C, c = _system()
    ctrl = GPCController.build(DiscreteLinearModel(A, B, C, c, Ts=TS), TS, Horizons(10), Weights(1.0, 0.01),
                         form="incremental-delayed", limits=Limits(du=0.05, torque=1.0))
    x, us = np.zeros(4), []
    for _ in range(30):
        info = ctrl.step(x, np.tile([1.0, -0.5], (10, 1)))
        assert not info.fallback
        us.append(info.u)
        x = A @ x + B @ info.u + c
    steps = np.abs(np.diff(us, axis=0))
    assert steps.max() <= 0.05 * (1 + 1e-6) and steps.max() >= 0.05 * (1 - 1e-3)
    assert np.abs(us).max() <= 1.0
