"""A closed loop that diverges part-way keeps its samples and says so (``SimulationResult.stopped``):
simulate, run_tracking, the track CLI (exit 3, every form's file), sweep cells and the robustness
rows; a reference outside the workspace is refused before the run with a true message."""

from __future__ import annotations

import numpy as np
import pytest

from parallel_gpc import ParallelRobot, ReducedModel, cli, load_result
from parallel_gpc.errors import FastStateError, InvalidParameterError, SingularPoseError, UnreachablePoseError
from parallel_gpc.gpc.controller import GPCController
from parallel_gpc.gpc.criterion import Weights
from parallel_gpc.gpc.prediction import Horizons
from parallel_gpc.gpc.references import Hold, SampledTrajectory
from parallel_gpc.model.plant import ReducedPlant
from parallel_gpc.studies import TrackingSettings, run_tracking, simulate
from parallel_gpc.sweeps import Cell, SweepStore, run_cell, run_sweep

HOME = np.array([0.5, 0.5, 0.0])
X_HOME = np.concatenate([HOME, np.zeros(3)])
TARGET = Hold((0.52, 0.49, 0.05))
TS = 0.005
#: A real divergence, no mock: Ts = 0.5 s on the S-curve (four samples, the plant blows up).
COARSE = {"robot": "planar_4rrr", "reference": "s-curve", "Ts": 0.5, "N": 5, "form": "absolute", "duration": 2.0}


@pytest.fixture(scope="module")
def r4():
    return ParallelRobot.load("planar_4rrr")


def controller(robot):
    return GPCController.build(ReducedModel(robot), TS, Horizons(5), Weights(1.0, 1e-4))


class PlantFailingAt(ReducedPlant):
    """A reduced plant whose ``fail_at``-th step (1-based) raises what a plant leaving the workspace raises."""

    def __init__(self, robot, X0, fail_at: int):
        super().__init__(robot, X0, Ts=TS)
        self.calls, self.fail_at = 0, fail_at

    def step(self, u):
        self.calls += 1
        if self.calls == self.fail_at:
            raise UnreachablePoseError("platform pose [9.0, 9.0, 0.0] cannot be assembled (test)")
        return super().step(u)


# ---------------------------------------------------------------- simulate
def test_a_plant_failing_mid_run_keeps_every_sample_up_to_there(r4, tmp_path):
    full = simulate(controller(r4), ReducedPlant(r4, X_HOME, Ts=TS), TARGET, 0.1, progress=False)
    res = simulate(controller(r4), PlantFailingAt(r4, X_HOME, 8), TARGET, 0.1, progress=False)
    assert full.stopped == "" and full.outcome == "ok" and len(full.t) == 20
    # the failing step's state and input are a sample: 8 rows, equal to the full run's first 8
    assert res.diverged and not res.interrupted and res.outcome == "diverged" and len(res.t) == 8
    for name in ("t", "pose", "velocity", "u", "q", "reference"):
        np.testing.assert_array_equal(getattr(res, name), getattr(full, name)[:8])
    assert res.stopped.startswith(f"closed loop diverged at t = {7 * TS:g} s after 8 of 20 samples: position error ")
    assert res.stopped.endswith("(cause: UnreachablePoseError: platform pose [9.0, 9.0, 0.0] cannot be assembled (test))")
    shown = float(res.stopped.split("position error ")[1].split(" m at t = ")[0])
    assert shown == pytest.approx(np.linalg.norm(full.error[7, :2]), rel=1e-2)  # the last sample's, x and y
    assert f" m at t = {7 * TS:g} s (cause" in res.stopped
    assert np.isfinite(res.metrics()["rms_position_error_m"])
    loaded = load_result(res.save(tmp_path / "diverged.npz"))
    assert loaded.meta["stopped"] == res.stopped and bool(loaded.arrays["diverged"])
    assert not bool(loaded.arrays["interrupted"]) and loaded.t.shape == (8,)
    np.testing.assert_array_equal(loaded.arrays["u"], full.u[:8])


