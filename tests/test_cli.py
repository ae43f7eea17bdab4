"""The command line: ``--version``, ``python -m parallel_gpc``, ``robots``, ``gallery``, a ``--help``
that imports neither Pinocchio nor matplotlib, and the help defaults against the library's."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest

import parallel_gpc
from parallel_gpc import (DEFAULT_ROBOT, FORMS, GPCSettings, Horizons, TrackingSettings, embedded_robots,
                          load_description)
from parallel_gpc.cli import REGISTRARS, build_parser, main
from parallel_gpc.cli import defaults, vocabulary
from parallel_gpc.errors import InvalidParameterError

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = ["robots", "info", "demo", "track", "plan", "robustness", "sweep", "bench", "view", "gallery"]


def run(args: list[str], **kwargs) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, env=env, timeout=120, **kwargs)


def test_every_command_is_registered():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert list(sub.choices) == COMMANDS and len(REGISTRARS) == len(COMMANDS)


def test_version_and_python_m(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0 and capsys.readouterr().out.strip() == f"parallel-gpc {parallel_gpc.__version__}"
    done = run(["-m", "parallel_gpc", "--version"])
    assert done.returncode == 0 and done.stdout.strip() == f"parallel-gpc {parallel_gpc.__version__}"


def test_help_imports_neither_pinocchio_nor_matplotlib():
    """--help of the program and of every command, in a fresh interpreter."""
    probe = (
        "import sys\n"
        "from parallel_gpc.cli import build_parser\n"
        "parser = build_parser()\n"
        f"for argv in [['--help']] + [[c, '--help'] for c in {COMMANDS!r}]:\n"
        "    try:\n"
        "        parser.parse_args(argv)\n"
        "    except SystemExit:\n"
        "        pass\n"
        "heavy = sorted(m for m in sys.modules if m.split('.')[0] in ('pinocchio', 'matplotlib', 'meshcat', 'scipy'))\n"
        "print('HEAVY', heavy, file=sys.stderr)\n"
    )
    done = run(["-c", probe])
    assert done.returncode == 0, done.stderr
    assert "HEAVY []" in done.stderr
    for command in COMMANDS:
        assert f"parallel-gpc {command}" in done.stdout


def test_help_defaults_are_the_library_defaults():
    assert defaults.DEFAULT_ROBOT == DEFAULT_ROBOT and defaults.FORMS == tuple(FORMS)
    library = TrackingSettings().flat()
    assert defaults.TRACKING == {k: library[k] for k in defaults.TRACKING}
    assert defaults.TOLERANCE == GPCSettings(0.002, Horizons(5)).tolerance
    from parallel_gpc.gpc.robot_references import REFERENCE_KINDS

    assert defaults.REFERENCES == REFERENCE_KINDS
    args = build_parser().parse_args(["track"])
    assert (args.robot, args.Ts, args.N, args.No, args.Qy, args.Qu) == (
        library["robot"], library["Ts"], library["N"], library["No"], library["Qy"], library["Qu"])


def test_one_vocabulary_for_forms_and_references():
    """--forms (space-separated, or all) and --reference take the same words in every command,
    the library's words, and the help names every form and every reference."""
    from parallel_gpc.gpc.robot_references import REFERENCE_KINDS
    from parallel_gpc.gpc.settings import PAPER_FORMS

    assert defaults.PAPER_FORMS == PAPER_FORMS and defaults.REFERENCES == REFERENCE_KINDS
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices
    for command in ("track", "demo", "robustness"):
        options = {a.dest: a for a in sub[command]._actions}
        assert options["forms"].choices == [*FORMS, "all"] and options["forms"].nargs == "+"
        assert options["reference"].type is vocabulary.reference_argument and options["reference"].default == "auto"
        assert all(form in options["forms"].help for form in FORMS)
        assert all(name in options["reference"].help for name in defaults.REFERENCES)
        args = parser.parse_args([command, "--forms", "nonlinear", "absolute"])
        assert args.forms == ["nonlinear", "absolute"]
    assert parser.parse_args(["robustness"]).forms == list(PAPER_FORMS)
    assert parser.parse_args(["track", "--form", "absolute"]).forms == ["absolute"]  # the earlier spelling
    for command in ("track", "robustness"):  # the built-in names and files; anything else is refused
        for name in (*defaults.REFERENCES, "my_path.csv", "plan_b.npz"):
            assert parser.parse_args([command, "--reference", name]).reference == name
        for bad in ("path", "scurve", "spiral", "my_path.txt"):
            with pytest.raises(InvalidParameterError, match="is not one of"):
                parser.parse_args([command, "--reference", bad])


