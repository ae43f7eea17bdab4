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


def _failing_every(n: int, monkeypatch):
    """Make every n-th stage-wise solve (RiccatiPath.solve, from the first) fail visibly."""
    from dataclasses import replace

    from parallel_gpc.gpc.riccati import RiccatiPath

    solve, calls = RiccatiPath.solve, [0]

    def failing(self, *args, **kwargs):
        result = solve(self, *args, **kwargs)
        calls[0] += 1
        if calls[0] % n == 1 or n == 1:
            return replace(result, v=np.full_like(result.v, np.nan), status="failed",
                           message="R + BᵀPB is not positive definite")
        return result

    monkeypatch.setattr(RiccatiPath, "solve", failing)


def test_a_replaced_stagewise_step_is_recorded_saved_and_summarized(robot4, monkeypatch, tmp_path):
    """Field test: a step where riccati failed and the condensed default replaced it was visible in
    StepInfo.result only; the run records, per step, the back end that solved it, whether it
    replaced a failed stage-wise solve and why, saves them, and summarizes them in one line."""
    from parallel_gpc.results import load_result

    _failing_every(3, monkeypatch)
    reference = SCurve(duration=0.5)
    ctrl = GPCController.build(ReducedModel(robot4), TS, Horizons(10), Weights(1.0, 1e-5), solver="riccati")
    plant = ConstrainedPlant(robot4, reference.initial_state(), Ts=TS)
    res = simulate(ctrl, plant, reference, 0.07, progress=False)
    expected = np.arange(7) % 3 == 0  # steps 0, 3, 6: their stage-wise solve failed
    np.testing.assert_array_equal(res.replaced, expected)
    assert list(res.solver) == ["qr" if e else "riccati" for e in expected]
    assert all(m.startswith("riccati failed (R + BᵀPB is not positive definite); solved by QR")
               for m in res.message[expected]) and not any(res.message[~expected])
    assert not res.fallback.any() and res.metrics()["replaced_steps"] == 3
    assert res.solver_summary().startswith("riccati 4, qr 3; 3 replaced; 0 fallbacks; first at t = 0.000 s: "
                                           "riccati failed (R + BᵀPB")
    saved = load_result(res.save(tmp_path / "run.npz")).arrays
    np.testing.assert_array_equal(saved["replaced"], expected)
    assert list(saved["solver"]) == list(res.solver) and list(saved["message"]) == list(res.message)


def test_track_prints_which_solver_solved_the_steps(monkeypatch, tmp_path, capsys):
    from parallel_gpc import cli

    _failing_every(1, monkeypatch)  # every stage-wise solve fails: QR solves every step
    assert cli.main(["track", "--forms", "absolute", "--solver", "riccati", "--duration", "0.03", "--Ts", "0.01",
                     "--N", "4", "--Qu", "1e-4", "--reference", "hold", "--limits", "none", "--no-progress",
                     "--out", str(tmp_path)]) == 0
    line = next(s for s in capsys.readouterr().out.splitlines() if s.startswith("solvers, absolute:"))
    assert line.startswith("solvers, absolute: qr 3; 3 replaced; 0 fallbacks; first at t = 0.000 s: riccati failed")
