"""The converged nonlinear MPC in tracking runs, sweeps and on the command line: ``TrackingSettings``'
iterations, tolerance and time budget reach the nonlinear form's controller (and no other form's), every
step's Gauss–Newton record (iterations, last relative step, budget hit) is kept in the result and its
file, and bad values are refused where they enter, before any run."""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from parallel_gpc import (ConstrainedPlant, GPCController, GPCSettings, Horizons, ParallelRobot, ReducedModel,
                          TrackingSettings, Weights)
from parallel_gpc.errors import InvalidParameterError
from parallel_gpc.results import load_result
from parallel_gpc.studies import run_tracking
from parallel_gpc.sweeps.spec import cell_settings

ROOT = Path(__file__).resolve().parents[1]
BASE = dict(N=10, Qu=1e-3, duration=0.024, reference="line", check_reference=False)  # 12 steps of 2 ms


def _run(forms=("nonlinear",), **kw):
    return run_tracking(TrackingSettings.from_flat(**{**BASE, **kw}), forms=forms, progress=False)


def test_iterations_reach_the_nonlinear_form_only_and_its_record_is_the_controllers():
    res = _run(forms=("absolute", "nonlinear"), iterations=20)
    absolute, nonlinear = res["absolute"], res["nonlinear"]
    assert np.all(absolute.nmpc_iterations == 1) and np.all(np.isnan(absolute.nmpc_residual))
    assert "iterations" not in absolute.meta and absolute.iterations_summary() == ""
    assert nonlinear.meta["iterations"] == 20 and nonlinear.meta["tolerance"] == 1e-8
    assert nonlinear.nmpc_iterations.max() > 1 and not nonlinear.budget_hit.any()
    # oracle: the same closed loop stepped here, a controller built from GPCSettings directly
    robot = ParallelRobot.load("planar_4rrr")
    s = TrackingSettings.from_flat(**BASE)
    ctrl = GPCController(ReducedModel(robot), GPCSettings(s.Ts, Horizons(10), Weights(1.0, 1e-3), "nonlinear",
                                                          disturbance_gain=0.5, iterations=20))
    ref = s.make_reference(robot)
    plant = ConstrainedPlant(robot, np.concatenate([ref.pose(0.0), np.zeros(3)]), Ts=s.Ts)
    its, resid = [], []
    for k in range(len(nonlinear.t)):
        info = ctrl.step(plant.X, ref.sample(k * s.Ts + s.Ts * np.arange(1, 11)))
        its.append(info.iterations)
        resid.append(info.residual)
        plant.step(info.u)
    assert its == nonlinear.nmpc_iterations.tolist()
    assert np.allclose(resid, nonlinear.nmpc_residual, rtol=0, atol=1e-9, equal_nan=True)  # ≤ 1e-8: converged
    assert nonlinear.nmpc_stop.tolist() == ["converged"] * len(its) and set(absolute.nmpc_stop) == {"iterations"}
    summary = nonlinear.solver_summary()
    assert f"max {max(its)}" in summary and f"stopped: converged {len(its)}" in summary


def test_the_tolerance_and_the_time_budget_reach_the_iterations():
    loose, tight = _run(iterations=20, tolerance=1e-2)["nonlinear"], _run(iterations=20, tolerance=1e-12)["nonlinear"]
    assert loose.nmpc_iterations.sum() < tight.nmpc_iterations.sum()
    assert loose.meta["tolerance"] == 1e-2
    rushed = _run(iterations=20, time_budget=1e-9)["nonlinear"]  # no second iteration fits: the paper's step, applied
    assert rushed.budget_hit.all() and np.all(rushed.nmpc_iterations == 1) and not rushed.fallback.any()
    assert f"stopped: time budget {len(rushed.t)}" in rushed.solver_summary()


def test_the_result_file_keeps_every_steps_iterations(tmp_path):
    res = _run(iterations=20)["nonlinear"]
    back = load_result(res.save(tmp_path / "run.npz"))
    assert np.array_equal(back.arrays["nmpc_iterations"], res.nmpc_iterations)
    assert np.array_equal(back.arrays["budget_hit"], res.budget_hit)
    assert np.array_equal(back.arrays["nmpc_stop"], res.nmpc_stop)
    assert back.meta["iterations"] == 20


