"""docs/your-plant.md: its foreign-plant example runs and tracks."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

DOC = Path(__file__).resolve().parents[1] / "docs" / "your-plant.md"


def test_foreign_plant_example_runs():
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(), re.S)
    assert len(blocks) == 1
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(blocks[0], str(DOC), "exec"), {})
    rms, overruns = out.getvalue().split()
    assert float(rms) < 1e-3 and int(overruns) >= 0
