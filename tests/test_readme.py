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


def test_the_readme_has_the_library_and_planning_examples():
    blocks = python_blocks()
    assert len(blocks) == 2
    assert all(old in "".join(blocks) for old, _ in SHORTER)
    imports = [line for block in blocks for line in block.splitlines() if "import" in line]
    assert all(line.startswith("from parallel_gpc import") for line in imports), imports


@pytest.mark.parametrize("index", [0, 1])
def test_readme_example_runs(index, tmp_path, monkeypatch, capsys):
    code = python_blocks()[index]
    for old, new in SHORTER:
        code = code.replace(old, new)
    monkeypatch.chdir(tmp_path)
    exec(compile(code, f"README.md python block {index + 1}", "exec"), {"__name__": "readme"})
    assert "peak_torque_Nm" in capsys.readouterr().out
    assert list(tmp_path.glob("*.npz"))