def test_a_controller_failing_mid_run_keeps_the_samples_before(r4, monkeypatch):
    ctrl = controller(r4)
    real, calls = ctrl.step, []

    def step(X, w):
        calls.append(1)
        if len(calls) == 6:
            raise SingularPoseError("near-singular pose (test)")
        return real(X, w)

    monkeypatch.setattr(ctrl, "step", step)
    res = simulate(ctrl, ReducedPlant(r4, X_HOME, Ts=TS), TARGET, 0.1, progress=False)
    assert res.diverged and len(res.t) == 5
    assert res.stopped.startswith(f"closed loop diverged at t = {5 * TS:g} s after 5 of 20 samples")
    assert "(cause: SingularPoseError: near-singular pose (test))" in res.stopped


def test_a_state_too_fast_for_the_one_sample_model_mid_run_is_a_divergence(r4, monkeypatch):
    """The controller's conditioning check names a velocity that makes the one-sample model
    near-singular (FastStateError): a measurement error at the first state — raised, an
    InvalidParameterError —, a divergence mid-run (a plant moving too fast through a near-singular
    region: seen on a five-bar with a tight torque limit), whose samples before are kept."""
    ctrl = controller(r4)
    real, calls = ctrl.step, []

    def step(X, w):
        calls.append(1)
        if len(calls) in (1, 6) and fast[0] == len(calls):
            X = X.copy()
            X[r4.n_y] = 1e5  # m/s: the one-sample model's gain is near-singular at this velocity only
        return real(X, w)

    monkeypatch.setattr(ctrl, "step", step)
    fast = [6]
    res = simulate(ctrl, ReducedPlant(r4, X_HOME, Ts=TS), TARGET, 0.1, progress=False)
    assert res.diverged and len(res.t) == 5
    assert "(cause: FastStateError: measured velocity" in res.stopped and "too fast" in res.stopped
    fast[0], calls[:] = 1, []
    ctrl.reset()
    with pytest.raises(InvalidParameterError, match="measured velocity") as info:
        simulate(ctrl, ReducedPlant(r4, X_HOME, Ts=TS), TARGET, 0.1, progress=False)
    assert isinstance(info.value, FastStateError) and isinstance(info.value, SingularPoseError)


def test_a_failure_before_the_first_sample_is_raised(r4, monkeypatch):
    ctrl = controller(r4)
    monkeypatch.setattr(ctrl, "step", lambda X, w: (_ for _ in ()).throw(SingularPoseError("singular start")))
    with pytest.raises(SingularPoseError, match="singular start"):
        simulate(ctrl, ReducedPlant(r4, X_HOME, Ts=TS), TARGET, 0.1, progress=False)


def test_ctrl_c_and_divergence_are_one_mechanism(r4, monkeypatch):
    plant = ReducedPlant(r4, X_HOME, Ts=TS)
    real, calls = plant.step, []

    def step(u):
        calls.append(1)
        if len(calls) == 4:
            raise KeyboardInterrupt
        return real(u)

    monkeypatch.setattr(plant, "step", step)
    res = simulate(controller(r4), plant, TARGET, 0.1, progress=False)
    assert res.interrupted and not res.diverged and res.outcome == "interrupted"
    assert res.stopped == "interrupted (Ctrl-C) after 3 of 20 samples" and len(res.t) == 3


def test_a_real_divergence_is_kept_not_raised(r4):
    settings, form = TrackingSettings.from_flat(**{k: v for k, v in COARSE.items() if k != "form"}), COARSE["form"]
    res = run_tracking(settings, (form,), progress=False, robot=r4)[form]
    assert res.diverged and 1 <= len(res.t) <= 4, res.stopped
    assert res.stopped.startswith("closed loop diverged at t = ") and "(cause: " in res.stopped
    assert np.all(np.isfinite(res.pose)) and np.all(np.isfinite(res.u))


# ---------------------------------------------------------------- the reference
def test_a_hold_target_outside_the_workspace_is_refused_before_the_run(r4):
    settings = TrackingSettings(reference="hold", hold_pose=(5.0, 0.0, 0.0), duration=0.1)
    with pytest.raises(UnreachablePoseError, match=r"reference pose \[5.0, 0.0, 0.0\] \(x, y, psi\) at t = 0 s is "
                                                   r"outside the workspace of 'planar_4rrr'"):
        run_tracking(settings, ("absolute",), progress=False, robot=r4)


