"""Sweeps: spec expansion, cell runs against the closed loop and an energy balance, failure
records, resume, Ctrl-C, the tidy table, plots, the CLI, and serial vs a real LocalCluster."""

from __future__ import annotations

import math
import os
import sys
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
from parallel_gpc.sweeps import batch_size, cluster_pays, failed_record, run_cells
from parallel_gpc.sweeps import local_cluster, runner

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


def test_a_spec_sets_state_limits_and_they_reach_the_controller(tmp_path):
    """[base]/[grid] limits of a TOML spec (an output velocity limit, a box, soft kinds, penalty)
    become the cell's Limits, and the cell's closed loop keeps the velocity limit."""
    from parallel_gpc.limits import Limits

    spec = tmp_path / "lim.toml"
    spec.write_text("[sweep]\nname = \"lim\"\n[base]\nrobot = \"planar_3rrr\"\nreference = \"s-curve\"\n"
                    "s_curve_duration = 0.3\nduration = 0.1\nTs = 0.005\nN = 4\nform = \"absolute\"\n"
                    "torque_limit = 200.0\nsoft_limits = []\nlimit_penalty = 50.0\n"
                    "output_box = [[-1.0, 1.0], [-1.0, 1.0], [-4.0, 4.0]]\n"
                    "[grid]\noutput_velocity = [0.05, 100.0]\n")
    cells = load_spec(spec).cells()
    assert len(cells) == 2
    settings, form = cell_settings(cells[0].params)
    assert settings.limits == Limits(torque=200.0, output_box=[[-1.0, 1.0], [-1.0, 1.0], [-4.0, 4.0]],
                                     output_velocity=0.05, soft=(), penalty=50.0)
    slow, fast = (run_cell(Cell(c.index, c.params, trajectory=True)) for c in cells)
    assert slow["status"] == "ok" and fast["status"] == "ok", (slow["error"], fast["error"])
    speed = {name: np.abs(np.diff(rec["trajectory"].pose[:, :2], axis=0)).max() / 0.005 for name, rec in
             (("slow", slow), ("fast", fast))}
    # the limit binds and holds (hard; the plant's motion differs from the one-step linearized model's
    # by ~2e-4 of the step)
    assert speed["fast"] > 0.1 and speed["slow"] <= 0.05 * (1 + 1e-3)


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


def _pid_cell(cell):
    """A blank ok record whose error field holds the pid of the process that ran the cell."""
    record = failed_record(cell, str(os.getpid()))
    record["status"] = "ok"
    return record


def _raise_on_odd(cell):
    if cell.index % 2:
        raise ValueError(f"odd   cell\n{cell.index}")
    return _pid_cell(cell)


@pytest.mark.parametrize("streams", [1, 2, 3, 8])
@pytest.mark.parametrize("per_cell", [None, 0.0, 1e-4, 0.03, 0.1, 0.2, 0.9, 5.0])
def test_batch_size_holds_a_second_of_work_and_shrinks_at_the_tail(streams, per_cell):
    for left in (1, 2, 3, 7, 12, 60, 64, 1000, 10**6):
        size = batch_size(left, streams, per_cell)
        assert 1 <= size <= left
        if per_cell is None:
            assert size == 1
            continue
        if size > 1:  # never more than a batch's worth of work, nor more than the share of the cells left
            assert size * per_cell <= runner.BATCH_SECONDS
            assert size <= math.ceil(left / (runner.SHARES * streams))
        # and as large as both bounds allow
        assert size + 1 > min(runner.BATCH_SECONDS / max(per_cell, 1e-6), left / (runner.SHARES * streams))


