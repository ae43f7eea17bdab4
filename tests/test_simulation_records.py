"""simulate()'s lean records: the batched reference windows and internal-force record against
the per-sample computations they replace."""

from __future__ import annotations

import numpy as np
import pytest

from parallel_gpc import GPCController, Horizons, ReducedModel, Weights
from parallel_gpc.gpc.references import SCurve
from parallel_gpc.model.plant import ConstrainedPlant
from parallel_gpc.studies import simulation
from parallel_gpc.studies import null_space_component, null_space_components, simulate

TS = 0.01  # s


class PoseByPose(SCurve):
    """The S-curve with its own window(): simulate() then asks it sample by sample."""

    def window(self, t, Ts, N):
        return np.array([self.pose(t + (j + 1) * Ts) for j in range(N)])


def _run(robot, reference, duration):
    ctrl = GPCController.build(ReducedModel(robot), TS, Horizons(10), Weights(1.0, 1e-5))
    plant = ConstrainedPlant(robot, reference.initial_state(), Ts=TS)
    return simulate(ctrl, plant, reference, duration, progress=False)


def test_batched_windows_and_records_equal_the_per_sample_ones(robot4, monkeypatch):
    """Chunks of 7 samples (the chunk boundary inside the run, a last partial chunk) against a
    reference whose own window() is called at every sample, and the internal force against
    null_space_component of each sample's B_r and u."""
    monkeypatch.setattr(simulation, "_WINDOW_CHUNK", 7)
    fast = _run(robot4, SCurve(duration=0.5), 0.3)
    slow = _run(robot4, PoseByPose(duration=0.5), 0.3)
    assert len(fast.t) == 30 and np.ptp(fast.reference[:, 0]) > 1e-3  # a moving reference
    np.testing.assert_allclose(fast.reference, [SCurve(duration=0.5).pose(t) for t in fast.t], rtol=0, atol=1e-14)
    np.testing.assert_allclose(fast.reference, slow.reference, rtol=0, atol=1e-14)
    # windows equal to the last bit or two (np.cos vs math.cos); the controller's gain (Qu = 1e-5)
    # maps 1e-16 m of reference into ~1e-11 N·m of u: the states follow to rounding
    for name in ("pose", "velocity", "u", "q"):
        np.testing.assert_allclose(getattr(fast, name), getattr(slow, name), rtol=1e-10, atol=1e-12, err_msg=name)
    # the absolute form's u lies in the range of B_rᵀ: its internal force is rounding, ~1e-13 ‖u‖
    rounding = 1e-11 * np.abs(fast.u).max()
    np.testing.assert_allclose(fast.internal_force, slow.internal_force, rtol=0, atol=rounding)
    plant = ConstrainedPlant(robot4, SCurve(duration=0.5).initial_state(), Ts=TS)
    expected = []
    for k in range(len(fast.t)):  # replay the recorded states: B_r at each, with the recorded u
        plant.q, plant.v = fast.q[k], robot4.velocity_map(fast.q[k])[0] @ fast.velocity[k]
        plant._T = robot4.velocity_map(fast.q[k])[0]
        expected.append(null_space_component(plant.input_matrix(), fast.u[k]))
    np.testing.assert_allclose(fast.internal_force, expected, rtol=1e-10, atol=rounding)


def test_batched_null_space_components_equal_the_single_ones():
    rng = np.random.default_rng(4)
    B = rng.normal(size=(40, 3, 4))
    B[5, 2] = B[5, 1]  # rank 2: a 2-D null space
    B[6] = 0.0  # no range at all: the whole u is internal
    B[7, :, 3] = 0.0  # a drive without effect
    u = rng.normal(size=(40, 4)) * 5.0
    got = null_space_components(B, u)
    expected = [null_space_component(b, x) for b, x in zip(B, u)]
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-13)
    assert got[6] == pytest.approx(np.linalg.norm(u[6]))
    assert got[7] >= abs(u[7, 3]) - 1e-12  # the drive without effect is all internal
    assert np.all(got > 0)
