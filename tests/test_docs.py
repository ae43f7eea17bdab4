"""The README and the pages of ``docs/`` cannot drift from the code.

Every fenced block is checked by its language:

* ```python — runs, one test per block, in a temporary folder holding the files the examples
  name (the five-bar of :mod:`mechanisms`, a tiny sweep spec), on a shorter time scale
  (:data:`SHORTER`); every ``.npz`` / ``.png`` file the block names exists afterwards. A block
  preceded by ``<!-- docs-test: no-run -->`` is only compiled (keep that rare);
* ```toml / ```yaml — parse; ``<!-- docs-test: sidecar-of MODEL -->`` loads the block as the
  sidecar of that test mechanism, ``same-as PATH`` / ``part-of PATH`` compare it with a file of
  the repository;
* ```bash — every ``parallel-gpc ...`` line parses with the command line's own parser.

Besides: every ``--option`` of an inline ```parallel-gpc COMMAND ...``` exists, every relative
link resolves (file and ``#anchor``), the sidecar-key table is ``SIDECAR_KEYS``, the README's two
commands are the ones CI runs, and the README is a front page (≤ 200 lines).
"""

from __future__ import annotations

import re
import shlex
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

import mechanisms as mech

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]
README_MAX_LINES = 200
#: The main job on a fresh machine (the README's first command; .ci/run runs the second, the tests).
DEMO_COMMAND = "python3 -m venv .venv && . .venv/bin/activate && pip install . && parallel-gpc demo"
#: (text in a block, shorter stand-in): the examples as written, on a shorter time scale.
SHORTER = [("duration=2.2", "duration=0.02"),
           ("PlanSettings()", "PlanSettings(Nmax=20, Nmin=6, Ts=0.05, settle_steps=2)"),
           ("workers=2", "workers=0")]  # the sweep in this process (the LocalCluster path: test_sweep)
#: the sweep spec the examples name, as a 4-cell stand-in.
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
MARKERS = ("no-run", "sidecar-of", "same-as", "part-of")
FENCE = re.compile(r"(?:^<!-- docs-test: (?P<marker>[^>]*?) -->\n)?^```(?P<lang>[\w-]*)[^\n]*\n(?P<body>.*?)^```",
                   re.MULTILINE | re.DOTALL)