def test_one_batch_per_worker_is_queued_once_the_cells_left_are_the_last_single_cell_shares():
    assert runner.in_flight(100, 2, 1) == runner.IN_FLIGHT == 2  # one running, the next ready
    assert runner.in_flight(100, 4, 3) == 2 * 3
    # 2 streams × 3 shares: from 6 cells left on, a worker gets its next cell only once free
    assert runner.in_flight(7, 2, 1) == 2 and runner.in_flight(6, 2, 1) == 1 and runner.in_flight(0, 2, 1) == 1
    assert runner.in_flight(12, 4, 3) == 3
    for left in range(0, 40):  # queued ahead only while the batch after would be larger than one cell
        assert (runner.in_flight(left, 2, 1) > 1) == (batch_size(max(left, 1), 2, 1e-3) > 1)


def test_sixty_four_cells_go_in_batches_of_a_second():
    assert runner.BATCH_SECONDS == 1.0 and runner.IN_FLIGHT == 2 and runner.SHARES == 3
    assert batch_size(60, 2, 0.1) == 10 and batch_size(60, 2, 0.2) == 5
    assert batch_size(12, 2, 0.1) == 2  # the tail: 12 cells left for 2 streams × 3 shares


def test_a_local_cluster_is_started_only_when_it_repays_its_start_up(monkeypatch):
    start, cost = local_cluster.LOCAL_START_SECONDS, local_cluster.LOCAL_COST_SECONDS
    assert cluster_pays(15 * 0.1, 2)  # 16 cells of 0.1 s (one run here first): the cluster starts
    assert not cluster_pays(5 * 0.1, 2)  # 6 cells of 0.1 s do not
    assert cluster_pays(60 * 0.2, 2)  # 64 cells of 0.2 s
    # the work left once the cluster is up: 2 workers save half of it, 3 two thirds
    assert not cluster_pays(start + 1.99 * cost, 2) and cluster_pays(start + 2.01 * cost, 2)
    assert not cluster_pays(start + 1.49 * cost, 3) and cluster_pays(start + 1.51 * cost, 3)
    slow = local_cluster.ClusterCost(start=2.0, cost=1.5)
    assert not cluster_pays(2.0 + 1.99 * 1.5, 2, slow) and cluster_pays(2.0 + 2.01 * 1.5, 2, slow)
    assert not cluster_pays(1.9, 2, local_cluster.ClusterCost(start=2.0, cost=0.0))  # done before it is up

    def no_cluster(*args, **kwargs):
        raise AssertionError("a LocalCluster was started for a sweep too small to repay it")

    import dask.distributed

    monkeypatch.setattr(dask.distributed, "LocalCluster", no_cluster)
    result = run_sweep(tiny_spec(N=[3, 4, 5]).cells(), workers=2, progress=False, func=_pid_cell)
    assert result.ran == 3 and {r["error"] for r in result.records} == {str(os.getpid())}


#: Length of a :func:`_sleeping_cell`, s.
SLEEP_CELL = 0.02


def _sleeping_cell(cell):
    """A cell of known length (:data:`SLEEP_CELL`; sleeping, so CPU load does not stretch it) that
    records the pid of the process that ran it."""
    import time

    time.sleep(SLEEP_CELL)
    return _pid_cell(cell)


def _sleep_cells(n):
    return [Cell(i, {**TINY, "Qu": 1e-4 * (i + 1)}) for i in range(n)]


@pytest.mark.slow
def test_sixteen_small_cells_start_the_cluster_and_share_the_cells(monkeypatch):
    """16 cells of 0.1 s (issue 23's small sweep), dask.distributed imported: the 1.5 s of work left
    after the first cell repays the cluster's start (its workers, forked between two cells, take
    cells from the same queue); every cell runs once, in this process or the one worker."""
    import dask.distributed  # noqa: F401 - imported, as in a process's second sweep

    monkeypatch.setattr(sys.modules[__name__], "SLEEP_CELL", 0.1)  # set before the worker forks
    result = run_sweep(_sleep_cells(16), workers=2, progress=False, func=_sleeping_cell)
    assert result.ran == 16 and result.failed == 0
    pids = [int(r["error"]) for r in result.records]
    assert pids[0] == os.getpid() and pids.count(os.getpid()) == result.local
    assert result.batches and result.local + sum(result.batches) == 16  # the cluster started and took cells
    assert len(set(pids) - {os.getpid()}) == 1