def test_robots_lists_every_embedded_robot(capsys):
    assert main(["robots"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:3] == ["robot", "DOF", "drives"]
    for name in embedded_robots():
        d = load_description(name)
        row = next(line for line in lines if line.startswith(name + " "))
        assert row.split()[1:3] == [str(len(d.output_joints)), str(len(d.drive_joints))]
        assert all(j in row for j in d.drive_joints)


@pytest.mark.parametrize("entry", [["-m", "parallel_gpc", "gallery"], [str(ROOT / "viz" / "serve_gallery.py")]])
def test_gallery_serves_a_folder_until_ctrl_c(tmp_path, entry):
    (tmp_path / "motion.html").write_text("<html><head><title>my motion</title></head></html>")
    proc = subprocess.Popen([sys.executable, *entry, str(tmp_path), "--port", "0"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=dict(os.environ, PYTHONPATH=str(ROOT / "src")))
    try:
        line = proc.stdout.readline()
        assert "http://127.0.0.1:" in line, (line, proc.stderr.read() if proc.poll() is not None else "")
        url = line.split()[line.split().index("(Ctrl-C") - 1]
        with urllib.request.urlopen(url, timeout=10) as page:
            body = page.read().decode()
        assert "my motion" in body and 'href="motion.html"' in body
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=20) == 0
        assert "gallery stopped" in proc.stdout.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_gallery_bad_folder_is_one_line_error(tmp_path, capsys):
    assert main(["gallery", str(tmp_path / "missing")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("parallel-gpc: error:") and "missing" in err and "\n" not in err


def test_without_meshcat_demo_hints_and_an_explicit_view_fails(tmp_path, monkeypatch, capsys):
    """The lean install (no ``view`` extra): demo still runs and says how to get the animation."""
    from parallel_gpc.cli import view

    monkeypatch.setattr(view, "_viz", lambda: None)
    quick = ["--duration", "0.03", "--Ts", "0.01", "--N", "4", "--no-progress", "--forms", "absolute", "nonlinear",
             "--deadbeat-duration", "0.03"]
    assert main(["demo", "--out", str(tmp_path), *quick]) == 0
    assert view.INSTALL_HINT in capsys.readouterr().out
    assert not list(tmp_path.glob("*.html")) and len(list(tmp_path.glob("demo_*.npz"))) == 6  # α 0, α, encoders
    assert main(["view", str(tmp_path / "demo_absolute_a0.npz"), "--html", str(tmp_path / "x.html")]) == 2
    assert view.INSTALL_HINT in capsys.readouterr().err


def test_the_limits_line_names_its_units():
    """`track` on a 3-PRR printed "limits (robot file and flags): torque ±50, drive_position
    [-0.15, 0.15]": N or N·m, m or rad? The line names the drive unit and the SI units."""
    import argparse

    from parallel_gpc.cli.vocabulary import limits_line
    from parallel_gpc.limits import Limits

    lim = Limits(torque=50.0, drive_position=[[-0.15, 0.15]] * 3)
    line = limits_line(argparse.Namespace(limits="robot"), lim, "N")
    assert line == ("limits (robot file and flags; efforts in N, positions in m and rad): "
                    "torque ±50, drive_position [-0.15, 0.15] (soft)")
    assert limits_line(argparse.Namespace(limits="none"), Limits(), "N·m").startswith("limits (flags only; efforts in N·m")
