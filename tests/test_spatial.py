"""The embedded spatial robots (Delta, 6- and 8-leg hexapods) against independent oracles.

Pinocchio's ``constraintDynamics`` on the full open tree checks the reduced accelerations;
the closed loop runs on the full constrained plant; error bounds were measured and asserted
with a margin (measured values in the comments, from the tests' own settings).
"""

from __future__ import annotations

import functools
import re
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from parallel_gpc import ParallelRobot, ReducedModel, cli
from parallel_gpc.errors import InvalidParameterError, RobotFormatError
from parallel_gpc.gpc.planning import PlanSettings, hold_torque, plan_point_to_point
from parallel_gpc.gpc.references import Helix, path_for, pose_error_norms
from parallel_gpc.model.robot import urdf_dir
from parallel_gpc.studies import TrackingSettings, run_tracking

from test_dynamics import _pin_constraint_dynamics, assert_matches_constraint_dynamics

SPATIAL = ["delta_3rus", "hexapod_6ups", "hexapod_8ups"]


@functools.lru_cache(maxsize=None)
def load(name: str) -> ParallelRobot:
    """The embedded robot ``name``, loaded once per test session."""
    return ParallelRobot.load(name)


@pytest.fixture(params=SPATIAL)
def spatial(request) -> ParallelRobot:
    return load(request.param)


def _poses(robot: ParallelRobot, rng: np.random.Generator, n: int) -> np.ndarray:
    """Random poses in the box spanned by the sidecar's A and B (m, rad)."""
    A, B = np.array(robot.description.pose_a), np.array(robot.description.pose_b)
    lo, hi = np.minimum(A, B), np.maximum(A, B)
    return lo + rng.uniform(0.0, 1.0, (n, robot.n_y)) * (hi - lo)


def test_sizes_and_output_kinds():
    sizes = {name: (r.n_y, r.n_u, r.model.nq, r.output_angular.tolist())
             for name in SPATIAL for r in [ParallelRobot.load(name)]}
    assert sizes == {"delta_3rus": (3, 3, 12, [False] * 3),
                     "hexapod_6ups": (6, 6, 24, [False] * 3 + [True] * 3),
                     "hexapod_8ups": (6, 8, 30, [False] * 3 + [True] * 3)}


#: a number in generated text (not a digit inside a name such as ``drive_1`` or ``3rus``)
NUMBER = re.compile(r"(?<![\w.])[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?(?![\w.])")
#: a zero written with a sign (``-0``, ``-0.0000``, ``-0e+00``)
NEGATIVE_ZERO = re.compile(r"(?<![\w.])-0(?:\.0*)?(?:[eE][-+]?\d+)?(?![\w.])")


def _last_digit(token: str) -> float:
    """One unit of the last printed digit of a number token (``0.0123`` → 1e-4, ``6.4e-06`` → 1e-7)."""
    mantissa, _, exponent = token.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    return 10.0 ** (int(exponent or 0) - decimals)


def assert_same_up_to_last_digits(committed: str, generated: str, where: str) -> None:
    """The same text between the numbers, and each pair of numbers equal to one unit of its last
    printed digit: rounding that differs between machines (libm, BLAS) does not fail the test."""
    assert NUMBER.split(committed) == NUMBER.split(generated), f"{where}: text outside the numbers differs"
    ours, theirs = NUMBER.findall(committed), NUMBER.findall(generated)
    assert len(ours) == len(theirs), where
    for a, b in zip(ours, theirs):
        unit = max(_last_digit(a), _last_digit(b))
        assert abs(float(a) - float(b)) <= 1.5 * unit, f"{where}: {a} (committed) vs {b} (generated)"