@pytest.mark.slow
def test_the_cells_run_here_size_the_first_batches_of_the_cluster_it_starts():
    """Enough short cells that a cluster pays: workers=2 is this process and a cluster of one
    worker process, started once the first cell measured the time per cell; this process runs
    cells from start to end, the cluster's first tasks are already batches sized from the time per
    cell measured here (no single-cell tasks), every cell runs once."""
    n = int(4 * local_cluster.LOCAL_START_SECONDS / SLEEP_CELL) + 25  # work left after a cell ≥ 4 cluster costs
    result = run_sweep(_sleep_cells(n), workers=2, progress=False, func=_sleeping_cell)
    assert result.ran == n and result.failed == 0
    assert 1 <= result.local < n and result.local + sum(result.batches) == n
    largest = runner.BATCH_SECONDS / SLEEP_CELL  # a batch holds at most BATCH_SECONDS at ≥ SLEEP_CELL per cell
    assert all(1 < size <= largest for size in result.batches[:runner.IN_FLIGHT]), result.batches
    pids = [int(r["error"]) for r in result.records]
    assert pids[0] == os.getpid() and pids.count(os.getpid()) == result.local
    assert len(set(pids) - {os.getpid()}) == 1


def test_run_cells_keeps_the_order_and_records_a_cell_function_that_raises():
    cells = tiny_spec(N=[3, 4, 5]).cells()
    records, seconds = run_cells(cells, _raise_on_odd)
    assert [r["key"] for r in records] == [c.key for c in cells] and seconds >= 0
    assert [r["status"] for r in records] == ["ok", "failed", "ok"]
    assert records[1]["error"] == "ValueError: odd cell 1" and math.isnan(records[1][METRIC_COLUMNS[0]])


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
    fig = heatmap(frame, "mass_scale", "form", "peak_drive_effort")
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
    from dask.distributed import Client, LocalCluster, get_task_stream

    from parallel_gpc.sweeps import robustness_study

    spec = load_spec({"sweep": {"samples": 2, "seed": 1}, "base": dict(TINY),
                      "grid": {"form": ["absolute", "incremental", "nonlinear"], "mass_scale": [0.9, -1.0]},
                      "random": {"noise_std": {"loguniform": [1e-6, 1e-4]}, "seed": {"integers": [0, 99]}}})
    serial = run_sweep(spec, workers=0, progress=False).frame()
    study = dict(forms=("absolute", "nonlinear"), mass_scales=(0.8,), noise_levels=(1e-5,), disturbances=(10.0,),
                 duration=0.1, reference="hold")
    with LocalCluster(n_workers=2, processes=True, threads_per_worker=1, host="127.0.0.1",
                      dashboard_address="127.0.0.1:0") as cluster, Client(cluster) as client:
        with get_task_stream(client) as stream:
            parallel = run_sweep(spec, scheduler=client, progress=False)
        batched = run_sweep(spec, scheduler=client, progress=False, func=_pid_cell)
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
    # single cells until a batch has returned, then batches (at most the share of the cells left)
    assert 4 <= len(stream.data) < 12
    assert batched.ran == 12 and {int(r["error"]) for r in batched.records} <= workers
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


# ---------------------------------------------------------------- hardening: journal, lock, spec bounds
def _journal_lines(folder):
    return (Path(folder) / "records.jsonl").read_bytes().split(b"\n")


