"""Adversarial inputs (issue 12): one table row per reproduced case, run through the CLI (exit 2,
one line naming the bad value, no traceback; with ``--debug`` the specific error type), the
Python API's type errors, and the console staying quiet around our messages."""

from __future__ import annotations

import errno
import os
import re
import shutil

import numpy as np
import pytest

from parallel_gpc.limits import Limits
from parallel_gpc import ParallelRobot, ReducedModel, cli
from parallel_gpc.errors import (
    FastStateError,
    InvalidParameterError,
    NonFiniteError,
    OutputError,
    ParallelGPCError,
    ResultFormatError,
    RobotFormatError,
    UnreachablePoseError,
)
from parallel_gpc.gpc.controller import GPCController
from parallel_gpc.gpc.criterion import Weights
from parallel_gpc.gpc.prediction import Horizons
from parallel_gpc.model.file_checks import SIDECAR_MAX_BYTES
from parallel_gpc.model.description import urdf_dir

URDF = (urdf_dir() / "planar_3rrr.urdf").read_text()
TOML = (urdf_dir() / "planar_3rrr.toml").read_text()
PLATFORM_MASS = '<mass value="5.0"/>'
PLATFORM_INERTIA = '<inertia ixx="0.028125" ixy="0" ixz="0" iyy="0.028125" iyz="0" izz="0.05625"/>'
GEPETTO = ("closed_loop: [[tip_1, attach_1], [tip_2, attach_2], [tip_3, attach_3]]\n"
           "name_mot: [drive_1, drive_2, drive_3]\noutput_joints: [platform_x, platform_y, platform_psi]\n")


def _edit(text: str, old: str, new: str) -> str:
    assert old in text, old
    return text.replace(old, new, 1)


def robot(tmp, stem, urdf=URDF, toml: str | bytes | None = TOML, yaml: str | None = None) -> str:
    """Write a robot (URDF + one sidecar) into tmp; return the URDF path."""
    (tmp / f"{stem}.urdf").write_text(urdf)
    if yaml is not None:
        (tmp / f"{stem}.yaml").write_text(yaml)
    elif isinstance(toml, bytes):
        (tmp / f"{stem}.toml").write_bytes(toml)
    else:
        (tmp / f"{stem}.toml").write_text(toml)
    return str(tmp / f"{stem}.urdf")


def mjcf(tmp, stem, replacement: str) -> str:
    """The 5-bar MJCF of tests/mechanisms.py with its first mass or diaginertia attribute replaced."""
    import mechanisms as mech

    key = replacement.split("=")[0]
    text = re.sub(rf'{key}="[^"]+"', replacement, mech.fivebar_mjcf(), count=1)
    return str(mech.write(tmp, stem, text, mech.fivebar_mjcf_sidecar(), ".xml"))


def sidecar(tmp, stem, old, new):
    return robot(tmp, stem, toml=_edit(TOML, old, new))


def link(tmp, stem, target):
    """A robot whose sidecar is a symlink to ``target``."""
    (tmp / f"{stem}.urdf").write_text(URDF)
    os.symlink(target, tmp / f"{stem}.toml")
    return str(tmp / f"{stem}.urdf")


def result_file(tmp, name, content: bytes | None = None, **arrays) -> str:
    path = tmp / name
    if content is not None:
        path.write_bytes(content)
    else:
        np.savez(path, **arrays)
    return str(path)


def track_result(tmp) -> bytes:
    """The bytes of a real result file (a short track run)."""
    assert cli.main(["track", "--form", "absolute", "--duration", "0.02", "--Ts", "0.01", "--N", "4",
                     "--no-progress", "--out", str(tmp / "run")]) == 0
    return (tmp / "run" / "track_absolute.npz").read_bytes()


QUICK = ["--no-progress", "--duration", "0.04", "--Ts", "0.01", "--N", "4"]
DRIVES = 'joints = ["drive_1", "drive_2", "drive_3"]'
OUTPUTS = 'joints = ["platform_x", "platform_y", "platform_psi"]'

