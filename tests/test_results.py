"""One result file format: every command's files open with ``parallel-gpc view`` from another
folder; robots are stored as embedded names or absolute paths; older files still load."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from parallel_gpc import ResultFile, SampledTrajectory, SCurve, load_result, save_result
from parallel_gpc.cli import main as cli_main
from parallel_gpc.errors import InvalidParameterError, ResultFormatError
from parallel_gpc.model import embedded_robots, urdf_dir
from parallel_gpc.results import FORMAT, FORMAT_VERSION

from conftest import line_motion

#: A few 10 ms samples: enough for a file, short enough for a fast test.
QUICK_TRACK = ["--duration", "0.05", "--Ts", "0.01", "--N", "5", "--no-progress"]


def view_every_result(folder: Path, elsewhere: Path, monkeypatch, expected: int) -> list[ResultFile]:
    """Open every .npz of ``folder`` with ``parallel-gpc view`` from the folder ``elsewhere``."""
    files = sorted(folder.resolve().glob("*.npz"))
    assert len(files) == expected, files
    elsewhere.mkdir(exist_ok=True)
    monkeypatch.chdir(elsewhere)
    loaded = []
    for path in files:
        html = elsewhere / f"{path.stem}.html"
        assert cli_main(["view", str(path), "--html", str(html)]) == 0
        assert html.stat().st_size > 500_000  # the inlined viewer bundle and the animation
        result = load_result(path)
        assert result.version == FORMAT_VERSION and result.q.shape[0] == result.t.shape[0]
        assert result.robot in embedded_robots() or Path(result.robot).is_absolute()
        loaded.append(result)
    return loaded


def test_view_opens_track_files_with_a_robot_given_by_a_relative_path(tmp_path, monkeypatch):
    own = tmp_path / "work" / "myrobot"
    own.mkdir(parents=True)
    for suffix in (".urdf", ".toml"):
        shutil.copy(urdf_dir() / f"planar_4rrr{suffix}", own / f"planar_4rrr{suffix}")
    monkeypatch.chdir(tmp_path / "work")
    assert cli_main(["track", "--form", "all", "--robot", "myrobot/planar_4rrr.urdf", "--torque-limit", "50",
                     "--out", "run", *QUICK_TRACK]) == 0
    results = view_every_result(tmp_path / "work" / "run", tmp_path / "elsewhere", monkeypatch, expected=4)
    for result in results:
        assert result.robot == str((own / "planar_4rrr.urdf").resolve())
        assert result.kind == "tracking" and result.meta["Ts"] == 0.01
        assert result.reference.shape == (5, 3) and result.saturated.shape == (5, 4)
        assert result.arrays["u"].shape == (5, 4) and result.arrays["status"].dtype.kind == "U"


def test_view_opens_demo_files(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli_main(["demo", "--out", "demo", "--forms", "absolute", "nonlinear", "--deadbeat-duration", "0.03",
                     *QUICK_TRACK]) == 0
    for form in ("absolute", "nonlinear"):  # one labelled animation per form
        assert (tmp_path / "demo" / f"demo_{form}.html").stat().st_size > 500_000
    # each form with the disturbance estimate off and on, and with encoders only (part 3)
    results = view_every_result(tmp_path / "demo", tmp_path / "elsewhere", monkeypatch, expected=6)
    assert sorted((r.meta["form"], r.meta.get("sensors", "full"), r.meta["disturbance_gain"]) for r in results) == [
        ("absolute", "encoders", 0.0), ("absolute", "full", 0.0), ("absolute", "full", 0.5),
        ("nonlinear", "encoders", 0.0), ("nonlinear", "full", 0.0), ("nonlinear", "full", 0.5)]
    assert all(r.robot == "planar_4rrr" for r in results)


def test_view_opens_plan_files(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli_main(["plan", "--Nmax", "12", "--Nmin", "6", "--Ts", "0.05", "--settle", "2", "--no-progress",
                     "--out", "plan"]) == 0
    results = view_every_result(tmp_path / "plan", tmp_path / "elsewhere", monkeypatch, expected=3)  # a, b, once
    for result in results:
        assert result.kind == "plan" and result.robot == "planar_4rrr"
        assert result.planned.shape == (result.t.size, 3) and result.meta["settings"]["Nmax"] == 12
    traj = SampledTrajectory.load(tmp_path / "plan" / "plan_b.npz")
    np.testing.assert_array_equal(traj.poses, results[1].planned)


def test_robustness_writes_no_trajectory_files(tmp_path):
    assert cli_main(["robustness", "--quick", "--mass-scales", "0.7", "--noise", "--disturbances",
                     "--forms", "absolute", "--duration", "0.1", "--out", str(tmp_path)]) == 0
    assert not list(tmp_path.glob("*.npz")) and (tmp_path / "robustness.csv").exists()


def test_roundtrip_keeps_every_array_and_the_meta(robot4, tmp_path):
    t, qs, poses = line_motion(robot4, n=6)
    path = save_result(tmp_path / "sub" / "r.npz", robot4, t, qs, planned=poses, kind="mine",
                       meta={"N": np.int64(5), "limit": np.array([1.0, 2.0])},
                       arrays={"u": np.ones((6, 4)), "status": np.array(["ok"] * 6)})
    with np.load(path, allow_pickle=False) as data:
        assert str(data["format"]) == FORMAT and int(data["format_version"]) == FORMAT_VERSION
    r = load_result(path)
    assert (r.robot, r.kind, r.meta) == ("planar_4rrr", "mine", {"N": 5, "limit": [1.0, 2.0]})
    np.testing.assert_array_equal(r.q, qs)
    np.testing.assert_array_equal(r.planned, poses)
    assert r.reference is None and r.saturated is None
    assert r.arrays["status"].tolist() == ["ok"] * 6 and r.arrays["u"].shape == (6, 4)


def test_bad_results_are_rejected(robot4, tmp_path):
    t, qs, _ = line_motion(robot4, n=4)
    with pytest.raises(InvalidParameterError, match="'t'"):
        save_result(tmp_path / "x.npz", robot4, t, qs, arrays={"t": t})
    with pytest.raises(InvalidParameterError, match="object"):
        save_result(tmp_path / "x.npz", robot4, t, qs, arrays={"odd": np.array([{}, 1], dtype=object)})
    with pytest.raises(InvalidParameterError, match=r"expected \(4, "):
        save_result(tmp_path / "x.npz", robot4, t, qs[:, :-1])
    with pytest.raises(InvalidParameterError, match="strictly increasing"):
        save_result(tmp_path / "x.npz", robot4, t[::-1], qs)
    np.savez(tmp_path / "future.npz", format="parallel-gpc-result", format_version=99, t=t, q=qs, robot="x")
    with pytest.raises(ResultFormatError, match="version 99"):
        load_result(tmp_path / "future.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ResultFormatError, match="cannot read"):
        load_result(tmp_path / "junk.npz")


def test_files_of_older_versions_still_open(robot4, tmp_path, capsys):
    t, qs, poses = line_motion(robot4, n=5)
    np.savez(tmp_path / "old_track.npz", t=t, q=qs, robot="planar_4rrr", meta="{'form': 'absolute'}")
    old = load_result(tmp_path / "old_track.npz")
    assert old.version == 0 and old.robot == "planar_4rrr" and "meta" in old.arrays
    # a plan written before version 1: poses but no robot; view needs --robot
    np.savez(tmp_path / "old_plan.npz", t=t, poses=poses, velocities=0 * poses, q=qs, mode="b")
    assert SampledTrajectory.load(tmp_path / "old_plan.npz").poses.tolist() == poses.tolist()
    assert cli_main(["view", str(tmp_path / "old_plan.npz")]) == 2
    assert "names no robot" in capsys.readouterr().err
    assert cli_main(["view", str(tmp_path / "old_plan.npz"), "--robot", "planar_4rrr",
                     "--html", str(tmp_path / "old_plan.html")]) == 0


def test_reference_files_roundtrip_and_initial_state(tmp_path):
    ref = SCurve()
    t = np.linspace(0.0, ref.duration, 11)
    traj = SampledTrajectory(t, ref.sample(t), np.zeros((11, 3)))
    back = SampledTrajectory.load(traj.save(tmp_path / "ref.npz"))
    np.testing.assert_array_equal(back.poses, traj.poses)
    np.testing.assert_array_equal(back.velocities, traj.velocities)
    assert load_result(tmp_path / "ref.npz").kind == "reference"
    X0 = ref.initial_state()
    assert X0.shape == (6,)
    np.testing.assert_array_equal(X0, np.concatenate([ref.pose(0.0), np.zeros(3)]))
    np.testing.assert_array_equal(traj.initial_state(ref.duration)[:3], ref.pose(ref.duration))
