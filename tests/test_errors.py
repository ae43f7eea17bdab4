"""Bad inputs: one table row per case — the call, the specific error class, and the offending
value that the message must name. Plus the CLI's one-line errors, solver failures that fall back
visibly, a controller that stops at a singular pose, and Ctrl-C keeping what was computed."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from parallel_gpc.limits import Limits
from parallel_gpc import ParallelRobot, ReducedModel, cli, discretize_zoh, load_description
from parallel_gpc.gpc.controller import GPCController
from parallel_gpc.errors import (
    AssemblyError,
    InfeasibleLimitsError,
    InvalidParameterError,
    NonFiniteError,
    ParallelGPCError,
    RobotFormatError,
    ShapeError,
    SingularPoseError,
    SolverNotFoundError,
    UnreachablePoseError,
)
from parallel_gpc.model.plant import ConstrainedPlant, ReducedPlant
from parallel_gpc.gpc.prediction import Horizons
from parallel_gpc.gpc.references import Hold, SampledTrajectory
from parallel_gpc.model.robot import urdf_dir
from parallel_gpc.sweeps import robustness_study
from parallel_gpc.studies import SimulationResult, simulate
from parallel_gpc.gpc.criterion import Weights
from parallel_gpc.solvers import make_solver

#: A direct (actuation) singularity of planar_3rrr: B_r loses rank there.
SINGULAR_3RRR = np.array([0.15021993, 0.1311108, 0.0])
HOME = np.array([0.5, 0.5, 0.0])
X_HOME = np.concatenate([HOME, np.zeros(3)])
TOML = (urdf_dir() / "planar_3rrr.toml").read_text()


@pytest.fixture(scope="module")
def r4():
    return ParallelRobot.load("planar_4rrr")


@pytest.fixture(scope="module")
def r3():
    return ParallelRobot.load("planar_3rrr")


def robot_file(tmp, stem, urdf=None, toml=None, yaml=None):
    """Write a robot (URDF + sidecar) into tmp and return the URDF path."""
    path = tmp / f"{stem}.urdf"
    if urdf is None:
        shutil.copy(urdf_dir() / "planar_3rrr.urdf", path)
    else:
        path.write_text(urdf)
    if yaml is not None:
        (tmp / f"{stem}.yaml").write_text(yaml)
    else:
        (tmp / f"{stem}.toml").write_text(TOML if toml is None else toml)
    return path


def sidecar_edit(old, new):
    assert old in TOML
    return TOML.replace(old, new)


def ctl(r4, **kw):
    kw.setdefault("Ts", 0.005)
    kw.setdefault("horizons", Horizons(5))
    return GPCController.build(ReducedModel(r4), **kw)


def window(n=5, pose=HOME):
    return np.tile(pose, (n, 1))


# Each row: id, call(tmp, r4, r3), error class, substrings the message must contain.
ROWS = [
    # ---- robot files
    ("malformed URDF XML", lambda t, r4, r3: ParallelRobot.load(robot_file(t, "badxml", urdf="<robot name='x'><link")),
     RobotFormatError, ["badxml.urdf"]),
    ("sidecar TOML syntax", lambda t, r4, r3: ParallelRobot.load(robot_file(t, "badtoml", toml="closures = [\n")),
     RobotFormatError, ["badtoml.toml"]),
    ("sidecar YAML syntax", lambda t, r4, r3: ParallelRobot.load(robot_file(t, "badyaml", yaml="a: [b\n")),
     RobotFormatError, ["badyaml.yaml"]),
    ("closure kind typo", lambda t, r4, r3: ParallelRobot.load(robot_file(
        t, "kind", toml=sidecar_edit('kind = "point"\nframes = ["tip_2"', 'kind = "pointt"\nframes = ["tip_2"'))),
     RobotFormatError, ["'pointt'", "point", "weld"]),
    ("unknown frame in a closure", lambda t, r4, r3: ParallelRobot.load(robot_file(
        t, "frame", toml=sidecar_edit('["tip_3", "attach_3"]', '["tip_3", "no_such_frame"]'))),
     RobotFormatError, ["no_such_frame", "leg_3"]),
    ("unknown drive joint", lambda t, r4, r3: ParallelRobot.load(robot_file(
        t, "joint", toml=sidecar_edit('"drive_2", "drive_3"]', '"drive_2", "drive_9"]'))),
     RobotFormatError, ["drive_9", "drive_3"]),
    ("unknown output joint", lambda t, r4, r3: ParallelRobot.load(robot_file(
        t, "outj", toml=sidecar_edit('"platform_x", "platform_y"', '"platform_x", "platform_q"'))),
     RobotFormatError, ["platform_q"]),
    ("drive list is a string", lambda t, r4, r3: ParallelRobot.load(robot_file(
        t, "drvstr", toml=sidecar_edit('joints = ["drive_1", "drive_2", "drive_3"]', 'joints = "drive_1"'))),
     RobotFormatError, ["'drive_1'", "list"]),
    ("non-numeric torque limit", lambda t, r4, r3: ParallelRobot.load(robot_file(
        t, "lim", toml=sidecar_edit("torque_limit = [60.0, 60.0, 60.0]", 'torque_limit = ["abc", 60.0, 60.0]'))),
     RobotFormatError, ["abc"]),
    ("negative torque limit in sidecar", lambda t, r4, r3: ParallelRobot.load(robot_file(
        t, "neglim", toml=sidecar_edit("torque_limit = [60.0, 60.0, 60.0]", "torque_limit = [60.0, -5.0, 60.0]"))),
     RobotFormatError, ["-5.0"]),
    ("Gepetto closure with one frame", lambda t, r4, r3: ParallelRobot.load(robot_file(
        t, "gep", yaml="closed_loop: [['tip_1']]\nname_mot: [drive_1]\noutput_joints: [platform_x]\n")),
     RobotFormatError, ["tip_1"]),
    ("unknown robot name", lambda t, r4, r3: load_description("nosuch_robot"), RobotFormatError,
     ["nosuch_robot", "planar_4rrr"]),
    ("closure that cannot be assembled", lambda t, r4, r3: ParallelRobot.load(robot_file(
        t, "asm", toml=sidecar_edit('["tip_3", "attach_3"]', '["attach_2", "attach_3"]'))),
     AssemblyError, ["leg_3", "attach_2", "attach_3"]),
    ("mass scale ≤ 0", lambda t, r4, r3: r3.with_mass_scale(-0.5), InvalidParameterError, ["-0.5"]),
    # ---- poses
    ("unreachable pose", lambda t, r4, r3: r4.assemble([2.5, 0.5, 0.0]), UnreachablePoseError, ["2.5"]),
    ("singular pose (with conditioning)", lambda t, r4, r3: r3.check_pose(SINGULAR_3RRR), SingularPoseError,
     ["0.15022", "cond(B_r)"]),
    ("controller at a singular pose", lambda t, r4, r3: GPCController.build(
        ReducedModel(r3), 0.005, Horizons(5)).step(np.r_[SINGULAR_3RRR, 0, 0, 0], window(5, SINGULAR_3RRR)),
     SingularPoseError, ["0.15022", "cond(g)"]),
    ("non-finite pose", lambda t, r4, r3: r4.assemble([np.nan, 0.5, 0.0]), NonFiniteError, ["nan"]),
    # ---- horizons
    ("N < 1", lambda t, r4, r3: Horizons(0), InvalidParameterError, ["N = 0"]),
    ("No ≥ N", lambda t, r4, r3: Horizons(5, No=5), InvalidParameterError, ["No = 5"]),
    ("Nu > N", lambda t, r4, r3: Horizons(5, Nu=6), InvalidParameterError, ["Nu = 6"]),
    ("Nu < 1", lambda t, r4, r3: Horizons(5, Nu=0), InvalidParameterError, ["Nu = 0"]),
    ("non-integer N", lambda t, r4, r3: Horizons(2.5), InvalidParameterError, ["2.5"]),
    # ---- weights
    ("NaN output weight", lambda t, r4, r3: ctl(r4, weights=Weights(np.nan, 0.0)), InvalidParameterError, ["nan"]),
    ("inf input weight", lambda t, r4, r3: ctl(r4, weights=Weights(1.0, [0, 0, np.inf, 0])), InvalidParameterError,
     ["inf"]),
    ("negative weight", lambda t, r4, r3: ctl(r4, weights=Weights([1.0, -3.0, 1.0], 0.0)), InvalidParameterError,
     ["-3.0"]),
    ("non-PSD weight matrix", lambda t, r4, r3: ctl(r4, weights=Weights([[1, 2, 0], [2, 1, 0], [0, 0, 1]], 0.0)),
     InvalidParameterError, ["-1.0"]),
    ("wrong-shaped weight", lambda t, r4, r3: ctl(r4, weights=Weights([1.0, 1.0], 0.0)), ShapeError, ["(2,)"]),
    # ---- references, states, measurements
    ("wrong-shaped reference", lambda t, r4, r3: ctl(r4).step(X_HOME, np.zeros((5, 2))), ShapeError, ["(5, 2)"]),
    ("NaN in the reference", lambda t, r4, r3: ctl(r4).step(X_HOME, np.r_[window(4), [[0.5, np.nan, 0.0]]]),
     NonFiniteError, ["nan"]),
    ("NaN in a sampled trajectory", lambda t, r4, r3: SampledTrajectory([0, 1], [[0.5, 0.5, 0], [np.nan, 0.5, 0]]),
     NonFiniteError, ["nan"]),
    ("NaN measured state", lambda t, r4, r3: ctl(r4).step(np.r_[0.5, 0.5, np.nan, 0, 0, 0], window()),
     NonFiniteError, ["nan"]),
    ("inf measured state", lambda t, r4, r3: ctl(r4).step(np.r_[0.5, 0.5, 0, np.inf, 0, 0], window()),
     NonFiniteError, ["inf"]),
    ("wrong-length state", lambda t, r4, r3: ctl(r4).step(np.zeros(5), window()), ShapeError, ["(5,)"]),
    ("NaN initial plant state", lambda t, r4, r3: ConstrainedPlant(r4, np.r_[0.5, np.nan, 0, 0, 0, 0], Ts=0.005),
     NonFiniteError, ["nan"]),
    ("NaN drive torque", lambda t, r4, r3: ReducedPlant(r4, X_HOME, Ts=0.005).step([0, np.nan, 0, 0]),
     NonFiniteError, ["nan"]),
    ("negative measurement noise", lambda t, r4, r3: simulate(ctl(r4), ReducedPlant(r4, X_HOME, Ts=0.005), Hold(HOME), 0.01,
                                                              noise_std=-0.1, progress=False),
     InvalidParameterError, ["-0.1"]),
    ("controller and plant of different robots", lambda t, r4, r3: simulate(
        ctl(r4), ReducedPlant(r3, X_HOME, Ts=0.005), Hold(HOME), 0.01, progress=False), ShapeError, ["planar_3rrr"]),
    # ---- sample time
    ("Ts = 0", lambda t, r4, r3: ctl(r4, Ts=0.0), InvalidParameterError, ["Ts = 0.0"]),
    ("Ts < 0", lambda t, r4, r3: ctl(r4, Ts=-0.001), InvalidParameterError, ["-0.001"]),
    ("Ts NaN in ZOH", lambda t, r4, r3: discretize_zoh(np.zeros((2, 2)), np.ones((2, 1)), None, float("nan")),
     InvalidParameterError, ["nan"]),
    ("plant Ts < 0", lambda t, r4, r3: ReducedPlant(r4, X_HOME, Ts=-0.002),
     InvalidParameterError, ["-0.002"]),
    # ---- limits
    ("negative torque limit", lambda t, r4, r3: ctl(r4, limits=Limits(torque=-1.0)), InfeasibleLimitsError, ["-1.0"]),
    ("zero Δu limit", lambda t, r4, r3: ctl(r4, form="incremental", limits=Limits(du=[1.0, 0.0, 1.0, 1.0])),
     InfeasibleLimitsError, ["0.0"]),
    ("torque limit of the wrong size", lambda t, r4, r3: ctl(r4, limits=Limits(torque=[10.0, 10.0, 10.0])), ShapeError,
     ["(3,)"]),
    ("u(k−1) beyond torque + Δu limits", lambda t, r4, r3: ctl(
        r4, form="incremental", u0=[20.0, 0, 0, 0], limits=Limits(torque=10.0, du=0.5)), InfeasibleLimitsError,
     ["20.0", "10.0", "0.5"]),
    ("Δu limit on the absolute form", lambda t, r4, r3: ctl(r4, limits=Limits(du=1.0)), InvalidParameterError,
     ["absolute"]),
    # ---- solvers and forms
    ("unavailable solver", lambda t, r4, r3: make_solver("gurobi"), SolverNotFoundError,
     ["gurobi", "osqp-direct", "daqp-direct"]),
    ("unavailable solver in a controller", lambda t, r4, r3: ctl(r4, solver="qpsolvers:nosuch", limits=Limits(torque=10.0)),
     SolverNotFoundError, ["nosuch", "qpsolvers:osqp"]),
    ("unknown form", lambda t, r4, r3: ctl(r4, form="relative"), InvalidParameterError, ["relative"]),
    ("robustness: unknown form", lambda t, r4, r3: robustness_study(forms=("bogus",)), InvalidParameterError,
     ["bogus"]),
    ("robustness: mass scale 0", lambda t, r4, r3: robustness_study(mass_scales=(0.0,)), InvalidParameterError,
     ["0.0"]),
]


@pytest.mark.parametrize("call, error, needles", [r[1:] for r in ROWS], ids=[r[0] for r in ROWS])
def test_bad_input_raises_specific_error_naming_the_value(tmp_path, r4, r3, call, error, needles):
    with pytest.raises(error) as info:
        call(tmp_path, r4, r3)
    assert isinstance(info.value, ParallelGPCError)
    message = str(info.value)
    for needle in needles:
        assert needle in message, f"{needle!r} not in {message!r}"


# ---------------------------------------------------------------------------- CLI
@pytest.fixture
def cli_with_robustness():
    """The CLI (its robustness command is registered)."""
    return cli


def _one_line_error(capsys, code, argv, cli_module=cli):
    assert cli_module.main(argv) == code
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("parallel-gpc: error:"), err
    assert "Traceback" not in err
    return lines[0]


def test_cli_bad_robot_exits_2_with_one_line(capsys):
    line = _one_line_error(capsys, 2, ["info", "nosuch_robot"])
    assert "nosuch_robot" in line


def test_cli_multi_line_parser_error_is_one_line(tmp_path, capsys):
    path = robot_file(tmp_path, "badyaml", yaml="a: [b\n")
    line = _one_line_error(capsys, 2, ["info", str(path)])
    assert "badyaml.yaml" in line


def test_cli_debug_shows_the_exception(capsys):
    with pytest.raises(RobotFormatError):
        cli.main(["--debug", "info", "nosuch_robot"])


@pytest.mark.parametrize("argv, needle", [
    (["robustness", "--N", "0"], "N = 0"),
    (["robustness", "--Ts", "-0.01"], "-0.01"),
    (["robustness", "--forms", "absolute", "bogus"], "'bogus' (choose from 'absolute', 'incremental', "
                                                     "'incremental-delayed', 'nonlinear', 'all')"),
    (["robustness", "--forms", "absolute,incremental"], "'absolute,incremental'"),  # the earlier comma spelling
    (["robustness", "--reference", "path"], "'path' is not one of auto, s-curve, circle, line, helix, hold, nor a .csv"),
    (["robustness", "--mass-scales", "0.7", "x"], "'x'"),
    (["robustness", "--robot", "nosuch_robot"], "nosuch_robot"),
])
def test_cli_robustness_bad_input_exits_2(cli_with_robustness, capsys, tmp_path, argv, needle):
    line = _one_line_error(capsys, 2, [*argv, "--out", str(tmp_path)], cli_with_robustness)
    assert needle in line


# ---------------------------------------------------------------------------- solver failures
@pytest.mark.parametrize("solver", ["osqp-direct", "proxqp-direct", "daqp-direct", "qpsolvers:osqp",
                                    "qr-first:daqp-direct"])
def test_infeasible_limits_fall_back_visibly(r4, solver):
    """A torque limit lowered below the held u(k−1) − δ admits no Δu: the QP reports it, the
    controller applies the projected QR solution with status 'fallback', no exception."""
    c = ctl(r4, form="incremental", solver=solver, u0=[9.8, 0.0, 0.0, 0.0], limits=Limits(torque=10.0, du=0.5))
    first = c.step(X_HOME, window())
    assert not first.fallback and first.result.ok
    c.limits = Limits(torque=5.0, du=0.5)  # drive derated while it holds ~9.8 N·m: |u| ≤ 5 needs Δu ≈ −4.8, but |Δu| ≤ 0.5
    u_prev = c.u_prev.copy()
    info = c.step(X_HOME, window())
    assert info.fallback and info.result.status == "fallback"
    assert "infeasible" in info.result.message
    assert np.all(np.isfinite(info.u))
    assert np.max(np.abs(info.u)) <= 5.0 + 1e-9  # the torque limit wins where both cannot hold
    others = np.arange(1, 4)
    assert np.all(np.abs(info.u[others] - u_prev[others]) <= 0.5 + 1e-9)  # Δu limit kept where it can
    assert not c.step(X_HOME, window()).fallback  # feasible again from the projected input


def test_fallbacks_are_counted_in_the_closed_loop(r4):
    c = ctl(r4, form="incremental", solver="daqp-direct", u0=[9.8, 0, 0, 0], limits=Limits(torque=10.0, du=0.5))
    c.limits = Limits(torque=5.0, du=0.5)
    res = simulate(c, ReducedPlant(r4, X_HOME, Ts=0.005), Hold(HOME), 0.05, progress=False)
    assert res.metrics()["fallbacks"] == 1 and res.fallback[0] and res.status[0] == "fallback"


def test_solver_exception_becomes_a_reported_fallback(r4):
    class Exploding:
        name = "exploding"

        def solve(self, problem, warm_start=None):
            raise RuntimeError("segfault-free explosion")

    c = ctl(r4, form="absolute", solver="daqp-direct", limits=Limits(torque=5.0))
    c._backend = Exploding()
    info = c.step(X_HOME, window(5, HOME + [0.05, 0, 0]))
    assert info.fallback and info.result.status == "fallback"
    assert "RuntimeError" in info.result.message and np.max(np.abs(info.u)) <= 5.0


# ---------------------------------------------------------------------------- singular pose in closed loop
def _through_singularity(r3, max_condition, torques: list) -> None:
    """Track a line through a planar_3rrr direct singularity; record max |u| of every step."""
    start = np.array([0.25, 0.25, 0.0])
    end = 2 * SINGULAR_3RRR - start
    t = np.linspace(0.0, 1.0, 101)
    ref = SampledTrajectory(t, start + np.outer(np.clip(t / 0.8, 0, 1), end - start))
    c = GPCController.build(ReducedModel(r3), 0.005, Horizons(10), Weights(1.0, 1e-4), max_condition=max_condition)
    plant = ConstrainedPlant(r3, np.r_[start, 0, 0, 0], Ts=0.005)
    for k in range(200):
        info = c.step(plant.X, ref.window(k * 0.005, 0.005, 10))
        torques.append(np.max(np.abs(info.u)))
        plant.step(info.u)


def test_controller_stops_at_a_singular_pose_before_torques_blow_up(r3):
    checked, unchecked = [], []
    with pytest.raises(SingularPoseError, match=r"cond\(g\)") as info:
        _through_singularity(r3, 1e3, checked)
    assert "max_condition" in str(info.value)
    try:  # the same run without the check, until the model or the plant gives up (through overflowing numbers:
        with np.errstate(over="ignore", invalid="ignore"):  # what the check is there to prevent)
            _through_singularity(r3, 1e300, unchecked)
    except (AssemblyError, SingularPoseError):
        pass
    except InvalidParameterError as exc:  # the pure-Python model's cond(g) reaches inf, not just > 1e300
        assert "measured velocity" in str(exc) and "too large" in str(exc)
    assert max(checked) < 200.0  # N·m: it stopped while the torques were still moderate
    assert max(unchecked) > 10 * max(checked)


# ---------------------------------------------------------------------------- Ctrl-C
class InterruptAfter(Hold):
    """A hold reference whose window() raises KeyboardInterrupt (Ctrl-C) after ``calls`` calls."""

    def __init__(self, target, calls):
        object.__setattr__(self, "target", tuple(target))
        object.__setattr__(self, "calls", calls)

    def window(self, t, Ts, N):
        object.__setattr__(self, "calls", self.calls - 1)
        if self.calls < 0:
            raise KeyboardInterrupt
        return super().window(t, Ts, N)


def test_ctrl_c_keeps_and_saves_the_partial_run(r4, tmp_path):
    res = simulate(ctl(r4), ReducedPlant(r4, X_HOME, Ts=0.005), InterruptAfter(HOME, 7), 1.0, progress=False)
    assert res.interrupted and len(res.t) == 7
    path = res.save(tmp_path / "partial.npz")
    with np.load(path) as data:
        assert bool(data["interrupted"]) and data["t"].shape == (7,)
    assert isinstance(res, SimulationResult)


def test_cli_robustness_ctrl_c_saves_partial_table_and_exits_130(cli_with_robustness, monkeypatch, tmp_path,
                                                                  capsys):
    from parallel_gpc.gpc import references as references

    calls = {"n": 0}
    original = references.SCurve.window

    def interrupting(self, t, Ts, N):
        calls["n"] += 1
        if calls["n"] > 10:
            raise KeyboardInterrupt
        return original(self, t, Ts, N)

    monkeypatch.setattr(references.SCurve, "window", interrupting)
    code = cli_with_robustness.main(["robustness", "--forms", "absolute", "--duration", "0.2", "--mass-scales",
                                     "--noise", "--disturbances", "--out", str(tmp_path)])
    assert code == 130
    rows = (tmp_path / "robustness.csv").read_text().strip().splitlines()
    assert len(rows) == 2 and rows[1].startswith("absolute,nominal") and rows[1].endswith("interrupted")
    assert "interrupted" in capsys.readouterr().err