@pytest.mark.parametrize("kw,word", [
    (dict(iterations=0), "iterations"), (dict(iterations=2.0), "iterations"), (dict(iterations=True), "iterations"),
    (dict(tolerance=0.0), "tolerance"), (dict(tolerance=float("nan")), "tolerance"),
    (dict(time_budget=-1.0), "time_budget"),
])
def test_bad_iteration_settings_are_refused_where_they_enter(kw, word):
    with pytest.raises(InvalidParameterError, match=word):
        TrackingSettings.from_flat(**kw)


def test_iterations_without_the_nonlinear_form_are_refused_before_any_run():
    with pytest.raises(InvalidParameterError, match="nonlinear"):
        _run(forms=("absolute", "incremental"), iterations=3)


def test_a_sweep_cell_sets_the_iterations_and_the_settings_round_trip():
    settings, form = cell_settings({"iterations": 4, "tolerance": 1e-6, "time_budget": 0.001})
    assert (settings.iterations, settings.tolerance, settings.time_budget, form) == (4, 1e-6, 0.001, "nonlinear")
    assert TrackingSettings.from_flat(**settings.flat()).flat() == settings.flat()
    assert TrackingSettings().controller_settings("nonlinear").tolerance == GPCSettings(0.002, Horizons(5)).tolerance


def test_the_command_line_iterates_and_refuses_iterations_without_the_nonlinear_form(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"), MPLBACKEND="Agg")
    cmd = [sys.executable, "-m", "parallel_gpc", "track", "--N", "10", "--Qu", "1e-3", "--duration", "0.02",
           "--reference", "line", "--no-progress", "--out", str(tmp_path)]
    for args, word in ((["--forms", "absolute", "--iterations", "3"], "nonlinear"),
                       (["--forms", "nonlinear", "--time-budget", "0.001"], "--iterations K > 1")):
        bad = subprocess.run([*cmd, *args], capture_output=True, text=True, env=env, timeout=120)
        assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1 and word in bad.stderr
    done = subprocess.run([*cmd, "--forms", "nonlinear", "--iterations", "20", "--tolerance", "1e-9"],
                          capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    line = next(x for x in done.stdout.splitlines() if x.startswith("solvers, nonlinear"))
    assert "Gauss–Newton iterations" in line and "stopped: converged" in line
    assert load_result(tmp_path / "track_nonlinear.npz").meta["tolerance"] == 1e-9


def test_an_encoder_run_chooses_the_default_solver_as_the_full_state_run():
    # the machine path turns the controller's own disturbance estimate off (a changed copy of its settings):
    # the default back end is chosen again for the copy, not kept as if given (the iterations' Riccati steps)
    enc = _run(iterations=20, sensors="encoders")["nonlinear"]
    full = _run(iterations=20)["nonlinear"]
    assert set(enc.solver) == set(full.solver)  # the Riccati steps with the compiled core, QR on the Python path
    assert enc.meta["disturbance_gain"] == 0.0


def test_a_changed_copy_chooses_a_default_solver_again_and_keeps_a_given_one():
    s = GPCSettings(0.002, Horizons(10), Weights(1.0, 1e-3), "nonlinear", iterations=5)
    c = s.changed(disturbance_gain=0.0)
    assert s.solver_is_default and c.solver_is_default and c.disturbance_gain == 0.0
    assert (c.solver, c.step_solver) == (s.solver, s.step_solver)
    assert not replace(s, disturbance_gain=0.0).solver_is_default  # what the machine path did before
    given = GPCSettings(0.002, Horizons(10), Weights(1.0, 1e-3), "nonlinear", solver="qr", iterations=5)
    assert given.changed(disturbance_gain=0.0).solver == "qr" and not given.changed(disturbance_gain=0.0).solver_is_default
    assert s.changed(solver="qr").solver == "qr"
