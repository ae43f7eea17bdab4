"""docs/your-robot.md: a user's five-bar (URDF + TOML written by hand, output (x, z)) through every
command. The page's files are the ones shown, its Python blocks and commands run (shorter), and
the tables and figures are labelled with the robot's outputs and drive unit."""

from __future__ import annotations

import re
import shlex
import shutil
from pathlib import Path

import numpy as np
import pytest

from parallel_gpc.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "your-robot.md"
FILES = ROOT / "docs" / "your-robot"
#: command -> options appended to make the page's commands short (same code paths)
SHORTER = {"track": ["--duration", "0.3", "--no-progress"],
           "plan": ["--Nmax", "20", "--settle", "5", "--no-progress"],
           "robustness": ["--duration", "0.3", "--mass-scales", "1.2", "--noise", "0", "--disturbances", "5"],
           "info": [], "view": []}


def blocks(kind: str) -> list[str]:
    return re.findall(rf"```{kind}\n(.*?)```", PAGE.read_text(encoding="utf-8"), re.DOTALL)


def commands() -> list[list[str]]:
    return [shlex.split(line)[1:] for block in blocks("bash") for line in block.splitlines()
            if line.startswith("parallel-gpc ")]


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    """A copy of the page's robot files at the page's relative path, as the working folder."""
    shutil.copytree(FILES, tmp_path / "docs" / "your-robot")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_the_page_shows_the_files_it_uses():
    assert blocks("xml") == [(FILES / "fivebar.urdf").read_text(encoding="utf-8")]
    assert blocks("toml") == [(FILES / "fivebar.toml").read_text(encoding="utf-8")]
    assert [c[0] for c in commands()] == ["info", "track", "track", "plan", "robustness", "view"]


def test_the_page_runs(workdir, capsys):
    """Every command of the page, in order, with the Python blocks between them where the page
    has them (the CSV is written before the command that reads it)."""
    namespace = {"__name__": "your_robot"}
    python = blocks("python")
    text = PAGE.read_text(encoding="utf-8")
    order = sorted([(text.index(b), "python", b) for b in python]
                   + [(text.index(" ".join(["parallel-gpc", *c])), "cli", c) for c in commands()])
    for _, kind, item in order:
        if kind == "python":
            exec(compile(item.replace("duration=1.2", "duration=0.3"), "docs/your-robot.md", "exec"), namespace)
            continue
        assert cli_main([*item, *SHORTER[item[0]]]) == 0, item
    out = capsys.readouterr().out
    assert "2: x [m], z [m]" in out and "efforts in N·m" in out  # info
    assert "t,x,z" in out  # the CSV header
    tables = [line for line in out.splitlines() if line.startswith("form ")]
    assert tables and all("rms ang" not in line and "RMS ang" not in line for line in tables)  # no angles
    assert "[N·m]" in out and "N²·m²·s" in out
    for path in ("out/fivebar/track_path.png", "out/fivebar/track_time.png", "out/fivebar/track_nonlinear.npz",
                 "out/fivebar-csv/track_path.png", "out/fivebar-plan/plan_fig3.png", "out/fivebar-plan/plan_fig4.png",
                 "out/fivebar-plan/plan_b.npz", "out/fivebar-robustness/robustness.png", "out/fivebar/track.html"):
        assert (workdir / path).stat().st_size > 1000, path
    results = namespace["results"]  # the library run on the CSV reference
    wave = namespace["wave"]
    res = results["nonlinear"]
    np.testing.assert_allclose(res.reference, wave.sample(res.t), atol=1e-12)  # the CSV is the reference
    assert res.metrics()["max_position_error_m"] < 1e-3


def test_figures_are_labelled_with_the_outputs(workdir):
    from parallel_gpc import ParallelRobot, PlanSettings, TrackingSettings, plan_modes, run_tracking
    from parallel_gpc.plots import plot_fig3, plot_fig4, plot_paths, plot_time_histories

    robot = ParallelRobot.load("docs/your-robot/fivebar.urdf")
    results = run_tracking(TrackingSettings(robot="docs/your-robot/fivebar.urdf", reference="circle", duration=0.2),
                           forms=("nonlinear",), progress=False, robot=robot)
    ax = plot_paths(results).axes[0]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x [m]", "z [m]")
    line = ax.lines[0]  # the reference, drawn in the x-z plane
    np.testing.assert_allclose(line.get_xdata(), results["nonlinear"].reference[:, 0])
    np.testing.assert_allclose(line.get_ydata(), results["nonlinear"].reference[:, 1])
    labels = [a.get_ylabel() for a in plot_time_histories(results).axes]
    assert labels == ["error x [mm]", "error z [mm]", "velocity [m/s]", "drive effort [N·m]"]
    plans = plan_modes(robot, robot.description.pose_a, robot.description.pose_b,
                       PlanSettings(Nmax=12, Nmin=6, Ts=0.02, settle_steps=2)).results
    fig3 = plot_fig3(plans, robot=robot)
    assert {(a.get_xlabel(), a.get_ylabel()) for a in fig3.axes} == {("x [m]", "z [m]")}
    assert len(fig3.axes[0].lines) > 3  # the robot's legs are drawn
    rows = [a.get_ylabel() for a in plot_fig4(plans).axes]  # row-major: one column per mode
    assert rows == ["position [m]"] * 3 + ["velocity [m/s]"] * 3 + ["drive effort [N·m]"] * 3


def test_helix_on_a_planar_five_bar_is_one_line(workdir, capsys):
    code = cli_main(["track", "--robot", "docs/your-robot/fivebar.urdf", "--reference", "helix", "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert "helix needs 3 translational outputs" in err[0] and "[x m, z m]" in err[0]


def test_a_reference_outside_the_workspace_is_refused_before_the_run(workdir, capsys):
    far = "t,z,x\n0,0.4,0\n1,0.9,0\n"  # columns in any order; z = 0.9 m is beyond the legs (0.55 m)
    Path("far.csv").write_text(far)
    code = cli_main(["track", "--robot", "docs/your-robot/fivebar.urdf", "--reference", "far.csv", "--no-progress",
                     "--out", "out/far"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert "outside the workspace of 'fivebar'" in err[0] and "at t = " in err[0]
    assert not Path("out/far/track_path.png").exists()