def test_number_comparison_of_generated_text():
    same = assert_same_up_to_last_digits
    same("x = 0.0000\nname = drive_1", "x = -0.0000\nname = drive_1", "signed zero")
    same('xyz="0.1 -0.0433012701892 6.4e-06"', 'xyz="0.1 -0.0433012701893 6.4e-06"', "last digit")
    for other in ("x = 0.0002\nname = drive_1", "x = 0.0000\nname = drive_2", "x = 0.0000 1\nname = drive_1"):
        with pytest.raises(AssertionError):
            same("x = 0.0000\nname = drive_1", other, "differs")
    assert NEGATIVE_ZERO.search("a = -0.0000") and NEGATIVE_ZERO.search("[-0, 1]")
    assert not NEGATIVE_ZERO.search("b = -0.02 c = 1e-07 d = -0.0001 drive_-0x")


def test_generated_files_are_up_to_date():
    """The committed files are what urdf/generate.py writes, up to the last printed digit of each
    number; neither writes a negative zero."""
    sys.path.insert(0, str(Path(urdf_dir())))
    try:
        import generate
        from generate_spatial import SPATIAL_ROBOTS
    finally:
        sys.path.pop(0)
    files = {name: (generate.urdf_text(name, n_legs), generate.sidecar_text(name, n_legs))
             for name, n_legs in (("planar_4rrr", 4), ("planar_3rrr", 3))}
    files.update({name: make() for name, make in SPATIAL_ROBOTS.items()})
    for name, (urdf, toml) in files.items():
        for suffix, generated in ((".urdf", urdf), (".toml", toml)):
            committed = (urdf_dir() / f"{name}{suffix}").read_text()
            assert_same_up_to_last_digits(committed, generated, f"{name}{suffix}")
            for text in (committed, generated):
                assert not NEGATIVE_ZERO.search(text), f"{name}{suffix}: {NEGATIVE_ZERO.search(text).group()!r}"


def test_closure_residual_after_assembly_and_conditioning(spatial):
    rng = np.random.default_rng(3)
    q = None
    poses = [spatial.home_pose, spatial.description.pose_a, spatial.description.pose_b, *_poses(spatial, rng, 8)]
    for pose in poses:
        q = spatial.assemble(pose, q)
        assert np.max(np.abs(spatial.closure_residual(q))) <= 1e-10
        np.testing.assert_allclose(spatial.platform_pose(q), pose, atol=1e-14)
        cond = spatial.singularity(q)
        assert cond["cond_phi_z"] < 20 and cond["cond_B_r"] < 30  # measured ≤ 6.2 and ≤ 13.2


def test_reduced_accelerations_equal_pinocchio_constraint_dynamics(spatial):
    model = ReducedModel(spatial)
    rng = np.random.default_rng(7)
    scale = np.where(spatial.output_angular, 0.5, 0.3)  # rad/s, m/s
    for pose in _poses(spatial, rng, 8):
        X = np.concatenate([pose, rng.uniform(-1.0, 1.0, spatial.n_y) * scale])
        u = rng.uniform(-0.3, 0.3, spatial.n_u) * spatial.torque_limit
        assert_matches_constraint_dynamics(spatial, model.terms(X), u)


def test_gravity_loads_the_drives_of_the_upright_robots(spatial):
    """Gravity (−z) enters as the affine term c of the factorization; the hold torque balances it."""
    model = ReducedModel(spatial)
    X = np.concatenate([spatial.home_pose, np.zeros(spatial.n_y)])
    _, _, c = model.factorize(X)
    assert np.linalg.norm(c) > 1.0  # m/s²: the free fall of the platform
    u = hold_torque(model, spatial.home_pose)
    np.testing.assert_allclose(model.acceleration(X, u), 0.0, atol=1e-9)
    ddq, _ = _pin_constraint_dynamics(spatial, model.terms(X).q, np.zeros(spatial.model.nv), u)
    assert np.max(np.abs(ddq)) <= 1e-8