# Each row: issue item and case, argv(tmp), error type (with --debug), substrings of the one-line message.
ROWS = [
    # 1. invalid physics
    ("1 negative mass", lambda t: ["info", robot(t, "m", urdf=_edit(URDF, PLATFORM_MASS, '<mass value="-5.0"/>'))],
     RobotFormatError, ["'platform'", "-5.0", ">= 0"]),
    ("1 infinite mass", lambda t: ["info", robot(t, "m", urdf=_edit(URDF, PLATFORM_MASS, '<mass value="inf"/>'))],
     RobotFormatError, ["'platform'", "'inf'", "finite"]),
    ("1 zero mass with a negative inertia", lambda t: ["info", robot(t, "m", urdf=_edit(_edit(
        URDF, PLATFORM_MASS, '<mass value="0"/>'), PLATFORM_INERTIA, PLATFORM_INERTIA.replace('0.05625', '-0.05625')))],
     RobotFormatError, ["'izz': -0.05625", "semi-definite"]),
    ("1 non-PD inertia", lambda t: ["info", robot(t, "i", urdf=_edit(URDF, PLATFORM_INERTIA, PLATFORM_INERTIA.replace(
        'ixy="0"', 'ixy="0.5"')))], RobotFormatError, ["'ixy': 0.5", "positive semi-definite"]),
    ("1 inertia breaks the triangle inequality", lambda t: ["info", robot(t, "i", urdf=_edit(
        URDF, PLATFORM_INERTIA, PLATFORM_INERTIA.replace('0.028125', '0.01')))], RobotFormatError,
     ["'ixx': 0.01", "triangle inequality"]),
    ("1 MJCF negative mass (the parser makes it 0)", lambda t: ["info", mjcf(t, "neg", 'mass="-1.0"')],
     RobotFormatError, ["'prox1'", "'-1.0'", ">= 0"]),
    ("1 MJCF inertia breaks the triangle inequality", lambda t: ["info", mjcf(t, "tri", 'diaginertia="0.001 0.001 0.01"')],
     RobotFormatError, ["'prox1'", "triangle inequality"]),
    ("1 duplicate drives", lambda t: ["info", sidecar(t, "d", DRIVES, 'joints = ["drive_1", "drive_1", "drive_3"]')],
     RobotFormatError, ["drive joints", "['drive_1']", "more than once"]),
    # 2. wrong types and files that ended in a traceback
    ("2 closure kind is a list", lambda t: ["info", sidecar(t, "k", 'kind = "point"', 'kind = ["point"]')],
     RobotFormatError, ["closures[0].kind = ['point']", "string"]),
    ("2 home pose is a string", lambda t: ["info", sidecar(t, "p", "pose = [0.5, 0.5, 0.0]", 'pose = "center"')],
     RobotFormatError, ["home.pose = 'center'"]),
    ("2 q_guess value is a string", lambda t: ["info", sidecar(t, "q", "drive_1 = -0.274", 'drive_1 = "x"')],
     RobotFormatError, ["home.q_guess.drive_1 = 'x'"]),
    ("2 empty drive list", lambda t: ["info", sidecar(t, "j", DRIVES, "joints = []")],
     RobotFormatError, ["drives.joints = []", "non-empty"]),
    ("2 YAML home is a list", lambda t: ["info", robot(t, "y", yaml=GEPETTO + "home: [1, 2]\n")],
     RobotFormatError, ["home = [1, 2]", "table"]),
    ("2 YAML type is a number", lambda t: ["info", robot(t, "y", yaml=GEPETTO + "type: 5\n")],
     RobotFormatError, ["type = 5"]),
    ("2 non-UTF-8 sidecar", lambda t: ["info", robot(t, "u", toml=b'name = "\xff\xfe"\n')],
     RobotFormatError, ["u.toml", "UTF-8", "0xff"]),
    ("2 empty robot name", lambda t: ["info", ""], RobotFormatError, ["empty"]),
    # (meshes outside the allowed roots no longer stop the load: tests/test_published_features.py)
    ("2 view an empty npz", lambda t: ["view", result_file(t, "e.npz", b"")], ResultFormatError,
     ["e.npz", "not a NumPy .npz"]),
    ("2 view a truncated npz", lambda t: ["view", result_file(t, "cut.npz", track_result(t)[:3000])],
     ResultFormatError, ["cut.npz"]),
    ("2 view an npz with string times", lambda t: ["view", result_file(
        t, "s.npz", t=np.array(["a", "b"]), q=np.zeros((2, 3)), robot="planar_4rrr")], ResultFormatError,
     ["'t'", "<U1"]),
    ("2 track --N 100000", lambda t: ["track", "--N", "100000", "--out", str(t / "o"), *QUICK[:3]],
     InvalidParameterError, ["N = 100000", "TiB", "limit is 1 GiB"]),
    ("2 plan --Nmax 100000", lambda t: ["plan", "--Nmax", "100000", "--no-progress", "--out", str(t / "o")],
     InvalidParameterError, ["N = 100000", "TiB", "limit is 1 GiB"]),
    # 3. unbounded reads
    ("3 sidecar is a symlink to /dev/zero", lambda t: ["info", link(t, "z", "/dev/zero")], RobotFormatError,
     ["z.toml", "not a regular file"]),
    ("3 oversized sidecar", lambda t: ["info", robot(t, "big", toml="#" * (SIDECAR_MAX_BYTES + 1))],
     RobotFormatError, [str(SIDECAR_MAX_BYTES + 1), str(SIDECAR_MAX_BYTES)]),
    ("3 result file is /dev/zero", lambda t: ["view", "/dev/zero"], ResultFormatError,
     ["/dev/zero", "not a regular file"]),
    # 5. no false "interrupted"
    ("5 track --Ts 1e9", lambda t: ["track", "--Ts", "1e9", "--no-progress", "--out", str(t / "o")],
     InvalidParameterError, ["Ts = 1e+09", "duration"]),
    ("5 track Ts > duration", lambda t: ["track", "--Ts", "0.05", "--duration", "0.01", "--no-progress",
                                         "--out", str(t / "o")], InvalidParameterError, ["Ts = 0.05", "0.01"]),
    # 6. outputs checked before running
    ("6 track --out EXISTING_FILE", lambda t: (t / "taken").write_text("x") and
     ["track", *QUICK, "--out", str(t / "taken")], InvalidParameterError, ["taken", "existing file"]),
    ("6 plan --out under a file", lambda t: (t / "taken").write_text("x") and
     ["plan", "--no-progress", "--out", str(t / "taken" / "sub")], InvalidParameterError, ["taken", "existing file"]),
    ("6 track --html FOLDER", lambda t: ["track", *QUICK, "--out", str(t / "o"), "--html", str(t)],
     InvalidParameterError, ["--html", "folder"]),
    # 7. the absolute form has no Δu limit
    ("7 track --form absolute --du-limit 1", lambda t: ["track", "--form", "absolute", "--du-limit", "1", *QUICK,
                                                        "--out", str(t / "o")], InvalidParameterError,
     ["du_limit = 1.0", "absolute"]),
    # 10. messages that name the cause
    ("10 identical closure frames", lambda t: ["info", sidecar(t, "f", 'frames = ["tip_1", "attach_1"]',
                                                              'frames = ["tip_1", "tip_1"]')],
     RobotFormatError, ["'leg_1'", "'tip_1'", "identical closure frames"]),
    ("10 the same closure twice", lambda t: ["info", sidecar(t, "f", 'frames = ["tip_2", "attach_2"]',
                                                            'frames = ["attach_1", "tip_1"]')],
     RobotFormatError, ["'leg_1'", "'leg_2'", "attach_1"]),
    ("10 duplicate output joints", lambda t: ["info", sidecar(t, "o", OUTPUTS,
                                                              'joints = ["platform_x", "platform_x", "platform_psi"]')],
     RobotFormatError, ["output joints", "['platform_x']"]),
    ("10 random bytes as result file", lambda t: ["view", result_file(t, "r.npz", bytes(range(256)) * 8)],
     ResultFormatError, ["r.npz", "not a NumPy .npz"]),
    ("10 a folder as result file", lambda t: (t / "d.npz").mkdir() or ["view", str(t / "d.npz")],
     ResultFormatError, ["d.npz", "is a folder"]),
    ("10 a folder as robot", lambda t: ["info", str(t)], RobotFormatError, ["robot path", "is a folder"]),
    ("10 --force 1e300 (the plant diverges)", lambda t: ["track", "--form", "absolute", "--force", "1e300", "0", "0",
                                                         *QUICK, "--out", str(t / "o")], NonFiniteError,
     ["platform_force = [1e+300, 0.0, 0.0]", "diverged"]),
    ("10 view with another robot", lambda t: ["view", result_file(t, "r.npz", track_result(t)), "--robot", "planar_3rrr"],
     ResultFormatError, ["'planar_4rrr'", "'planar_3rrr' has nq = 9"]),
    ("10 --noise 1e6", lambda t: ["track", "--form", "absolute", "--noise", "1e6", *QUICK, "--out", str(t / "o")],
     UnreachablePoseError, ["noise_std", "1000000.0"]),
    # issue 24, 9: one-line errors, no traceback, before allocating
    *[(f"24.9 demo --deadbeat-duration {v}", lambda t, v=v: ["demo", "--deadbeat-duration", v, "--no-progress",
                                                           "--out", str(t / "o")],
       InvalidParameterError, ["dead-beat check duration", "must be finite and > 0"]) for v in ("nan", "inf", "0", "-1")],
    ("24.9 demo --deadbeat-duration below Ts", lambda t: ["demo", "--deadbeat-duration", "1e-4", "--no-progress",
                                                          "--out", str(t / "o")],
     InvalidParameterError, ["0.0001 s", "at least one sample"]),
    ("24.9 plan --settle 1000000000", lambda t: ["plan", "--settle", "1000000000", "--no-progress",
                                                 "--out", str(t / "o")],
     InvalidParameterError, ["settle_steps = 1000000000", "GiB", "reduce settle_steps"]),
]


