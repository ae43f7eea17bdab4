"""Sweeps: spec expansion, cell runs against the closed loop and an energy balance, failure
records, resume, Ctrl-C, the tidy table, plots, the CLI, and serial vs a real LocalCluster."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from parallel_gpc.errors import InvalidParameterError
from parallel_gpc.sweeps import (
    METRIC_COLUMNS,
    TIMING_COLUMNS,
    Cell,
    cell_settings,
    drive_q_indices,
    drive_work,
    load_spec,
    run_cell,
)
from parallel_gpc.sweeps import run_sweep
from parallel_gpc.sweeps import SweepStore, load_results

ROBOTS = Path(__file__).resolve().parents[1] / "urdf"
#: Tiny runs: hold of the home pose offset by the default hold pose, 0.1 s at Ts = 5 ms, N = 4.
TINY = {"robot": "planar_3rrr", "reference": "hold", "duration": 0.1, "Ts": 0.005, "N": 4, "Qu": 1e-4}

SPEC_TOML = """
[sweep]
name = "tiny"
samples = 2
seed = 7

[base]
robot = "planar_3rrr"
reference = "hold"
duration = 0.1
Ts = 0.005
Qu = 1e-4

[grid]
form = ["absolute", "nonlinear"]
N = [3, 5]

[random]
noise_std = {loguniform = [1e-6, 1e-4]}
seed = {integers = [0, 1000]}
"platform_force[0]" = {uniform = [-5.0, 5.0]}
"""


def tiny_spec(**grid):
    grid = grid or {"form": ["absolute", "nonlinear"]}
    return load_spec({"base": {k: v for k, v in TINY.items() if k not in grid}, "grid": grid})


def deterministic(frame):
    """The columns of a result table that do not depend on machine speed."""
    return frame[[c for c in frame.columns if c not in TIMING_COLUMNS]]


# ---------------------------------------------------------------- spec and cells
def test_toml_spec_expands_grid_times_samples(tmp_path):
    path = tmp_path / "tiny.toml"
    path.write_text(SPEC_TOML)
    spec = load_spec(path)
    cells = spec.cells()
    assert spec.name == "tiny" and spec.axes == ("form", "N", "noise_std", "seed", "platform_force[0]")
    assert len(cells) == 2 * 2 * 2
    # grid product, last axis fastest, the random draws repeated for every grid point
    assert [(c.params["form"], c.params["N"]) for c in cells[::2]] == [
        ("absolute", 3), ("absolute", 5), ("nonlinear", 3), ("nonlinear", 5)]
    draws = [(c.params["noise_std"], c.params["seed"], c.params["platform_force[0]"]) for c in cells]
    assert draws[0::2] == [draws[0]] * 4 and draws[1::2] == [draws[1]] * 4 and draws[0] != draws[1]
    for noise, seed, force in draws:
        assert 1e-6 <= noise <= 1e-4 and 0 <= seed < 1000 and isinstance(seed, int) and -5 <= force <= 5
    assert all(c.params["Qu"] == 1e-4 for c in cells)
    assert len({c.key for c in cells}) == len(cells)
    # the same spec gives the same cells and keys; another seed other draws
    assert [c.key for c in load_spec(path).cells()] == [c.key for c in cells]
    other = load_spec({**spec.to_dict(), "sweep": {**spec.to_dict()["sweep"], "seed": 8}})
    assert other.cells()[0].params["noise_std"] != cells[0].params["noise_std"]


def test_cell_key_ignores_order_and_index():
    a = Cell(0, {"N": 5, "form": "absolute"})
    assert a.key == Cell(9, {"form": "absolute", "N": 5}).key != Cell(0, {"N": 6, "form": "absolute"}).key


@pytest.mark.parametrize("tables, words", [
    ({"grid": {"Nx": [1]}}, ["'Nx'", "valid"]),
    ({"grid": {"N": []}}, ["N", "non-empty"]),
    ({"base": {"N": 5}, "grid": {"N": [5, 6]}}, ["['N']", "both"]),
    ({"random": {"Qu": {"uniform": [0, 1]}}}, ["samples"]),
    ({"sweep": {"samples": 2}, "random": {"Qu": {"gauss": [0, 1]}}}, ["Qu", "uniform"]),
    ({"sweep": {"samples": 2}, "random": {"Qu": {"uniform": [1, 0]}}}, ["lo < hi"]),
    ({"sweep": {"samples": 2}, "random": {"Qu": {"loguniform": [0, 1]}}}, ["lo > 0"]),
    ({"sweep": {"samples": -1}}, ["samples = -1"]),
    ({"sweep": {"workers": 2}}, ["workers"]),
    ({"plot": {}}, ["plot", "valid"]),
])
def test_bad_specs_name_the_problem(tables, words):
    with pytest.raises(InvalidParameterError) as info:
        load_spec(tables)
    assert all(w in str(info.value) for w in words), str(info.value)


def test_bad_toml_is_one_error(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text("[grid\nN = [1]")
    with pytest.raises(InvalidParameterError, match="not valid TOML"):
        load_spec(path)


def test_cell_settings_vector_elements_and_velocity_noise():
    settings, form = cell_settings({"platform_force[0]": 5.0, "noise_std": 1e-5, "velocity_noise_std": 2e-3,
                                    "form": "incremental"}, n_y=3)
    assert form == "incremental" and settings.platform_force == (5.0, 0.0, 0.0)
    assert settings.noise_std == (1e-5,) * 3 + (2e-3,) * 3
    assert cell_settings({"noise_std": 0.0, "velocity_noise_std": 0.0})[0].noise_std == 0.0
    with pytest.raises(InvalidParameterError, match="indices 0…2"):
        cell_settings({"platform_force[3]": 1.0})
    with pytest.raises(InvalidParameterError, match="N is not a vector"):
        cell_settings({"N[0]": 5})
    with pytest.raises(InvalidParameterError, match="set whole"):
        cell_settings({"platform_force": [1.0, 0.0, 0.0], "platform_force[0]": 2.0})


# ---------------------------------------------------------------- one cell
def test_run_cell_matches_the_closed_loop_and_keeps_the_trajectory_on_request(robot3):
    from parallel_gpc.studies import run_tracking

    params = {**TINY, "form": "incremental", "noise_std": 1e-5, "seed": 3}
    record = run_cell(Cell(4, params, trajectory=True))
    assert record["status"] == "ok" and record["error"] == "" and record["index"] == 4
    settings, form = cell_settings(params)
    direct = run_tracking(settings, forms=(form,), progress=False, robot=robot3)[form]
    np.testing.assert_array_equal(record["trajectory"].u, direct.u)  # same seed, same noise, same run
    for key, value in direct.metrics().items():
        if key not in TIMING_COLUMNS:
            assert record[key] == value, key
    assert record["steps"] == 20 and set(METRIC_COLUMNS) <= set(record)
    assert "trajectory" not in run_cell(Cell(4, params))


def test_drive_work_balances_the_kinetic_energy(robot3):
    """Oracle: with no external force and gravity normal to the plane, the drives' signed work
    up to t_k equals the kinetic energy ½ ẏᵀ M_r ẏ gained (M_r from the reduced model)."""
    from parallel_gpc import ReducedModel

    params = {"robot": "planar_3rrr", "reference": "s-curve", "s_curve_duration": 0.3, "duration": 0.4,
              "Ts": 0.002, "N": 10, "Qu": 1e-4, "form": "nonlinear"}
    record = run_cell(Cell(0, params, trajectory=True))
    res = record["trajectory"]
    work = drive_work(res, drive_q_indices(robot3))
    model = ReducedModel(robot3)
    kinetic = np.array([0.5 * v @ model.terms_at_q(q, v).M_r @ v for q, v in zip(res.q, res.velocity)])
    assert kinetic.max() > 50.0  # the run does move: ~120 J at the S-curve's middle
    np.testing.assert_allclose(np.cumsum(work.sum(axis=1)), kinetic[1:] - kinetic[0], atol=1e-3 * kinetic.max())
    assert record["drive_energy_J"] == pytest.approx(np.abs(work).sum(), rel=1e-12)
    assert record["drive_energy_J"] >= 2 * kinetic.max()  # accelerate, then brake


def test_the_robot_is_an_axis_like_any_other():
    """A planar and a spatial robot in one sweep; a force element beyond the planar robot's 3 outputs
    fails that cell only, with the index range in the message."""
    result = run_sweep(tiny_spec(robot=["planar_3rrr", "delta_3rus", "hexapod_6ups"]), workers=0, progress=False)
    assert [r["status"] for r in result.records] == ["ok"] * 3
    assert all(math.isfinite(r["drive_energy_J"]) and r["drive_energy_J"] > 0 for r in result.records)
    base = {k: v for k, v in TINY.items() if k != "robot"}
    wide = run_sweep(load_spec({"base": {**base, "platform_force[5]": 1.0},
                                "grid": {"robot": ["planar_3rrr", "hexapod_6ups"]}}), workers=0, progress=False)
    assert [r["status"] for r in wide.records] == ["failed", "ok"]
    assert "indices 0…2" in wide.records[0]["error"]


def test_a_failing_cell_is_recorded_and_the_sweep_goes_on():
    result = run_sweep(tiny_spec(mass_scale=[1.0, -1.0]), workers=0, progress=False)
    assert result.ran == 2 and result.failed == 1 and not result.interrupted
    ok, bad = result.records
    assert ok["status"] == "ok" and math.isfinite(ok["rms_position_error_m"])
    assert bad["status"] == "failed" and bad["error"].startswith("InvalidParameterError: mass_scale = -1.0")
    assert all(math.isnan(bad[k]) for k in METRIC_COLUMNS)


# ---------------------------------------------------------------- store, resume, Ctrl-C
def _counting(calls):
    def func(cell):
        calls.append(cell.key)
        return run_cell(cell)
    return func


def test_resume_skips_finished_cells_and_runs_only_new_ones(tmp_path):
    calls = []
    first = run_sweep(tiny_spec(N=[3, 4]), workers=0, store=tmp_path, progress=False, func=_counting(calls))
    assert (first.ran, first.skipped, len(calls)) == (2, 0, 2)
    again = run_sweep(tiny_spec(N=[3, 4]), workers=0, store=tmp_path, progress=False, func=_counting(calls))
    assert (again.ran, again.skipped, len(calls)) == (0, 2, 2)
    assert deterministic(again.frame()).equals(deterministic(first.frame()))
    wider = run_sweep(tiny_spec(N=[3, 4, 5]), workers=0, store=tmp_path, progress=False, func=_counting(calls))
    assert (wider.ran, wider.skipped, len(calls)) == (1, 2, 3)
    table = load_results(tmp_path)
    assert list(table["N"]) == [3, 4, 5] and list(table["index"]) == [0, 1, 2]


def test_failed_cells_are_retried_only_on_request(tmp_path):
    spec = tiny_spec(mass_scale=[1.0, -1.0])
    run_sweep(spec, workers=0, store=tmp_path, progress=False)
    assert run_sweep(spec, workers=0, store=tmp_path, progress=False).ran == 0
    assert run_sweep(spec, workers=0, store=tmp_path, progress=False, retry_failed=True).ran == 1


def test_ctrl_c_keeps_finished_cells_and_a_rerun_resumes(tmp_path):
    spec = tiny_spec(N=[3, 4, 5, 6])
    seen = []

    def interrupt_at_second(record):
        seen.append(record["key"])
        if len(seen) == 2:
            raise KeyboardInterrupt

    stopped = run_sweep(spec, workers=0, store=tmp_path, progress=False, on_record=interrupt_at_second)
    assert stopped.interrupted and stopped.ran == 2 and len(stopped.records) == 2
    assert set(SweepStore(tmp_path).finished()) == set(seen)
    assert len(load_results(tmp_path)) == 2
    calls = []
    resumed = run_sweep(spec, workers=0, store=tmp_path, progress=False, func=_counting(calls))
    assert (resumed.ran, resumed.skipped) == (2, 2) and not resumed.interrupted
    assert not set(calls) & set(seen)
    assert list(load_results(tmp_path)["N"]) == [3, 4, 5, 6]


def test_an_interrupted_run_stops_the_sweep_and_is_not_journalled(tmp_path):
    cells = tiny_spec(N=[3, 4, 5]).cells()

    def func(cell):
        record = run_cell(cell)
        if cell.index == 1:  # Ctrl-C inside simulate: a partial record
            record["status"] = "interrupted"
        return record

    result = run_sweep(cells, workers=0, store=tmp_path, progress=False, func=func)
    assert result.interrupted and result.ran == 2
    assert set(SweepStore(tmp_path).finished()) == {cells[0].key}


def test_table_round_trips_through_parquet_and_csv(tmp_path):
    result = run_sweep(tiny_spec(mass_scale=[1.0, -1.0], form=["absolute"]), workers=0, store=tmp_path,
                       progress=False)
    parquet, csv = load_results(tmp_path / "results.parquet"), load_results(tmp_path / "results.csv")
    for table in (parquet, csv):
        assert list(table["status"]) == ["ok", "failed"] and list(table["mass_scale"]) == [1.0, -1.0]
        np.testing.assert_array_equal(table["rms_position_error_m"], result.frame()["rms_position_error_m"])
    with pytest.raises(InvalidParameterError, match="not a sweep folder"):
        load_results(tmp_path / "records.jsonl")


def test_trajectories_on_request_are_result_files(tmp_path):
    from parallel_gpc.results import load_result

    cells = [Cell(i, c.params, trajectory=(i == 0)) for i, c in enumerate(tiny_spec().cells())]
    result = run_sweep(cells, workers=0, store=tmp_path, progress=False)
    table = load_results(tmp_path)
    assert table.loc[0, "trajectory_file"] == f"trajectories/{cells[0].key}.npz"
    assert table["trajectory_file"].isna()[1]  # only the cell that asked for it
    loaded = load_result(tmp_path / table.loc[0, "trajectory_file"])
    assert len(loaded.t) == result.records[0]["steps"] == 20


# ---------------------------------------------------------------- plots
def test_pareto_mask_against_a_sort_oracle():
    rng = np.random.default_rng(0)
    cost, error = rng.uniform(size=60), rng.uniform(size=60)
    from parallel_gpc.plots import pareto_mask

    mask = pareto_mask(cost, error)
    order = np.argsort(cost)  # on the front iff its error is below every cheaper point's
    best, oracle = np.inf, np.zeros(60, dtype=bool)
    for i in order:
        oracle[i] = error[i] < best
        best = min(best, error[i])
    np.testing.assert_array_equal(mask, oracle)


def test_plots_return_figures_and_mark_failed_cells(tmp_path):
    from matplotlib.figure import Figure

    from parallel_gpc.plots import heatmap, plot_sweep, robustness_bands

    spec = load_spec({"sweep": {"samples": 2}, "base": dict(TINY),
                      "grid": {"form": ["absolute", "nonlinear"], "mass_scale": [0.8, 1.0, -1.0]},
                      "random": {"noise_std": {"uniform": [0.0, 1e-5]}}})
    frame = run_sweep(spec, workers=0, progress=False).frame()
    fig = heatmap(frame, "mass_scale", "form", "peak_torque_Nm")
    assert isinstance(fig, Figure)
    assert sum(t.get_text() == "failed" for t in fig.axes[0].texts) == 2
    assert isinstance(robustness_bands(frame, "mass_scale", "rms_position_error_m", "form"), Figure)
    paths = plot_sweep(frame, {"heatmap": [{"x": "mass_scale", "y": "form"}], "pareto": {"labels": ["form"]},
                               "bands": {"x": "mass_scale", "where": {"form": "nonlinear"}}}, tmp_path)
    assert len(paths) == 3 and all(p.stat().st_size > 5000 for p in paths)
    with pytest.raises(InvalidParameterError, match="not in the sweep table"):
        heatmap(frame, "Qy", "form")
    with pytest.raises(InvalidParameterError, match="'violin' is not one of"):
        plot_sweep(frame, {"violin": {}}, tmp_path)


# ---------------------------------------------------------------- CLI
def test_cli_sweep_writes_the_table_and_resumes(tmp_path, capsys):
    from parallel_gpc.cli import main

    spec = tmp_path / "s.toml"
    spec.write_text(SPEC_TOML.replace("samples = 2", "samples = 1").replace("N = [3, 5]", "N = [3]")
                    + '\n[plots]\nheatmap = {x = "form", y = "N"}\n')
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "--workers", "0", "--out", str(out), "--no-progress"]) == 0
    assert "2 run now, 0 reused" in capsys.readouterr().out
    assert (out / "results.parquet").exists() and (out / "spec.json").exists()
    assert list(out.glob("heatmap0_*.png"))
    assert main(["sweep", str(spec), "--workers", "0", "--out", str(out), "--no-progress"]) == 0
    assert "0 run now, 2 reused" in capsys.readouterr().out
    assert main(["sweep", str(spec), "--dry-run"]) == 0
    assert "2 cells" in capsys.readouterr().err
    assert main(["sweep", str(spec), "--workers", "-1", "--out", str(out)]) == 2


# ---------------------------------------------------------------- Dask
@pytest.mark.slow
def test_local_cluster_gives_the_serial_metrics_records_failures_and_keeps_cells_on_ctrl_c(tmp_path):
    """A real LocalCluster (2 processes): bit-identical metrics to the serial path, the failed cell
    recorded the same way, Ctrl-C in the progress loop keeps the finished cells; the robustness
    preset gives the serial table."""
    from dask.distributed import Client, LocalCluster

    from parallel_gpc.sweeps import robustness_study

    spec = load_spec({"sweep": {"samples": 2, "seed": 1}, "base": dict(TINY),
                      "grid": {"form": ["absolute", "incremental", "nonlinear"], "mass_scale": [0.9, -1.0]},
                      "random": {"noise_std": {"loguniform": [1e-6, 1e-4]}, "seed": {"integers": [0, 99]}}})
    serial = run_sweep(spec, workers=0, progress=False).frame()
    study = dict(forms=("absolute", "nonlinear"), mass_scales=(0.8,), noise_levels=(1e-5,), disturbances=(10.0,),
                 duration=0.1, reference="hold")
    with LocalCluster(n_workers=2, processes=True, threads_per_worker=1, host="127.0.0.1",
                      dashboard_address="127.0.0.1:0") as cluster, Client(cluster) as client:
        parallel = run_sweep(spec, scheduler=client, progress=False)
        seen = []

        def interrupt_at_third(record):
            seen.append(record["key"])
            if len(seen) == 3:
                raise KeyboardInterrupt

        stopped = run_sweep(spec, scheduler=client, store=tmp_path, progress=False, on_record=interrupt_at_third)
        kept = set(SweepStore(tmp_path).finished())
        resumed = run_sweep(spec, scheduler=client, store=tmp_path, progress=False)
        rows_cluster = robustness_study(scheduler=client, **study).rows
        for suffix in (".urdf", ".toml"):  # a robot file that only the workers have
            shipped = tmp_path / f"shipped_3rrr{suffix}"
            shipped.write_text((ROBOTS / f"planar_3rrr{suffix}").read_text())
            client.upload_file(str(shipped), load=False)
            shipped.unlink()
        own = run_sweep([Cell(0, {**TINY, "robot": "shipped_3rrr.toml"})], scheduler=client, progress=False)
        workers = set(client.run(os.getpid).values())
    assert len(workers) == 2 and os.getpid() not in workers  # really other processes
    assert parallel.ran == 12 and parallel.failed == 6
    frame = parallel.frame()
    assert deterministic(frame).equals(deterministic(serial))  # bit-identical, NaN where failed
    assert (frame["status"] == "failed").sum() == 6
    assert stopped.interrupted and stopped.ran == 3 and kept == set(seen)
    assert (resumed.skipped, resumed.ran) == (3, 9) and not resumed.interrupted
    assert deterministic(load_results(tmp_path)).equals(deterministic(serial))
    rows_serial = robustness_study(**study).rows
    assert rows_cluster == rows_serial
    assert own.records[0]["status"] == "ok", own.records[0]["error"]
    assert own.records[0]["rms_position_error_m"] == run_cell(Cell(0, dict(TINY)))["rms_position_error_m"]
    assert run_cell(Cell(0, {**TINY, "robot": "shipped_3rrr.toml"}))["status"] == "failed"  # not here