# ------------------------------------------------------------------------------ references
def test_helix_starts_rises_and_returns_its_angles():
    h = Helix((0.1, 0.0, -0.5, 0.2), radius=0.05, rise=0.1, angle_amplitude=(0.3,), duration=2.0)
    np.testing.assert_allclose(h.pose(0.0), [0.1, 0.0, -0.5, 0.2], atol=1e-15)
    np.testing.assert_allclose(h.pose(1.0), [0.0, 0.0, -0.45, 0.2], atol=1e-12)  # half a turn, half the rise
    np.testing.assert_allclose(h.pose(2.0), [0.1, 0.0, -0.4, 0.2], atol=1e-12)
    radius = [np.hypot(*(h.pose(t)[:2] - [0.05, 0.0])) for t in np.linspace(0, 2, 9)]
    np.testing.assert_allclose(radius, 0.05, atol=1e-12)


@pytest.mark.parametrize("kwargs, match", [
    (dict(start=(0.0, 0.0)), "position_columns"),
    (dict(start=(0.0, 0.0, 0.0, 0.0), angle_amplitude=(0.1, 0.2)), "angle_amplitude has 2"),
    (dict(start=(0.0, 0.0, 0.0), radius=-1.0), "radius"),
    (dict(start=(0.0, 0.0, float("nan"))), "start"),
])
def test_bad_helix_is_rejected(kwargs, match):
    with pytest.raises(InvalidParameterError, match=match):
        Helix(**kwargs)


def test_default_path_depends_on_the_outputs(robot4):
    delta, hexapod = load("delta_3rus"), load("hexapod_6ups")
    assert type(path_for("auto", robot4.home_pose, robot4.output_angular, 2.0)).__name__ == "SCurve"
    for r in (delta, hexapod):
        ref = path_for("auto", r.home_pose, r.output_angular, 2.0)
        assert isinstance(ref, Helix)
        xy = np.array([ref.pose(t)[:2] for t in np.linspace(0.0, 2.0, 41)])
        np.testing.assert_allclose(np.hypot(*(xy - r.home_pose[:2]).T), ref.radius, atol=1e-12)  # about home
        np.testing.assert_allclose(ref.pose(1.0)[2:3], r.home_pose[2:3], atol=1e-12)  # mid-height at home
    s_curve = path_for("s-curve", hexapod.home_pose, hexapod.output_angular, 2.0)  # in the x-y plane about home
    assert s_curve.columns == (0, 1)
    np.testing.assert_allclose(s_curve.sample([0.0, 1.0, 2.0])[:, :2] - hexapod.home_pose[:2],
                               [[0.0, -2 * s_curve.size], [0.0, 0.0], [0.0, 2 * s_curve.size]], atol=1e-15)
    with pytest.raises(InvalidParameterError, match=r"helix needs 3 translational outputs; this robot's outputs are "
                                                    r"\[x m, y m, psi rad\]"):
        path_for("helix", robot4.home_pose, robot4.output_angular, 2.0, labels=("x", "y", "psi"))


def test_error_norms_split_translations_and_angles():
    e = np.array([[3.0, 4.0, 12.0, 1.0, 0.0, 0.0]])
    pos, ang = pose_error_norms(e, [False] * 3 + [True] * 3)
    np.testing.assert_allclose([pos[0], ang[0]], [13.0, 1.0])
    pos, ang = pose_error_norms(e[:, :3])  # planar convention: x, y in m, psi in rad
    np.testing.assert_allclose([pos[0], ang[0]], [5.0, 12.0])


# ------------------------------------------------------------------------------ closed loop
def _track(robot, forms, **kw):
    settings = TrackingSettings.from_flat(robot=robot.name, Ts=0.004, N=15, **kw)
    return run_tracking(settings, forms, progress=False, robot=robot)


