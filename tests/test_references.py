"""Vectorized reference windows and samples against the pose-by-pose evaluation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from parallel_gpc.gpc.references import Helix, Hold, SampledTrajectory, SCurve, path_for, quintic, quintic_array

TS = 1e-3  # s


def _pose_by_pose(ref, t: float, Ts: float, N: int) -> np.ndarray:
    """The window as N separate pose() calls (the definition: poses at t + Ts … t + N·Ts)."""
    return np.array([ref.pose(t + (j + 1) * Ts) for j in range(N)])


REFERENCES = {
    "s-curve": SCurve(duration=2.0, t_start=0.3),
    "helix-with-angles": path_for("helix", [0.1, -0.05, 0.6, 0.02, -0.01, 0.0],
                                  [False, False, False, True, True, True], 2.0),
    "helix-positions-only": Helix((0.0, 0.1, 0.5), turns=1.5, rise=-0.1, duration=1.0),
    "helix-columns-permuted": Helix((0.2, 0.4, 0.1, -0.3), position_columns=(3, 0, 1),
                                    angle_amplitude=(0.2,), duration=1.5),
    "hold": Hold((0.55, 0.55, math.radians(5.0))),
    "sampled": SampledTrajectory(np.linspace(0.0, 1.0, 7), np.random.default_rng(0).normal(size=(7, 3))),
}


@pytest.mark.parametrize("name", list(REFERENCES))
def test_window_equals_pose_by_pose(name):
    """Before the start, across the S-curve's switch of half circles (s = 0.5), at the end and
    after it, with several horizons and sample times."""
    ref = REFERENCES[name]
    for t in (-0.05, 0.0, 0.3, 0.77, 1.29, 1.3, 1.3005, 1.9, 2.29, 2.3, 3.0):
        for Ts, N in ((TS, 20), (0.01, 7), (0.05, 40), (TS, 1)):
            w = ref.window(t, Ts, N)
            expected = _pose_by_pose(ref, t, Ts, N)
            assert w.shape == expected.shape
            np.testing.assert_allclose(w, expected, rtol=0, atol=1e-14)


def test_window_moves_and_crosses_the_half_circle_switch():
    """The S-curve window is not constant and spans both half circles around the switch."""
    ref = SCurve(duration=2.0)
    t_mid = 1.0  # quintic symmetric: s = 0.5 at half the duration
    w = ref.window(t_mid - 0.01, TS, 20)
    s = quintic_array((t_mid - 0.01 + TS * np.arange(1, 21)) / 2.0)
    assert s.min() < 0.5 < s.max()
    assert np.ptp(w[:, 0]) > 1e-6 and np.ptp(w[:, 2]) > 1e-6


@pytest.mark.parametrize("name", list(REFERENCES))
def test_sample_equals_pose_by_pose(name):
    ref = REFERENCES[name]
    times = np.linspace(-0.5, 3.5, 57)
    np.testing.assert_allclose(ref.sample(times), np.array([ref.pose(float(t)) for t in times]), rtol=0, atol=1e-14)


def test_quintic_array_equals_quintic():
    tau = np.linspace(-0.5, 1.5, 401)
    # x**3 of numpy and of Python may round differently in the last bit
    np.testing.assert_allclose(quintic_array(tau), [quintic(float(x)) for x in tau], rtol=0, atol=1e-15)


# ------------------------------------------------------------------ references in any output space
from pathlib import Path  # noqa: E402

from parallel_gpc import ParallelRobot  # noqa: E402
from parallel_gpc.errors import InvalidParameterError, SingularPoseError, UnreachablePoseError  # noqa: E402
from parallel_gpc.gpc.references import OutputPath  # noqa: E402
from parallel_gpc.gpc.robot_references import (  # noqa: E402
    WORKSPACE_FRACTION, check_reference, check_times, ray_reach, reference_for, sized_path)
from parallel_gpc.model.output_space import OutputSpace  # noqa: E402

from mechanisms import write  # noqa: E402
from parallel_gpc.model.description import urdf_dir  # noqa: E402

FIVEBAR = Path(__file__).resolve().parents[1] / "docs" / "your-robot" / "fivebar.urdf"
T = np.linspace(-0.1, 2.1, 301)


@pytest.fixture(scope="module")
def fivebar():
    return ParallelRobot.load(FIVEBAR)


def test_circle_poses_lie_on_the_circle_and_other_outputs_swing_back():
    ref = path_for("circle", [0.1, 0.2, 0.3, 0.0], [False, True, False, True], 2.0, size=0.05)
    assert ref.columns == (0, 2)
    p = ref.sample(T)
    np.testing.assert_allclose(np.hypot(p[:, 0] - 0.1, p[:, 2] - 0.3), 0.05, rtol=1e-13)
    np.testing.assert_allclose(p[[0, -1]][:, [0, 2]], [[0.15, 0.3]] * 2, atol=1e-15)  # one full turn from +x
    s = quintic_array(T / 2.0)
    np.testing.assert_allclose(p[:, [1, 3]], np.column_stack([0.2 + 0.05 * np.sin(2 * np.pi * s),
                                                              0.05 * np.sin(2 * np.pi * s)]), atol=1e-15)


def test_generic_s_curve_is_the_papers_shape_about_home():
    """The output-space S-curve against the paper's SCurve (an independent formula) moved to start
    2·size below home."""
    ref = OutputPath("s-curve", (0.3, 0.7), 0.04, (0, 1), duration=1.5)
    paper = SCurve(start=(0.3, 0.7 - 0.08), radius=0.04, duration=1.5)
    np.testing.assert_allclose(ref.sample(T), paper.sample(T)[:, :2], atol=1e-15)


def test_line_is_straight_through_home():
    ref = path_for("line", [1.0, 2.0, 3.0], [False] * 3, 1.0, size=0.3)
    p = ref.sample(np.linspace(0.0, 1.0, 51)) - [1.0, 2.0, 3.0]
    np.testing.assert_allclose(p[[0, -1]], [[-0.3 / np.sqrt(3)] * 3, [0.3 / np.sqrt(3)] * 3], atol=1e-15)
    assert np.linalg.matrix_rank(p, tol=1e-12) == 1


def test_paths_refuse_what_the_outputs_cannot_do():
    with pytest.raises(InvalidParameterError, match=r"circle needs 2 translational outputs; this robot's outputs are "
                                                    r"\[z m, yaw rad\]"):
        path_for("circle", [0.5, 0.0], [False, True], 1.0, labels=("z", "yaw"))
    with pytest.raises(InvalidParameterError, match="is not one of"):
        path_for("spiral", [0.5, 0.0], [False, True], 1.0)
    ref = path_for("auto", [0.5, 0.0], [False, True], 1.0)  # one translation: a line, the angle swings
    assert ref.kind == "line" and ref.columns == (0,) and ref.swing == (0.05,)


def test_embedded_robots_keep_their_paths():
    planar = ParallelRobot.load("planar_3rrr")
    assert sized_path("auto", planar, 2.0, 1e3) == SCurve(duration=2.0)
    delta = ParallelRobot.load("delta_3rus")
    assert sized_path("auto", delta, 2.0, 1e3) == path_for("helix", delta.home_pose, delta.output_angular, 2.0)


def test_a_planar_robot_away_from_the_papers_home_gets_paths_about_its_own_home(tmp_path):
    """The paper's S-curve and hold target are drawn about (0.5 m, 0.5 m, 0): a planar [x, y, ψ]
    robot whose home is elsewhere (planar_3rrr with its home moved by (−4 cm, +3 cm)) gets an
    S-curve centred on its own home that passes the workspace check, a hold target 2 cm from
    home and no default plan poses (a 3-PRR written from the docs got the paper's poses, outside
    its workspace)."""
    sidecar = (urdf_dir() / "planar_3rrr.toml").read_text()
    assert "pose = [0.5, 0.5, 0.0]" in sidecar
    sidecar = sidecar.replace("pose = [0.5, 0.5, 0.0]", "pose = [0.46, 0.53, 0.0]")
    robot = ParallelRobot.load(write(tmp_path, "moved", (urdf_dir() / "planar_3rrr.urdf").read_text(), sidecar))
    home = robot.home_pose
    np.testing.assert_allclose(home, [0.46, 0.53, 0.0], atol=1e-9)
    ref = sized_path("auto", robot, 2.0, 1e3)
    p = ref.sample(T)
    np.testing.assert_allclose((p.max(axis=0) + p.min(axis=0)) / 2, home, atol=1e-9)  # centred on home
    assert np.ptp(p[:, 1]) > 0.05 and np.ptp(p[:, 2]) > 0.05  # an S-curve: it moves y and swings ψ
    check_reference(robot, ref, check_times(ref, 2.2, 0.002), 1e3)
    np.testing.assert_allclose(reference_for("hold", robot, 1.0).pose(0.0), home + [0.02, 0.02, 0.0], atol=1e-12)
    from parallel_gpc.cli.plan import default_poses

    assert default_poses(robot) == (None, None)  # `plan` asks for --A/--B instead of the paper's (0.2, 0.2, -20°)
    paper = ParallelRobot.load("planar_3rrr")
    np.testing.assert_allclose(np.array(default_poses(paper))[:, :2], [[0.2, 0.2], [0.8, 0.8]])


def test_workspace_probe_and_scaling_on_the_five_bar(fivebar):
    """Up from home the legs (0.25 + 0.30 m on pivots at x = ±0.1 m) stretch at z = √(0.55² − 0.1²):
    the probe must stop before; the S-curve is scaled to half the reach found, and passes the check."""
    stretched = np.sqrt(0.55**2 - 0.1**2) - 0.4
    up = ray_reach(fivebar, [0, 1], [0.0, 1.0], 0.3, 1e3, steps=30)
    assert 0.05 < up <= stretched
    ref = sized_path("s-curve", fivebar, 2.0, 1e3)
    assert ref.size < 0.05  # smaller than the default
    assert np.max(ref.sample(T)[:, 1]) - 0.4 <= WORKSPACE_FRACTION * stretched + 1e-12
    check_reference(fivebar, ref, check_times(ref, 2.2, 0.002), 1e3)


def test_check_names_the_first_bad_pose(fivebar):
    far = SampledTrajectory([0.0, 1.0], [[0.0, 0.4], [0.0, 0.9]])
    with pytest.raises(UnreachablePoseError, match=r"reference pose \[0.0, 0.5\d*\] \(x, z\) at t = 0.\d+ s is outside"):
        check_reference(fivebar, far, np.linspace(0.0, 1.0, 11), 1e3)
    with pytest.raises(SingularPoseError, match="cond"):  # a tiny limit: every pose is 'near-singular'
        check_reference(fivebar, Hold((0.0, 0.4)), [0.0], 1.0)


def test_csv_round_trip_equals_the_trajectory(fivebar, tmp_path):
    t = np.linspace(0.0, 0.5, 9)
    traj = SampledTrajectory(t, np.column_stack([0.02 * np.sin(6 * t), 0.4 + 0.01 * t]))
    traj.to_csv(tmp_path / "a.csv", ["x", "z"])
    back = reference_for(str(tmp_path / "a.csv"), fivebar, 1.0)
    times = np.linspace(-0.1, 0.7, 97)
    np.testing.assert_array_equal(back.sample(times), traj.sample(times))
    (tmp_path / "b.csv").write_text("z, t ,x\n0.4,0,0.01\n0.41,0.5,0.02\n")  # any column order, spaces
    np.testing.assert_allclose(reference_for(str(tmp_path / "b.csv"), fivebar, 1.0).sample([0.25]), [[0.015, 0.405]])


@pytest.mark.parametrize("text, match", [
    ("t,x\n0,0\n1,0\n", r"missing \['z'\]"),
    ("t,x,z,z\n0,0,0.4,0.4\n1,0,0.4,0.4\n", r"duplicated \['z'\]"),
    ("t,x,z,psi\n0,0,0.4,0\n1,0,0.4,0\n", r"unknown \['psi'\]"),
    ("t,x,z\n0,0,0.4\n", "at least 2"),
    ("t,x,z\n0,0,0.4\n0,0,0.41\n", "strictly increasing"),
    ("t,x,z\n0,0,0.4\n1,nan,0.41\n", "line 3, column 'x' is nan"),
    ("t,x,z\n0,0,0.4\n1,a,0.41\n", "line 3, column 'x': 'a' is not a number"),
    ("t,x,z\n0,0,0.4\n1,0\n", "line 3 has 2 values"),
    ("", "is empty"),
])
def test_bad_csv_is_one_clear_error(fivebar, tmp_path, text, match):
    (tmp_path / "r.csv").write_text(text)
    with pytest.raises(InvalidParameterError, match=match):
        reference_for(str(tmp_path / "r.csv"), fivebar, 1.0)


def test_output_space_labels_and_units(fivebar):
    space = fivebar.output_space
    assert (space.labels, space.units, space.drive_unit) == (("x", "z"), ("m", "m"), "N·m")
    assert space.translational == [0, 1] and not space.has_angles
    hexapod = ParallelRobot.load("hexapod_6ups").output_space
    assert hexapod.drive_unit == "N" and hexapod.effort_unit == "N²·s" and hexapod.rotational == [3, 4, 5]
    planar = OutputSpace.from_angular(None, 3)
    assert planar.labels == ("x", "y", "ψ") and planar.units == ("m", "m", "rad")
    with pytest.raises(InvalidParameterError, match="distinct"):
        OutputSpace(("x", "x"), (False, False))


def test_poses_in_messages_show_no_negative_zero(tmp_path):
    """`info` of a five-bar whose home x is −1e-12 m (the loader's refined home of a robot written
    from the docs) printed "home pose [m, m] [-0.0, 0.38064]"."""
    from parallel_gpc.cli.info import robot_info
    from parallel_gpc.validation import rounded

    assert [str(v) for v in rounded([-1e-12, 0.1234567, -0.25], 6)] == ["0.0", "0.123457", "-0.25"]
    sidecar = FIVEBAR.with_suffix(".toml").read_text()
    assert "pose = [0.0, 0.4]" in sidecar
    urdf = write(tmp_path, "fb", FIVEBAR.read_text(), sidecar.replace("pose = [0.0, 0.4]", "pose = [-1e-12, 0.4]"))
    rows = dict(robot_info(ParallelRobot.load(urdf)))
    assert rows["home pose [m, m]"] == "[0.0, 0.4]"
