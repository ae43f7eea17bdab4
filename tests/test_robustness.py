"""The robustness study in a tiny configuration: table structure, plot, and integral action."""

from __future__ import annotations

import math

import pytest

from parallel_gpc import robustness_study
from parallel_gpc.plots import save_figure
from parallel_gpc.sweeps import COLUMNS, RobustnessResult, robustness_cases
from parallel_gpc.plots import plot_robustness


@pytest.fixture(scope="module")
def hold_study() -> RobustnessResult:
    """Hold of the home pose, 1 s runs at Ts = 5 ms: nominal, −30 % mass, noise, and a 20 N force."""
    return robustness_study(mass_scales=(0.7,), noise_levels=(1e-5,), disturbances=(20.0,), duration=1.0,
                            Ts=0.005, N=10, reference="hold")


def test_cases_cover_nominal_and_each_variation():
    cases = robustness_cases((0.7, 1.0, 1.3), (0.0, 1e-4), (20.0,))
    assert [(c.study, c.value, c.unit) for c in cases] == [
        ("nominal", 0.0, ""), ("mass", -30.0, "%"), ("mass", 30.0, "%"), ("noise", 1e-4, "m"),
        ("disturbance", 20.0, "N")]


def test_table_has_one_row_per_form_and_case(hold_study):
    rows = hold_study.rows
    assert not hold_study.interrupted
    assert len(rows) == 3 * 4
    assert {r["form"] for r in rows} == {"absolute", "incremental", "nonlinear"}
    assert [r["study"] for r in rows[::3]] == ["nominal", "mass", "noise", "disturbance"]
    for r in rows:
        assert tuple(r) == COLUMNS
        assert r["status"] == "ok" and r["steps"] == 200 and r["fallbacks"] == 0
        assert all(math.isfinite(r[k]) for k in ("rms_position_error_mm", "steady_state_error_mm", "peak_drive_effort"))
    text = hold_study.format_table()
    assert len(text.splitlines()) == 2 + len(rows) and "disturbance" in text


def test_incremental_forms_remove_the_steady_state_error_of_a_constant_force(hold_study):
    steady = {r["form"]: r["steady_state_error_mm"] for r in hold_study.rows if r["study"] == "disturbance"}
    # absolute form with Qu > 0: a persistent offset (≈ 0.85 mm at 20 N); incremental: integral action
    assert steady["absolute"] > 0.3
    assert steady["incremental"] < 1e-3 and steady["nonlinear"] < 1e-3
    nominal = {r["form"]: r["steady_state_error_mm"] for r in hold_study.rows if r["study"] == "nominal"}
    assert max(nominal.values()) < 1e-6  # at rest on the reference without the force


def test_outputs_are_written(hold_study, tmp_path):
    png = save_figure(plot_robustness(hold_study), tmp_path / "r.png")
    csv_path = hold_study.save_csv(tmp_path / "r.csv")
    json_path = hold_study.save_json(tmp_path / "r.json")
    assert png.stat().st_size > 10_000
    assert csv_path.read_text().splitlines()[0] == ",".join(COLUMNS)
    assert '"rows"' in json_path.read_text()


def test_a_diverging_run_is_recorded_not_raised(monkeypatch):
    from parallel_gpc.studies import tracking
    from parallel_gpc.errors import UnreachablePoseError

    real = tracking.simulate

    def simulate(controller, plant, *args, **kwargs):
        if plant.robot.mass_scale != 1.0:  # the lighter plant "leaves the workspace"
            raise UnreachablePoseError("platform pose [2.0, 0.5, 0.0] cannot be assembled")
        return real(controller, plant, *args, **kwargs)

    monkeypatch.setattr(tracking, "simulate", simulate)
    result = robustness_study(forms=("absolute",), mass_scales=(0.7,), noise_levels=(), disturbances=(),
                              duration=0.05, reference="hold")
    assert [r["status"] for r in result.rows] == ["ok", "diverged (UnreachablePoseError)"]
    assert math.isnan(result.rows[1]["rms_position_error_mm"])
    assert "—" in result.format_table().splitlines()[-1]