@pytest.mark.slow
@pytest.mark.parametrize("name, bounds", [
    # (max position error m, max orientation error rad) per form; measured (Ts 4 ms, N 15, Qu 0):
    # delta absolute 9.3e-8 m, nonlinear 4.7e-9 m; hexapod absolute 8.0e-8 m / 2.7e-7 rad,
    # nonlinear 3.6e-9 m / 1.6e-8 rad
    ("delta_3rus", {"absolute": (5e-7, 1e-12), "nonlinear": (2e-8, 1e-12)}),
    ("hexapod_6ups", {"absolute": (5e-7, 1e-6), "nonlinear": (2e-8, 5e-8)}),
])
def test_gpc_tracks_the_helix_on_the_constrained_plant(name, bounds):
    robot = load(name)
    results = _track(robot, tuple(bounds))
    for form, (pos_bound, ang_bound) in bounds.items():
        res = results[form]
        m = res.metrics()
        span = np.ptp(res.reference[:, :3], axis=0)
        np.testing.assert_allclose(span, [0.16, 0.16, 0.12], rtol=0.02)  # the helix was run, not a hold
        assert m["max_position_error_m"] <= pos_bound, (form, m["max_position_error_m"])
        assert m["max_orientation_error_rad"] <= ang_bound, (form, m["max_orientation_error_rad"])
        assert m["fallbacks"] == 0
        # the closures of the full plant stay closed along the run
        assert max(np.max(np.abs(robot.closure_residual(q))) for q in res.q[::25]) <= 1e-8


@pytest.mark.parametrize("form, Qu, bound", [("absolute", 1e-4, 1e-6), ("incremental", 1e-4, 1e-9)])
def test_controllers_hold_position_under_gravity(form, Qu, bound):
    delta = load("delta_3rus")
    res = _track(delta, (form,), Qu=Qu, reference="hold", duration=1.0)[form]
    target = delta.home_pose + 0.02
    np.testing.assert_allclose(res.reference[-1], target)
    pos, _ = pose_error_norms(res.pose[-20:] - target, res.angular)
    # measured 1.5e-7 m (absolute: Qu > 0 trades a small offset for the gravity load) and 6e-17 m
    # (incremental: its disturbance estimate removes the offset)
    assert pos.max() <= bound
    assert np.min(res.u[-1]) < -0.5  # the drives carry the platform's weight (N·m)


@pytest.mark.slow
def test_redundant_hexapod_has_no_internal_force():
    results = _track(load("hexapod_8ups"), ("absolute", "nonlinear"), torque_limit=None)
    for form, res in results.items():
        m = res.metrics()
        assert m["max_internal_force"] <= 1e-6, form  # measured 1.2e-10 N
        assert m["max_position_error_m"] <= 5e-7 and m["peak_drive_effort"] > 50.0  # the drives do work


# ------------------------------------------------------------------------------ planning
@pytest.mark.parametrize("name", ["delta_3rus", "hexapod_6ups"])
def test_plan_mode_b_stops_at_B(name):
    robot = load(name)
    A, B = robot.description.pose_a, robot.description.pose_b
    res = plan_point_to_point(robot, A, B, PlanSettings(), mode="b")
    pos, ang = res.end_error
    assert pos <= 5e-6 and ang <= 5e-6  # measured 5.3e-7 m (delta), 6.3e-7 m / 7.3e-7 rad (hexapod)
    assert res.time_to_reach <= 1.4  # measured 1.27 s for a 1.2 s move
    lin, rot = res.end_speed
    assert lin <= 1e-4 and rot <= 1e-4
    assert np.linalg.norm(np.asarray(A) - B) > 0.1  # a real 3-D move


def test_sidecar_poses_are_validated(tmp_path):
    src = urdf_dir() / "delta_3rus"
    (tmp_path / "d.urdf").write_text(src.with_suffix(".urdf").read_text())
    (tmp_path / "d.toml").write_text(src.with_suffix(".toml").read_text().replace(
        "A = [-0.1, -0.08, -0.58]", "A = [-0.1, -0.08]"))
    with pytest.raises(RobotFormatError, match=r"home.A = \[-0.1, -0.08\] must hold 3 finite numbers"):
        ParallelRobot.load(tmp_path / "d.urdf")