def test_a_journal_line_cut_mid_write_loses_no_other_record(tmp_path):
    spec = tiny_spec(N=[3, 4, 5])
    run_sweep(tiny_spec(N=[3, 4]), workers=0, store=tmp_path, progress=False)
    journal = tmp_path / "records.jsonl"
    whole = journal.read_bytes()
    journal.write_bytes(whole + b'{"key": "0123456789abcdef", "index": 2, "status": "ok", "rms_pos')  # the crash
    resumed = run_sweep(spec, workers=0, store=tmp_path, progress=False)
    assert (resumed.ran, resumed.skipped) == (1, 2)
    store = SweepStore(tmp_path)
    assert set(store.finished()) == {c.key for c in spec.cells()} and store.skipped_lines == 0
    assert journal.read_bytes().startswith(whole) and journal.read_bytes().endswith(b"\n")
    # a whole last record that only lost its newline is kept, and the next one starts its own line
    journal.write_bytes(journal.read_bytes()[:-1])
    wider = run_sweep(tiny_spec(N=[3, 4, 5, 6]), workers=0, store=tmp_path, progress=False)
    assert (wider.ran, wider.skipped) == (1, 3)
    assert len(SweepStore(tmp_path).finished()) == 4 and _journal_lines(tmp_path)[-1] == b""


def test_lines_that_are_not_records_are_skipped_and_counted(tmp_path, capsys):
    from parallel_gpc.cli import main

    spec = tiny_spec(N=[3, 4])
    run_sweep(spec, workers=0, store=tmp_path, progress=False)
    journal = tmp_path / "records.jsonl"
    journal.write_bytes(b'[1, 2]\n"x"\n{"status": "ok"}\n\xff\xfe{}\n' + journal.read_bytes() + b"{}\n")
    store = SweepStore(tmp_path)
    assert set(store.finished()) == {c.key for c in spec.cells()} and store.skipped_lines == 5
    again = run_sweep(spec, workers=0, store=tmp_path, progress=False)
    assert (again.ran, again.skipped_lines) == (0, 5)
    toml = tmp_path / "s.toml"
    toml.write_text('[base]\nrobot = "planar_3rrr"\nreference = "hold"\nduration = 0.1\nTs = 0.005\nN = 3\nQu = 1e-4\n')
    assert main(["sweep", str(toml), "--workers", "0", "--out", str(tmp_path), "--no-progress"]) == 0
    assert "skipped 5 lines that are not records" in capsys.readouterr().err


def test_two_sweeps_into_one_folder_the_second_is_refused(tmp_path, capsys):
    from parallel_gpc.cli import main

    holder = SweepStore(tmp_path)
    with holder.locked():
        with holder.locked():  # re-entrant in its holder
            pass
        with pytest.raises(InvalidParameterError, match=f"is in use by another sweep \\(pid {os.getpid()}\\)"):
            run_sweep(tiny_spec(), workers=0, store=tmp_path, progress=False)
        toml = tmp_path / "s.toml"
        toml.write_text('[base]\nreference = "hold"\nduration = 0.1\n')
        assert main(["sweep", str(toml), "--workers", "0", "--out", str(tmp_path)]) == 2
        error = capsys.readouterr().err.splitlines()[-1]  # after the line counting the cells
        assert error.startswith("parallel-gpc: error: sweep folder ") and str(tmp_path) in error
        assert "in use by another sweep" in error
        assert not (tmp_path / "records.jsonl").exists()  # nothing ran
    assert run_sweep(tiny_spec(), workers=0, store=tmp_path, progress=False).ran == 2  # released