@dataclass(frozen=True)
class Block:
    page: Path
    line: int
    lang: str
    marker: str
    body: str

    @property
    def name(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def blocks(*langs: str) -> list[Block]:
    found = []
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for m in FENCE.finditer(text):
            if m["lang"] in langs:
                line = text.count("\n", 0, m.start("body"))
                found.append(Block(page, line, m["lang"], (m["marker"] or "").strip(), m["body"]))
    return found


#: Pages whose blocks build on each other (a walk-through): tests/test_your_robot.py runs them in
#: order, so the block-by-block test leaves them out.
SEQUENTIAL_PAGES = ("your-robot.md",)


def params(*langs: str):
    return [pytest.param(b, id=b.name) for b in blocks(*langs)
            if not (b.lang == "python" and b.page.name in SEQUENTIAL_PAGES)]


def example_files(folder: Path) -> None:
    """The files the examples name: a user's five-bar (URDF + sidecar, MJCF + a sidecar elsewhere)
    and the tuning sweep spec (as a 4-cell stand-in)."""
    (folder / "my_robots").mkdir()
    (folder / "config").mkdir()
    (folder / "examples").mkdir()
    mech.write(folder / "my_robots", "fivebar", mech.fivebar_urdf(), mech.fivebar_sidecar())
    (folder / "model.xml").write_text(mech.fivebar_mjcf())
    (folder / "config" / "fivebar_drives.toml").write_text(mech.fivebar_mjcf_sidecar())
    (folder / "examples" / "sweep_tuning.toml").write_text(TINY_SWEEP)


# ------------------------------------------------------------------------------------ python
def test_markers_are_known_and_rare():
    marked = [b for b in blocks("python", "toml", "yaml", "bash") if b.marker]
    assert all(b.marker.split()[0] in MARKERS for b in marked), [(b.name, b.marker) for b in marked]
    assert sum(b.marker == "no-run" for b in marked) <= 2
    assert len(blocks("python")) >= 6  # README library, planning, robot files, linear model, sweep, result file


def test_every_shorter_stand_in_is_used():
    code = "".join(b.body for b in blocks("python"))
    assert all(old in code for old, _ in SHORTER), [old for old, _ in SHORTER if old not in code]


def test_examples_import_from_the_package_top_level():
    """Everything is one import away; figures come from their own modules."""
    lines = [(b.name, line) for b in blocks("python") for line in b.body.splitlines()
             if re.match(r"\s*(from|import)\s", line)]
    for name, line in lines:
        module = line.split()[1]
        assert module in ("numpy", "parallel_gpc") or (module.startswith("parallel_gpc.") and "plots" in module), (
            name, line)


@pytest.mark.parametrize("block", params("python"))
def test_python_block_runs(block, tmp_path, monkeypatch):
    code = block.body
    for old, new in SHORTER:
        code = code.replace(old, new)
    compiled = compile(code, block.name, "exec")
    if block.marker == "no-run":
        return
    example_files(tmp_path)
    monkeypatch.chdir(tmp_path)
    exec(compiled, {"__name__": "docs_example"})
    for written in re.findall(r"[\"']([\w./-]+\.(?:npz|png))[\"']", code):
        assert (tmp_path / written).is_file(), f"{block.name} names {written} but did not write it"


# ------------------------------------------------------------------------------ toml, yaml
def _parse(block: Block) -> dict:
    return tomllib.loads(block.body) if block.lang == "toml" else yaml.safe_load(block.body)


def _is_part(part, whole) -> bool:
    if isinstance(part, dict):
        return isinstance(whole, dict) and all(k in whole and _is_part(v, whole[k]) for k, v in part.items())
    return part == whole


@pytest.mark.parametrize("block", params("toml", "yaml"))
def test_config_block_parses_and_matches(block, tmp_path):
    data = _parse(block)
    assert isinstance(data, dict) and data
    kind, _, arg = block.marker.partition(" ")
    if kind == "same-as":
        assert data == tomllib.loads((ROOT / arg).read_text(encoding="utf-8")), f"{block.name} differs from {arg}"
    elif kind == "part-of":
        assert _is_part(data, tomllib.loads((ROOT / arg).read_text(encoding="utf-8"))), f"{block.name} not in {arg}"
    elif kind == "sidecar-of":
        from parallel_gpc import ParallelRobot

        model = {"fivebar.urdf": mech.fivebar_urdf, "fivebar.xml": mech.fivebar_mjcf}[arg]
        (tmp_path / arg).write_text(model())
        sidecar = tmp_path / f"sidecar.{block.lang}"
        sidecar.write_text(block.body)
        robot = ParallelRobot.load(tmp_path / arg, sidecar=sidecar)
        assert (robot.n_y, robot.n_u, robot.redundancy) == (2, 2, 0)
    else:
        assert not block.marker


def test_the_sidecar_key_table_is_the_loaders():
    from parallel_gpc.model import SIDECAR_KEYS

    text = (ROOT / "docs" / "robot-files.md").read_text(encoding="utf-8")
    rows = {"top level (TOML)": "toml", "top level (Gepetto YAML)": "gepetto", "`[[closures]]`": "closures",
            "`[drives]`": "drives", "`[output]`": "output", "`[home]`": "home", "`[sensors]`": "sensors",
            "`[limits]`": "limits"}
    for label, table in rows.items():
        row = next(line for line in text.splitlines() if line.startswith(f"| {label} |"))
        keys = set(re.findall(r"`(\w+)`", row.split("|")[2]))
        assert keys == set(SIDECAR_KEYS[table]), (label, keys ^ set(SIDECAR_KEYS[table]))
    assert set(rows.values()) == set(SIDECAR_KEYS)


# --------------------------------------------------------------------------- command line
def _subparsers():
    from parallel_gpc.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices
    return parser, sub


@pytest.mark.parametrize("block", params("bash"))
def test_command_lines_parse(block):
    parser, _ = _subparsers()
    for line in block.body.splitlines():
        if line.startswith("parallel-gpc "):
            args = parser.parse_args(shlex.split(line, comments=True)[1:])
            assert args.func, line


def test_inline_commands_name_existing_options():
    parser, sub = _subparsers()
    top = {s for a in parser._actions for s in a.option_strings}
    for page in PAGES:
        for span in re.findall(r"`(parallel-gpc [^`]+)`", page.read_text(encoding="utf-8")):
            words = span.split()
            options = set(re.findall(r"(?<![\w-])--[a-zA-Z][\w-]*", span))
            if words[1] in sub:
                valid = top | {s for a in sub[words[1]]._actions for s in a.option_strings}
            elif words[1].startswith("--") or words[1] == "...":
                valid = top
            else:
                assert words[1].isupper(), f"{page.name}: unknown command in `{span}`"  # COMMAND, a placeholder
                continue
            assert options <= valid, f"{page.name}: `{span}` names {sorted(options - valid)}"


# ------------------------------------------------------------------------------- the pages
def _slug(heading: str) -> str:
    """GitHub's anchor of a heading."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    text = re.sub(r"^```.*?^```", "", page.read_text(encoding="utf-8"), flags=re.MULTILINE | re.DOTALL)
    return {_slug(h) for h in re.findall(r"^#+ (.+)$", text, re.MULTILINE)}


def test_every_relative_link_resolves():
    checked = 0
    for page in PAGES:
        text = re.sub(r"^```.*?^```", "", page.read_text(encoding="utf-8"), flags=re.MULTILINE | re.DOTALL)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):
                continue
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            assert dest.exists(), f"{page.name}: link {target} points to a missing file"
            if anchor and dest.suffix == ".md":
                assert anchor in _anchors(dest), f"{page.name}: link {target}: no heading with that anchor"
            checked += 1
    assert checked > 20


def test_every_page_is_linked_from_the_readme():
    text = README.read_text(encoding="utf-8")
    for page in PAGES[1:]:
        assert f"](docs/{page.name})" in text, page.name


def test_the_readme_is_a_front_page_with_the_two_commands_ci_runs():
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= README_MAX_LINES
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8").strip().splitlines()[-1]
    bash = [b.body.strip() for b in blocks("bash") if b.page == README]
    assert bash == [DEMO_COMMAND, ci], bash