# ------------------------------------------------------------------------------ command line
def test_cli_info_reports_reach_and_conditioning(capsys):
    for name in SPATIAL:
        assert cli.main(["info", name]) == 0
        out = capsys.readouterr().out
        assert "segment A -> B" in out and "NOT reachable" not in out


def test_cli_plan_rejects_a_pose_of_the_wrong_size(capsys):
    assert cli.main(["plan", "--robot", "hexapod_6ups", "--A", "0", "0", "0.7"]) == 2
    assert "--A has 3 values; robot 'hexapod_6ups' has 6 outputs" in capsys.readouterr().err


def test_cli_track_runs_the_helix_on_the_hexapod(tmp_path, capsys):
    code = cli.main(["track", "--robot", "hexapod_8ups", "--form", "nonlinear", "--Ts", "0.01", "--N", "8",
                     "--duration", "0.3", "--out", str(tmp_path), "--no-progress"])
    assert code == 0
    with np.load(tmp_path / "track_nonlinear.npz") as data:
        assert data["reference"].shape == (30, 6) and data["q"].shape == (30, 30)
    rows = [line.split() for line in capsys.readouterr().out.splitlines() if line.startswith("nonlinear")]
    assert len(rows) == 1 and float(rows[0][1]) < 1.0  # RMS position error in mm


# ------------------------------------------------------------------------------ view
def test_view_draws_every_leg_and_closes_the_loops(spatial):
    from parallel_gpc import viz

    scene = viz.RobotScene(SimpleNamespace(path=viz.meshcat.path.Path(("meshcat",))), spatial)
    n_legs = len(spatial.description.closures)
    base = scene.base_points()
    assert base.shape == (n_legs, 3)  # one ground joint per leg, not the platform's virtual joints
    np.testing.assert_allclose(np.hypot(base[:, 0], base[:, 1]), base[0, 0] if n_legs == 3 else 0.5, atol=1e-12)
    T = dict(zip(scene.paths, scene.placements(spatial.assemble(spatial.description.pose_b))))
    assert sum(path.startswith("robot/") and "closures" not in path for path in T) >= 2 * n_legs + 1
    for c in spatial.description.closures:
        np.testing.assert_allclose(T[f"robot/closures/{c.name}_a"][:3, 3], T[f"robot/closures/{c.name}_b"][:3, 3],
                                   atol=1e-9)


class _RecordingVis:
    """A stand-in meshcat visualizer that records the objects set at each path."""

    def __init__(self, log: dict, name: str = ""):
        from parallel_gpc import viz

        self.log, self.name, self.path = log, name, viz.meshcat.path.Path(("meshcat",))

    def __getitem__(self, key: str) -> "_RecordingVis":
        return _RecordingVis(self.log, f"{self.name}/{key}")

    def set_object(self, obj, material=None) -> None:
        self.log[self.name] = obj

    def set_transform(self, matrix=None) -> None:
        pass

    def set_property(self, key, value) -> None:
        pass

    def set_animation(self, animation, play=True, repetitions=1) -> None:
        self.log["animation"] = animation


def test_view_draws_the_reference_path_in_3d():
    from parallel_gpc import viz

    delta = load("delta_3rus")
    ref = path_for("auto", delta.home_pose, delta.output_angular, 2.0)
    t = np.linspace(0.0, 2.0, 5)
    poses = ref.sample(t)
    qs, q = [], None
    for pose in poses:
        q = delta.assemble(pose, q)
        qs.append(q)
    log = {}
    viz.animate(_RecordingVis(log), delta, t, np.array(qs), reference=poses)
    line = log["/paths/reference"]
    np.testing.assert_allclose(np.asarray(line.geometry.position).T, poses, atol=1e-6)  # float32 x, y, z
    assert "animation" in log