def test_a_path_leaving_the_workspace_names_the_time_it_leaves(r4):
    t = np.linspace(0.0, 1.0, 11)
    path = SampledTrajectory(t, HOME + np.outer(t, [3.0, 0.0, 0.0]))  # x from 0.5 m to 3.5 m
    with pytest.raises(UnreachablePoseError, match=r"reference pose \[.*\] \(x, y, psi\) at t = ") as info:
        simulate(controller(r4), ReducedPlant(r4, X_HOME, Ts=TS), path, 1.0, progress=False)
    t_out = float(str(info.value).split("t = ")[1].split(" s")[0])
    assert 0.0 < t_out < 1.0
    r4.assemble(path.pose(0.0))  # the start is reachable: the refusal is about where the path goes


# ---------------------------------------------------------------- CLI
def test_track_all_forms_keeps_every_form_when_one_diverges(tmp_path, monkeypatch, capsys):
    real = GPCController.step

    def step(self, X, w):  # the incremental form's controller fails at its 6th sample
        if self.form == "incremental":
            self._test_calls = getattr(self, "_test_calls", 0) + 1
            if self._test_calls == 6:
                raise SingularPoseError("near-singular pose (test)")
        return real(self, X, w)

    monkeypatch.setattr(GPCController, "step", step)
    out = tmp_path / "track"
    code = cli.main(["track", "--form", "all", "--Ts", "0.005", "--N", "5", "--Qu", "1e-4", "--reference", "hold",
                     "--duration", "0.05", "--no-progress", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 3
    assert "incremental GPC: closed loop diverged at t = 0.025 s after 5 of 10 samples" in captured.err
    assert "(diverged)" in captured.out
    for form in ("absolute", "incremental", "incremental-delayed", "nonlinear"):
        loaded = load_result(out / f"track_{form}.npz")
        if form == "incremental":
            assert loaded.t.shape == (5,) and loaded.meta["stopped"].startswith("closed loop diverged")
        else:
            assert loaded.t.shape == (10,) and loaded.meta["stopped"] == ""
    assert (out / "track_time.png").exists()


def test_track_exit_codes_are_in_its_help(capsys):
    with pytest.raises(SystemExit):
        cli.main(["track", "--help"])
    assert "3 a closed loop diverged" in " ".join(capsys.readouterr().out.split())


# ---------------------------------------------------------------- sweeps and robustness
def test_a_diverged_cell_is_a_result_not_a_failure(tmp_path):
    record = run_cell(Cell(0, dict(COARSE)))
    assert record["status"] == "diverged" and record["error"].startswith("closed loop diverged at t = ")
    assert np.isfinite(record["rms_position_error_m"]) and 1 <= record["steps"] <= 4
    cells = [Cell(0, dict(COARSE)), Cell(1, {**COARSE, "mass_scale": -1.0})]
    first = run_sweep(cells, workers=0, store=tmp_path, progress=False)
    assert (first.diverged, first.failed) == (1, 1)
    assert [r["status"] for r in first.records] == ["diverged", "failed"]
    assert set(SweepStore(tmp_path).finished(retry_failed=True)) == {cells[0].key}  # not retried
    again = run_sweep(cells, workers=0, store=tmp_path, progress=False, retry_failed=True)
    assert (again.ran, again.skipped) == (1, 1)


def test_robustness_rows_of_diverged_runs_name_cause_and_time(monkeypatch):
    from parallel_gpc.sweeps import robustness_study
    from parallel_gpc.sweeps import robustness as study

    real = study.run_sweep

    def run_sweep(cells, **kwargs):  # the lighter plant's run fails at its 4th plant step
        def func(cell):
            if cell.params["mass_scale"] != 1.0:
                return run_cell(Cell(cell.index, {**cell.params, "Ts": 0.5, "duration": 2.0,
                                                  "reference": "s-curve"}))
            return run_cell(cell)
        return real(cells, func=func, **kwargs)

    monkeypatch.setattr(study, "run_sweep", run_sweep)
    result = robustness_study(forms=("absolute",), mass_scales=(0.7,), noise_levels=(), disturbances=(),
                              duration=0.05, reference="hold")
    status = [r["status"] for r in result.rows]
    assert status[0] == "ok" and status[1].startswith("diverged (") and " at t = " in status[1], status


def test_a_plant_failing_within_the_first_sample_is_raised(r4):
    with pytest.raises(UnreachablePoseError, match=r"\(test\)"):
        simulate(controller(r4), PlantFailingAt(r4, X_HOME, 1), TARGET, 0.1, progress=False)
    res = simulate(controller(r4), PlantFailingAt(r4, X_HOME, 2), TARGET, 0.1, progress=False)
    assert res.diverged and len(res.t) == 2