@pytest.mark.parametrize("argv, error, needles", [r[1:] for r in ROWS], ids=[r[0] for r in ROWS])
def test_cli_bad_input_exits_2_with_one_line_naming_the_value(tmp_path, capfd, argv, error, needles):
    args = argv(tmp_path)
    capfd.readouterr()
    assert cli.main(args) == 2
    out, err = capfd.readouterr()
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("parallel-gpc: error:"), err
    assert "Traceback" not in err and "Traceback" not in out and "interrupted" not in out + err
    for needle in needles:
        assert needle in lines[0], f"{needle!r} not in {lines[0]!r}"
    with pytest.raises(error):
        cli.main(["--debug", *args])


def test_track_out_is_checked_before_the_run(tmp_path, monkeypatch):
    """``--out EXISTING_FILE`` fails before any simulation step."""
    from parallel_gpc.studies import tracking

    monkeypatch.setattr(tracking, "simulate", lambda *a, **k: pytest.fail("the run started"))
    (tmp_path / "taken").write_text("x")
    assert cli.main(["track", *QUICK, "--out", str(tmp_path / "taken")]) == 2


# ---------------------------------------------------------------------------- 11. the Python API's types
API_ROWS = [
    ("load(None)", lambda: ParallelRobot.load(None), RobotFormatError, ["None"]),
    ("load(5)", lambda: ParallelRobot.load(5), RobotFormatError, ["5", "int"]),
    ("ParallelRobot(name)", lambda: ParallelRobot("planar_4rrr"), RobotFormatError, ["str", "ParallelRobot.load"]),
    ("Weights('a')", lambda: Weights("a"), InvalidParameterError, ["Qy = 'a'"]),
    ("Weights(Qu=[1, 'x'])", lambda: Weights(1.0, [1, "x"]), InvalidParameterError, ["Qu = [1, 'x']"]),
    ("Weights(True)", lambda: Weights(True), InvalidParameterError, ["True"]),
    ("mass_scale='2'", lambda: ParallelRobot.load("planar_3rrr", mass_scale="2"), InvalidParameterError,
     ["mass_scale = '2'", "str"]),
    ("mass_scale=None", lambda: ParallelRobot.load("planar_3rrr", mass_scale=None), InvalidParameterError,
     ["mass_scale = None"]),
    ("Horizons('5')", lambda: Horizons("5"), InvalidParameterError, ["'5'"]),
]


