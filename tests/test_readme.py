"""The README's Python examples run (with shorter runs), so they cannot rot."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
#: (text in the README, shorter stand-in): the examples as written, on a shorter time scale.
SHORTER = [("duration=2.2", "duration=0.02"),
           ("PlanSettings()", "PlanSettings(Nmax=20, Nmin=6, Ts=0.05, settle_steps=2)")]


def python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.DOTALL)


def test_the_readme_has_the_library_planning_sweep_and_robot_file_examples():
    blocks = python_blocks()
    assert len(blocks) == 4
    assert all(old in "".join(blocks) for old, _ in SHORTER)
    imports = [line for block in blocks for line in block.splitlines() if "import" in line]
    plots = [line for line in imports if line.startswith("from parallel_gpc.studies.plots_")]  # one module per figure family
    assert all(line.startswith("from parallel_gpc import") for line in imports if line not in plots), imports
    assert len(plots) == 1


@pytest.mark.parametrize("index", [0, 1])  # block 3 (robot files) runs below
def test_readme_example_runs(index, tmp_path, monkeypatch, capsys):
    code = python_blocks()[index]
    for old, new in SHORTER:
        code = code.replace(old, new)
    monkeypatch.chdir(tmp_path)
    exec(compile(code, f"README.md python block {index + 1}", "exec"), {"__name__": "readme"})
    assert "peak_torque_Nm" in capsys.readouterr().out
    assert list(tmp_path.glob("*.npz"))


TINY_SWEEP = """
[sweep]
name = "tiny"
[base]
robot = "planar_3rrr"
duration = 0.05
Ts = 0.01
[grid]
form = ["nonlinear"]
N = [3, 4]
Qu = [1e-4, 1e-3]
"""


def test_readme_sweep_example_runs(tmp_path, monkeypatch):
    """The sweep block, on a 4-cell spec and in this process (the LocalCluster path is tested in test_sweep)."""
    code = python_blocks()[2].replace("examples/sweep_tuning.toml", "tiny.toml").replace("workers=2", "workers=0")
    (tmp_path / "tiny.toml").write_text(TINY_SWEEP)
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "README.md python block 3", "exec"), {"__name__": "readme"})
    assert (tmp_path / "rms.png").stat().st_size > 0
    assert (tmp_path / "out" / "sweep" / "tuning" / "results.csv").exists()


def test_readme_robot_file_example_runs(tmp_path, monkeypatch):
    """The robot-file block loads a user's URDF + sidecar and an MJCF file with an explicit sidecar."""
    import mechanisms as mech

    code = python_blocks()[3]
    (tmp_path / "my_robots").mkdir()
    (tmp_path / "config").mkdir()
    mech.write(tmp_path / "my_robots", "fivebar", mech.fivebar_urdf(), mech.fivebar_sidecar())
    (tmp_path / "model.xml").write_text(mech.fivebar_mjcf())
    (tmp_path / "config" / "fivebar_drives.toml").write_text(mech.fivebar_mjcf_sidecar())
    monkeypatch.chdir(tmp_path)
    scope = {"__name__": "readme"}
    exec(compile(code, "README.md python block 4", "exec"), scope)
    assert scope["robot"].description.model_format == "mjcf" and scope["robot"].n_y == 2
