"""Vectorized reference windows and samples against the pose-by-pose evaluation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from parallel_gpc.gpc.references import Helix, Hold, SampledTrajectory, SCurve, path_for, quintic, quintic_array

TS = 1e-3  # s


def _pose_by_pose(ref, t: float, Ts: float, N: int) -> np.ndarray:
    """The window as N separate pose() calls (the definition: poses at t + Ts … t + N·Ts)."""
    return np.array([ref.pose(t + (j + 1) * Ts) for j in range(N)])


REFERENCES = {
    "s-curve": SCurve(duration=2.0, t_start=0.3),
    "helix-with-angles": path_for("helix", [0.1, -0.05, 0.6, 0.02, -0.01, 0.0],
                                  [False, False, False, True, True, True], 2.0),
    "helix-positions-only": Helix((0.0, 0.1, 0.5), turns=1.5, rise=-0.1, duration=1.0),
    "helix-columns-permuted": Helix((0.2, 0.4, 0.1, -0.3), position_columns=(3, 0, 1),
                                    angle_amplitude=(0.2,), duration=1.5),
    "hold": Hold((0.55, 0.55, math.radians(5.0))),
    "sampled": SampledTrajectory(np.linspace(0.0, 1.0, 7), np.random.default_rng(0).normal(size=(7, 3))),
}


@pytest.mark.parametrize("name", list(REFERENCES))
def test_window_equals_pose_by_pose(name):
    """Before the start, across the S-curve's switch of half circles (s = 0.5), at the end and
    after it, with several horizons and sample times."""
    ref = REFERENCES[name]
    for t in (-0.05, 0.0, 0.3, 0.77, 1.29, 1.3, 1.3005, 1.9, 2.29, 2.3, 3.0):
        for Ts, N in ((TS, 20), (0.01, 7), (0.05, 40), (TS, 1)):
            w = ref.window(t, Ts, N)
            expected = _pose_by_pose(ref, t, Ts, N)
            assert w.shape == expected.shape
            np.testing.assert_allclose(w, expected, rtol=0, atol=1e-14)


def test_window_moves_and_crosses_the_half_circle_switch():
    """The S-curve window is not constant and spans both half circles around the switch."""
    ref = SCurve(duration=2.0)
    t_mid = 1.0  # quintic symmetric: s = 0.5 at half the duration
    w = ref.window(t_mid - 0.01, TS, 20)
    s = quintic_array((t_mid - 0.01 + TS * np.arange(1, 21)) / 2.0)
    assert s.min() < 0.5 < s.max()
    assert np.ptp(w[:, 0]) > 1e-6 and np.ptp(w[:, 2]) > 1e-6


@pytest.mark.parametrize("name", list(REFERENCES))
def test_sample_equals_pose_by_pose(name):
    ref = REFERENCES[name]
    times = np.linspace(-0.5, 3.5, 57)
    np.testing.assert_allclose(ref.sample(times), np.array([ref.pose(float(t)) for t in times]), rtol=0, atol=1e-14)


def test_quintic_array_equals_quintic():
    tau = np.linspace(-0.5, 1.5, 401)
    # x**3 of numpy and of Python may round differently in the last bit
    np.testing.assert_allclose(quintic_array(tau), [quintic(float(x)) for x in tau], rtol=0, atol=1e-15)