@pytest.mark.parametrize("call, error, needles", [r[1:] for r in API_ROWS], ids=[r[0] for r in API_ROWS])
def test_api_wrong_types_raise_package_errors(call, error, needles):
    with pytest.raises(error) as info:
        call()
    assert isinstance(info.value, ParallelGPCError)
    for needle in needles:
        assert needle in str(info.value), f"{needle!r} not in {str(info.value)!r}"


def test_a_huge_velocity_is_named_not_called_a_singular_pose(robot4):
    """At home (cond(g) ≈ 10 at rest) a measured velocity of 1e5 m/s blows up the one-sample
    model: the error names the velocity, not a near-singular pose."""
    c = GPCController.build(ReducedModel(robot4), 0.005, Horizons(5))
    with pytest.raises(InvalidParameterError, match=r"measured velocity \[100000.0, 0.0, 0.0\]") as info:
        c.step(np.r_[0.5, 0.5, 0.0, 1e5, 0.0, 0.0], np.tile([0.5, 0.5, 0.0], (5, 1)))
    assert "at rest" in str(info.value) and "singular" not in str(info.value)
    assert isinstance(info.value, FastStateError)  # also a SingularPoseError: a closed loop keeps its samples


# ---------------------------------------------------------------------------- 12. console noise
def test_urdfdom_output_goes_into_our_message_not_the_console(tmp_path, capfd):
    bad = _edit(URDF, 'child link="distal_1"', 'child link="no_such_link"')
    path = robot(tmp_path, "tree", urdf=bad)
    capfd.readouterr()
    assert cli.main(["info", path]) == 2
    out, err = capfd.readouterr()
    assert out == "" and len(err.strip().splitlines()) == 1, err
    assert "no_such_link" in err and "urdfdom" in err