BAD_SPECS = [
    ("[sweep]\nseed = -1\n", "seed = -1"),
    ('[sweep]\nseed = "x"\n', "seed = 'x'"),
    ("[sweep]\nseed = 1.5\n", "seed = 1.5"),
    ('[sweep]\nsamples = 2\n[random]\nQu = {normal = [0, "x"]}\n', "normal takes two finite numbers"),
    ('[sweep]\nsamples = 2\n[random]\nQu = {uniform = ["a", "b"]}\n', "uniform takes two finite numbers"),
    ("[sweep]\nsamples = 2\n[random]\nQu = {uniform = [0, inf]}\n", "uniform takes two finite numbers"),
    ("[sweep]\nsamples = 2\n[random]\nN = {integers = [0, 1e30]}\n", "integers takes two integers"),
    ("[sweep]\nsamples = 2\n[random]\nN = {integers = [1.5, 7]}\n", "integers takes two integers"),
    ('[sweep]\ntrajectories = "no"\n', "trajectories = 'no' must be true or false"),
    ('[sweep]\nname = "../../x"\n', "one folder name"),
    ('[sweep]\nname = "/tmp/abs"\n', "one folder name"),
    ("[sweep]\nname = 5\n", "name = 5"),
    ("[sweep]\nsamples = 1000000000\n", "the limit is 100000"),
    ("[grid]\n" + "".join(f"{n} = {list(range(1, 101))}\n" for n in ("N", "Qu", "Qy", "Ts", "No")),
     "10000000000 cells (100 × 100 × 100 × 100 × 100)"),
    ("a = " + "[" * 3000 + "]" * 3000 + "\n", "too deeply"),
    ("[base]\nplatform_force = " + "[" * 40 + "1" + "]" * 40 + "\n", "more than 32 deep"),
    ('[sweep]\nname = "x"\n[plots]\nheatmap = {x = "N", y = "Qu"}\n', "['N', 'Qu'] not among"),
    ('[grid]\nN = [3]\n[plots]\nheatmap = {x = "N", y = "form", agg = "sum"}\n', "not among"),
    ('[grid]\nN = [3]\nform = ["absolute"]\n[plots]\nheatmap = {x = "N", y = "form", agg = "sum"}\n', "agg 'sum'"),
    ('[grid]\nN = [3]\n[plots]\npareto = {colour = "red"}\n', "colour"),
]


@pytest.mark.parametrize("text, words", BAD_SPECS)
def test_bad_spec_values_are_one_line_errors_before_anything_runs(tmp_path, capsys, text, words):
    from parallel_gpc.cli import main

    spec = tmp_path / "s.toml"
    spec.write_text(text)
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "--workers", "0", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("parallel-gpc: error: ") and words in err, err
    assert not out.exists()  # refused before any cell ran (and before the folder was made)


def test_spec_files_are_bounded_regular_utf8_files(tmp_path):
    import threading

    from parallel_gpc.sweeps import SPEC_MAX_BYTES

    fifo = tmp_path / "spec.toml"
    os.mkfifo(fifo)
    outcome = []

    def load():
        try:
            load_spec(fifo)
        except InvalidParameterError as exc:
            outcome.append(str(exc))

    thread = threading.Thread(target=load, daemon=True)  # a blocked open would hang the thread, not the suite
    thread.start()
    thread.join(20.0)
    assert outcome and "is not a regular file" in outcome[0]
    if os.path.exists("/dev/zero"):
        with pytest.raises(InvalidParameterError, match="not a regular file"):
            load_spec("/dev/zero")
    big = tmp_path / "big.toml"
    big.write_text("# " + "x" * SPEC_MAX_BYTES + "\n")
    with pytest.raises(InvalidParameterError, match=f"the limit is {SPEC_MAX_BYTES} bytes"):
        load_spec(big)
    latin = tmp_path / "latin.toml"
    latin.write_bytes(b'[sweep]\nname = "caf\xe9"\n')
    with pytest.raises(InvalidParameterError, match="not UTF-8 text: byte 0xe9 at offset 19"):
        load_spec(latin)
    with pytest.raises(InvalidParameterError, match="does not exist"):
        load_spec(tmp_path / "missing.toml")


def test_the_cell_count_is_refused_before_expansion(monkeypatch):
    from parallel_gpc.sweeps import MAX_CELLS, SweepSpec

    def no_expansion(self):
        raise AssertionError("cells() was called")

    small = load_spec({"sweep": {"samples": 3}, "grid": {"N": [3, 4], "Qu": [1e-4, 1e-3, 1e-2]},
                       "random": {"Qy": {"uniform": [0.5, 1.0]}}})
    assert small.count == len(small.cells()) == 18  # the count is the expansion's length
    monkeypatch.setattr(SweepSpec, "cells", no_expansion)
    with pytest.raises(InvalidParameterError, match=f"the limit is {MAX_CELLS}"):
        load_spec({"grid": {n: list(range(100)) for n in ("N", "Qu", "Qy", "Ts", "No")}})
    with pytest.raises(InvalidParameterError, match=f"the limit is {MAX_CELLS}"):
        load_spec({"sweep": {"samples": 10**9}})
    assert load_spec({"sweep": {"samples": MAX_CELLS}}).count == MAX_CELLS


def test_dry_run_counts_must_be_non_negative_and_print_exactly_k_cells(tmp_path, capsys):
    from parallel_gpc.cli import main

    spec = tmp_path / "s.toml"
    spec.write_text('[grid]\nN = [3, 4, 5]\n')
    assert main(["sweep", str(spec), "--dry-run", "-1"]) == 2
    assert "--dry-run -1" in capsys.readouterr().err
    for k, shown in ((0, 0), (2, 2), (9, 3)):
        assert main(["sweep", str(spec), "--dry-run", str(k), "--out", str(tmp_path / "o")]) == 0
        assert len(capsys.readouterr().out.splitlines()) == shown
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", ["sweep", "robustness"])
def test_a_bad_scheduler_address_is_one_line(tmp_path, capsys, command):
    from parallel_gpc.cli import main

    spec = tmp_path / "s.toml"
    spec.write_text('[grid]\nN = [3]\n')
    argv = [command, *([str(spec)] if command == "sweep" else []), "--scheduler", "bogus", "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "scheduler = 'bogus'" in err and "tcp://" in err
    with pytest.raises(InvalidParameterError, match="not the address"):
        run_sweep(tiny_spec(), scheduler="localhost:8786", progress=False)


@pytest.mark.slow
def test_ctrl_c_during_a_dask_sweep_is_quiet_and_keeps_the_cells(tmp_path):
    """Ctrl-C as a terminal sends it: SIGINT to the whole process group (the sweep and its workers)."""
    import signal
    import subprocess
    import sys
    import time

    spec = tmp_path / "s.toml"
    spec.write_text('[base]\nrobot = "planar_3rrr"\nreference = "hold"\nduration = 6.0\nTs = 0.005\nQu = 1e-4\n'
                    f'[grid]\nN = {list(range(3, 13))}\nform = ["absolute", "nonlinear"]\n')
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parents[1] / "src"),
                                                        os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, "-m", "parallel_gpc", "sweep", str(spec), "--workers", "2", "--out",
                             str(out), "--no-progress"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env, start_new_session=True)
    journal = out / "records.jsonl"
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and not (journal.exists() and journal.read_text().count("\n") >= 2):
        time.sleep(0.5)
    os.killpg(proc.pid, signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr and "WARNING" not in stderr, stderr
    assert len(stderr.splitlines()) <= 3, stderr
    kept = len(SweepStore(out).finished())
    assert kept >= 2 and f"{kept} finished cells are saved" in stderr


def test_the_resource_tracker_of_a_local_cluster_does_not_report_leaks_after_ctrl_c():
    """A process that dies holding a semaphore (a sweep's workers after Ctrl-C) makes Python's
    resource tracker print a 'leaked semaphore' warning; the tracker the sweep starts is quiet
    (oracle: the same process without it prints the warning)."""
    import subprocess
    import sys

    code = ("import os, sys, multiprocessing as mp\n"
            "if sys.argv[1] == '1':\n"
            "    from parallel_gpc.sweeps.runner import start_quiet_resource_tracker; start_quiet_resource_tracker()\n"
            "lock = mp.get_context('spawn').Lock()\n"
            "os._exit(0)\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parents[1] / "src"),
                                                        os.environ.get("PYTHONPATH", "")])}
    env.pop("PYTHONWARNINGS", None)
    stderr = {}
    for quiet in ("0", "1"):
        # the tracker outlives the process: wait for it through the pipe it inherited
        proc = subprocess.run([sys.executable, "-c", code, quiet], capture_output=True, text=True, env=env, timeout=60)
        stderr[quiet] = proc.stderr
    assert "leaked semaphore" in stderr["0"]
    assert "leaked semaphore" not in stderr["1"] and "PYTHONWARNINGS" not in os.environ