@pytest.mark.parametrize("solver", ["osqp-direct", "qpsolvers:osqp"])
def test_osqp_prints_nothing(robot4, capfd, solver):
    c = GPCController.build(ReducedModel(robot4), 0.005, Horizons(5), solver=solver, limits=Limits(torque=50.0))
    capfd.readouterr()
    for _ in range(3):  # limits inactive at rest: OSQP's polish finds no active set
        c.step(np.r_[0.5, 0.5, 0.0, 0.0, 0.0, 0.0], np.tile([0.5, 0.5, 0.0], (5, 1)))
    out, err = capfd.readouterr()
    assert "Polishing" not in out and out == "", out


def test_embedded_robots_pass_the_checks():
    """The policy accepts what we ship (masses > 0, inertias PD with the triangle inequality)."""
    for name in ("planar_3rrr", "planar_4rrr"):
        text = (urdf_dir() / f"{name}.urdf").read_text()
        masses = [float(m) for m in re.findall(r'<mass value="([^"]+)"', text)]
        assert masses and min(masses) > 0
        ParallelRobot.load(name)


def test_a_symlinked_robot_file_inside_a_folder_still_loads(tmp_path):
    """Bounded reads follow symlinks to regular files."""
    shutil.copy(urdf_dir() / "planar_3rrr.urdf", tmp_path / "r.urdf")
    os.symlink(urdf_dir() / "planar_3rrr.toml", tmp_path / "r.toml")
    assert ParallelRobot.load(tmp_path / "r.urdf").n_u == 3


# ---------------------------------------------------------------------------- issue 24, 12: writing fails
def _disk_full_after(nbytes: int):
    """A writer that puts ``nbytes`` into the open file, then fails like a full disk (ENOSPC)."""
    def write(target, *args, **kwargs):
        data = b"x" * nbytes
        if hasattr(target, "write"):
            target.write(data)
        else:
            with open(target, "wb") as fh:
                fh.write(data)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    return write


def test_a_full_disk_is_named_with_the_path_and_the_partial_file_removed(tmp_path, monkeypatch):
    from matplotlib.figure import Figure

    from parallel_gpc import results, save_result
    from parallel_gpc.plots import save_figure

    t = np.array([0.0, 0.1])
    target = tmp_path / "run.npz"
    monkeypatch.setattr(results.np, "savez_compressed", _disk_full_after(100))
    with pytest.raises(OutputError, match=re.escape(f"cannot write result file {str(target)!r}: No space left")) as e:
        save_result(target, None, t)
    assert e.value.errno == errno.ENOSPC and isinstance(e.value, OSError)
    assert not target.exists()  # no truncated archive left behind
    monkeypatch.undo()
    save_result(target, None, t)  # a good file ...
    good = target.read_bytes()

    def refuse(path, *args, **kwargs):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))

    monkeypatch.setattr(results, "open", refuse, raising=False)  # fails before writing anything
    with pytest.raises(OutputError, match="Permission denied"):
        save_result(target, None, t)
    assert target.read_bytes() == good  # ... that the failed write never touched is kept
    monkeypatch.undo()

    figure = tmp_path / "f.png"
    monkeypatch.setattr(Figure, "savefig", lambda self, path, **kw: _disk_full_after(10)(path))
    with pytest.raises(OutputError, match=re.escape(f"cannot write figure {str(figure)!r}: No space left")):
        save_figure(Figure(), figure)
    assert not figure.exists()
    with pytest.raises(OutputError, match=re.escape(f"cannot write figure {str(tmp_path / 'x.npz' / 'g.png')!r}")):
        (tmp_path / "x.npz").write_bytes(b"")
        save_figure(Figure(), tmp_path / "x.npz" / "g.png")  # its folder would be under a file


def test_cli_names_the_unwritable_file_on_one_line(tmp_path, monkeypatch, capfd):
    from parallel_gpc import results

    monkeypatch.setattr(results.np, "savez_compressed", _disk_full_after(100))
    capfd.readouterr()
    assert cli.main(["track", "--form", "absolute", *QUICK, "--out", str(tmp_path / "o")]) == 2
    err = capfd.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("parallel-gpc: error: cannot write result file"), err
    assert str(tmp_path / "o") in err[0] and "No space left on device" in err[0]