def test_the_cli_counts_only_the_saved_cells_after_ctrl_c(tmp_path, monkeypatch, capsys):
    """A cell that Ctrl-C stopped mid-run has a partial record: shown, but neither finished nor saved
    (the message counted it: '3 finished cells are saved' with 2 in the store)."""
    import parallel_gpc.sweeps as sweeps
    from parallel_gpc import cli

    def interrupted_at_second(cell):
        record = run_cell(cell)
        if cell.index == 1:  # Ctrl-C inside simulate: a partial record
            record["status"] = "interrupted"
        return record

    plain = sweeps.run_sweep
    monkeypatch.setattr(sweeps, "run_sweep", lambda cells, **kw: plain(cells, **kw, func=interrupted_at_second))
    spec = tmp_path / "s.toml"
    spec.write_text('[base]\nrobot = "planar_3rrr"\nreference = "hold"\nduration = 0.05\nTs = 0.005\nQu = 1e-4\n'
                    '[grid]\nN = [3, 4, 5]\n')
    assert cli.main(["sweep", str(spec), "--workers", "0", "--out", str(tmp_path / "out"), "--no-progress"]) == 130
    out, err = capsys.readouterr()
    assert len(SweepStore(tmp_path / "out").finished()) == 1
    assert "1 finished cells are saved" in err and "1 of 3 cells finished" in out, (out, err)


def test_drive_effort_columns_are_named_for_any_drive_kind(prr3, tmp_path):
    """Field test: the column peak_torque_Nm held newtons for a 3-PRR's prismatic drives. The
    effort columns carry no unit in their names (the drives' own: N here), hold max |u| and
    ∫‖u‖² dt of the run, and tables and journals written with the old names read with the new."""
    params = {**TINY, "robot": str(prr3.description.urdf_path), "reference": "s-curve", "s_curve_duration": 0.1,
              "form": "absolute"}
    record = run_cell(Cell(0, params, trajectory=True))
    assert record["status"] == "ok", record["error"]
    u = record["trajectory"].u
    assert record["peak_drive_effort"] == pytest.approx(np.abs(u).max(), rel=1e-12) and np.abs(u).max() > 0
    assert record["effort_integral"] == pytest.approx(TINY["Ts"] * np.sum(u**2), rel=1e-12)
    assert not [k for k in record if k.endswith("_Nm") or k.endswith("N2m2s")]
    # an older sweep folder: its journal and table use the old names
    run_sweep(tiny_spec(N=[3, 4]), workers=0, store=tmp_path, progress=False)
    journal = tmp_path / "records.jsonl"
    new = journal.read_text()
    journal.write_text(new.replace('"peak_drive_effort"', '"peak_torque_Nm"').replace('"effort_integral"', '"effort_N2m2s"'))
    assert '"peak_torque_Nm"' in journal.read_text()
    records = SweepStore(tmp_path).finished().values()
    assert all("peak_drive_effort" in r and "effort_integral" in r and "peak_torque_Nm" not in r for r in records)
    table = load_results(tmp_path / "results.csv")
    table.rename(columns={"peak_drive_effort": "peak_torque_Nm"}).to_csv(tmp_path / "old.csv", index=False)
    old = load_results(tmp_path / "old.csv")
    assert "peak_drive_effort" in old and "peak_torque_Nm" not in old
    np.testing.assert_array_equal(old["peak_drive_effort"], table["peak_drive_effort"])
