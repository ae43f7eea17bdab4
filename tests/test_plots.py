"""Plot modules: importing them leaves the caller's matplotlib backend alone, and every plot
function returns a ``matplotlib.figure.Figure`` that ``save_figure`` writes."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from matplotlib.figure import Figure

from parallel_gpc.plots import save_figure
from parallel_gpc.plots import plot_results

ROOT = Path(__file__).resolve().parents[1]
PLOT_MODULES = ["common", "tracking", "planning", "robustness", "bench", "sweep"]


@pytest.mark.parametrize("module", PLOT_MODULES)
def test_importing_a_plot_module_keeps_the_backend(module):
    """In a fresh interpreter the user picks the SVG backend, then imports the module."""
    probe = ("import matplotlib\nmatplotlib.use('svg')\n"
             f"import parallel_gpc.plots.{module}\n"
             "print(matplotlib.get_backend())\n")
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    env["PYTHONPATH"] = str(ROOT / "src")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "svg"


def test_bench_plot_returns_a_figure(tmp_path):
    rows = [{"section": s, "method": m, "robot": "planar_4rrr", "N": n, "median_us": 10.0 * n}
            for s in ("unconstrained", "limited", "step", "loop", "qpmpc") for m in ("qr", "daqp") for n in (5, 10)]
    fig = plot_results(rows)
    assert isinstance(fig, Figure) and len(fig.axes) == 6
    assert [len(ax.lines) for ax in fig.axes[:5]] == [2] * 5
    assert save_figure(fig, tmp_path / "a" / "b.png").stat().st_size > 10_000


def test_bench_plot_keeps_twenty_methods_and_five_robots_apart():
    """The step panels carry ~20 methods and the run five robots: every method of a panel gets its
    own colour and every robot its own (line style, marker) pair (tab10 repeated after ten methods
    and the line styles after four robots, so "absolute" and a Python reference looked alike)."""
    methods = [f"method {i}" for i in range(20)]
    robots = ["planar_4rrr", "planar_3rrr", "delta_3rus", "hexapod_6ups", "hexapod_8ups"]
    rows = [{"section": "step", "method": m, "robot": r, "N": n, "median_us": 10.0 * n}
            for m in methods for r in robots for n in (10, 20)]
    ax = plot_results(rows).axes[2]
    first_robot = [line for line in ax.lines if line.get_label() in methods]
    assert len({tuple(line.get_color()) for line in first_robot}) == 20
    of_one_method = [line for line in ax.lines if tuple(line.get_color()) == tuple(first_robot[0].get_color())]
    assert len({(line.get_linestyle(), line.get_marker()) for line in of_one_method}) == 5


def test_the_title_of_a_one_column_figure_clears_its_panels():
    """track_time.png of a single run of a 6-output robot (9 panels, as the hexapod's): the
    figure's title stays clear of the column's title and of the panels' offset texts (errors of
    1e-7 mm); it overlapped the column's title under the tight layout."""
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.text import Text

    from parallel_gpc.plots import plot_time_histories
    from parallel_gpc.studies import SimulationResult

    K = 60
    t = np.linspace(0.0, 0.3, K)
    tiny = 1e-9 * np.outer(t ** 2, [1.0, -2.0, 3.0, 1.0, 2.0, -3.0])  # offset texts (1e-7 …) above the panels
    res = SimulationResult(t=t, reference=np.zeros((K, 6)), pose=tiny, velocity=tiny, u=np.zeros((K, 6)),
                           internal_force=np.zeros(K), q=np.zeros((K, 3)), step_time=np.zeros(K),
                           solve_time=np.zeros(K), iterations=np.zeros(K, int), status=np.array(["ok"] * K),
                           fallback=np.zeros(K, bool), saturated=np.zeros(K, bool))
    title = "Tracking (auto reference): error, velocity, drive effort"
    fig = plot_time_histories({"absolute": res}, title=title)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    (suptitle,) = [x for x in fig.findobj(Text) if x.get_text() == title]
    top = suptitle.get_window_extent(renderer)
    below = [fig.axes[0].title] + [ax.yaxis.get_offset_text() for ax in fig.axes]
    texts = [x for x in below if x.get_text()]
    assert texts and len(texts) > 1
    for text in texts:
        box = text.get_window_extent(renderer)
        assert not box.overlaps(top), (text.get_text(), box, top)


@pytest.mark.parametrize("peak, lines", [(0.4, False), (20.0, True)])
def test_a_far_drive_limit_does_not_squash_the_efforts(peak, lines):
    """plan_fig4.png of a 3-PRR with a 50 N limit and efforts of 0.4 N: the ±50 N lines set the
    y range and drew the efforts as a flat line at zero. Far below the limit it is named in the
    legend (off scale) and the axis fits the efforts; near it the dotted lines are drawn."""
    import numpy as np

    from parallel_gpc.gpc import PlanResult
    from parallel_gpc.gpc.plan_settings import PlanSettings
    from parallel_gpc.limits import Limits
    from parallel_gpc.plots import plot_fig4

    K = 40
    t = np.linspace(0.0, 0.4, K + 1)
    settings = PlanSettings(Nmax=30, Nmin=10, limits=Limits(torque=50.0))
    target = np.array([0.02, 0.01, 0.05])
    poses = np.outer(t / t[-1], target)
    res = PlanResult(mode="b", start=np.zeros(3), target=target, t=t, poses=poses, velocities=np.gradient(poses, axis=0),
                     u=peak * np.sin(np.outer(t[:-1], [10.0, 20.0, 30.0])), horizon=np.full(K, 10),
                     status=np.array(["ok"] * K), solve_time=np.zeros(K), q=None, settings=settings)
    ax = plot_fig4([res]).axes[-1]
    labels = ax.get_legend_handles_labels()[1]
    low, high = ax.get_ylim()
    if lines:
        assert "drive limit" in labels and low <= -50.0 and high >= 50.0
    else:
        assert any("drive limit ±50" in s and "off scale" in s for s in labels)
        assert -2 * peak < low < -0.5 * peak and 0.5 * peak < high < 2 * peak


def test_robustness_error_axes_start_at_zero():
    """robustness.png of a 3-PRR: the steady-state errors 2.23e-14 and 2.35e-14 mm (rounding) were
    drawn as a full-height rising line (axis 2.22e-14 … 2.35e-14); an error axis starts at 0 and
    ends a little above the largest error."""
    from parallel_gpc.plots import plot_robustness
    from parallel_gpc.sweeps import RobustnessResult

    def row(study, value, err):
        return {"form": "nonlinear", "study": study, "value": value, "status": "ok",
                "rms_position_error_mm": err, "steady_state_error_mm": err}

    rows = [row("nominal", 0.0, 2.23e-14), row("mass", 30.0, 1.8e-3), row("noise", 1e-4, 0.34),
            row("disturbance", 20.0, 2.35e-14)]
    fig = plot_robustness(RobustnessResult(rows=rows, settings={"robot": "prr3", "outputs": ["x", "y", "rz"],
                                                                "angular": [False, False, True]}))
    tops = {"mass": 1.8e-3, "noise": 0.34, "disturbance": 2.35e-14}
    for ax in fig.axes:
        low, high = ax.get_ylim()
        assert low == 0.0 and 1.02 * tops[ax.get_title()] < high < 1.2 * tops[ax.get_title()]  # the points inside


def test_a_hold_reference_is_drawn_as_a_point():
    """track_path.png of `track --reference hold`: the reference, one pose, was a dashed line of
    zero length (in the legend, invisible in the plot); it is a cross at the held pose."""
    import numpy as np

    from parallel_gpc.model.output_space import OutputSpace
    from parallel_gpc.plots import plot_paths
    from parallel_gpc.studies import SimulationResult

    K = 30
    t = np.linspace(0.0, 0.3, K)
    target = np.array([0.02, 0.40])
    pose = target + np.outer(np.exp(-20 * t), [-0.02, -0.02])
    res = SimulationResult(t=t, reference=np.tile(target, (K, 1)), pose=pose, velocity=np.gradient(pose, axis=0),
                           u=np.zeros((K, 2)), internal_force=np.zeros(K), q=np.zeros((K, 4)), step_time=np.zeros(K),
                           solve_time=np.zeros(K), iterations=np.zeros(K, int), status=np.array(["ok"] * K),
                           fallback=np.zeros(K, bool), saturated=np.zeros(K, bool),
                           outputs=OutputSpace(("x", "z"), (False, False)))
    ax = plot_paths({"nonlinear": res}).axes[0]
    ref = [line for line in ax.lines if line.get_label().startswith("reference")]
    assert len(ref) == 1 and ref[0].get_marker() == "x"
    np.testing.assert_allclose(np.column_stack(ref[0].get_data()), [target])


def test_orientation_markers_scale_with_a_small_path():
    """track_path.png of a 3-PRR over 0.6 s (a path 8 mm across): the orientation markers were
    2.5 mm long (5 % of a 5 cm floor), a third of the plot; they are 5 % of the drawn extent."""
    import numpy as np

    from parallel_gpc.model.output_space import OutputSpace
    from parallel_gpc.plots import plot_paths
    from parallel_gpc.studies import SimulationResult

    K = 60
    t = np.linspace(0.0, 0.6, K)
    pose = np.column_stack([0.008 * t / 0.6, -0.0187 + 0.0045 * (t / 0.6) ** 2, 0.05 * np.sin(5 * t)])
    res = SimulationResult(t=t, reference=pose, pose=pose, velocity=np.gradient(pose, axis=0), u=np.zeros((K, 3)),
                           internal_force=np.zeros(K), q=np.zeros((K, 7)), step_time=np.zeros(K),
                           solve_time=np.zeros(K), iterations=np.zeros(K, int), status=np.array(["ok"] * K),
                           fallback=np.zeros(K, bool), saturated=np.zeros(K, bool),
                           outputs=OutputSpace(("x", "y", "rz"), (False, False, True)))
    ax = plot_paths({"nonlinear": res}).axes[0]
    markers = [line for line in ax.lines if line.get_label().startswith("_") and len(line.get_xdata()) == 2]
    assert len(markers) >= 10
    lengths = [np.hypot(*np.diff(np.column_stack(m.get_data()), axis=0)[0]) for m in markers]
    np.testing.assert_allclose(lengths, 0.05 * 0.008, rtol=1e-9)


def test_heatmap_text_is_readable_on_its_cell():
    """The 3-PRR sweep heatmap: 0.688 mm was written in black on a dark cell (the colour was
    chosen against the median, 0.629, while one 23.6 mm cell stretched the colour scale); the text
    is black on light cells and white on dark ones, by the cell colour's luminance."""
    import pandas as pd

    from parallel_gpc.plots import heatmap

    frame = pd.DataFrame({"form": ["absolute", "nonlinear"] * 2, "Qu": [1e-4, 1e-4, 1e-3, 1e-3],
                          "status": ["ok"] * 4, "rms_position_error_m": [0.688e-3, 0.0622e-3, 23.6e-3, 0.57e-3]})
    ax = heatmap(frame, "form", "Qu").axes[0]
    # viridis: the three small values are dark purple cells, 23.6 the yellow top of the scale
    assert {t.get_text(): t.get_color() for t in ax.texts} == {"0.688": "w", "0.0622": "w", "0.57": "w", "23.6": "k"}


def test_a_long_path_title_stays_inside_the_figure():
    """demo_path.png: the title "platform path, estimator on (Qu = 0.001, mass × 1.2, load
    [5.0, -5.0, 0.5])" was cut at both edges of the 5.5 in figure; it wraps."""
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from parallel_gpc.model.output_space import OutputSpace
    from parallel_gpc.plots import plot_paths
    from parallel_gpc.studies import SimulationResult

    K = 20
    t = np.linspace(0.0, 0.2, K)
    pose = np.column_stack([0.5 + 0.1 * t, 0.5 + 0.2 * t, 0.01 * t])
    res = SimulationResult(t=t, reference=pose, pose=pose, velocity=np.gradient(pose, axis=0), u=np.zeros((K, 3)),
                           internal_force=np.zeros(K), q=np.zeros((K, 3)), step_time=np.zeros(K),
                           solve_time=np.zeros(K), iterations=np.zeros(K, int), status=np.array(["ok"] * K),
                           fallback=np.zeros(K, bool), saturated=np.zeros(K, bool),
                           outputs=OutputSpace(("x", "y", "ψ"), (False, False, True)))
    fig = plot_paths({"nonlinear": res}, "platform path, estimator on (Qu = 0.001, mass × 1.2, load [5.0, -5.0, 0.5])")
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    box = fig.axes[0].title.get_window_extent(canvas.get_renderer())
    assert box.x0 >= 0.0 and box.x1 <= fig.bbox.width
    assert "load [5.0, -5.0, 0.5])" in fig.axes[0].get_title().replace("\n", " ")


def _record(space, K: int = 20):
    """A closed-loop record of ``space``'s robot with distinct efforts per drive."""
    import numpy as np

    from parallel_gpc.studies import SimulationResult

    n_y, n_u = space.n_y, len(space.drives) or 3
    t = np.linspace(0.0, 0.2, K)
    pose = np.outer(t, np.ones(n_y)) * 0.01
    return SimulationResult(t=t, reference=pose, pose=pose, velocity=np.gradient(pose, axis=0),
                            u=np.outer(np.sin(10 * t), np.arange(1.0, n_u + 1)), internal_force=np.zeros(K),
                            q=np.zeros((K, 3)), step_time=np.zeros(K), solve_time=np.zeros(K),
                            iterations=np.zeros(K, int), status=np.array(["ok"] * K), fallback=np.zeros(K, bool),
                            saturated=np.zeros(K, bool), outputs=space)


def test_effort_plots_name_the_drives_with_their_units(prr3, robot4):
    """Field test: the effort panels of a 3-PRR labelled its drives u1, u2, u3; they carry the
    drive joints' names and each drive's unit (N prismatic, N·m revolute)."""
    import numpy as np

    from parallel_gpc.gpc import PlanResult
    from parallel_gpc.gpc.plan_settings import PlanSettings
    from parallel_gpc.limits import Limits
    from parallel_gpc.plots import plot_comparison, plot_fig4, plot_time_histories

    for robot in (prr3, robot4):
        space = robot.output_space
        unit = "N" if robot is prr3 else "N·m"
        expected = [f"{name} [{unit}]" for name in robot.description.drive_joints]
        res = _record(space)
        ax = plot_time_histories({"absolute": res}).axes[-1]
        assert ax.get_legend_handles_labels()[1] == expected
        ax = plot_comparison({("absolute", 0.0): res}, Limits(torque=50.0)).axes[-1]
        assert ax.get_legend_handles_labels()[1][:robot.n_u] == expected
        K = 10
        t = np.linspace(0.0, 0.1, K + 1)
        plan = PlanResult(mode="a", start=np.zeros(robot.n_y), target=np.zeros(robot.n_y), t=t,
                          poses=np.zeros((K + 1, robot.n_y)), velocities=np.zeros((K + 1, robot.n_y)),
                          u=np.ones((K, robot.n_u)), horizon=np.full(K, 10), status=np.array(["ok"] * K),
                          solve_time=np.zeros(K), q=None, settings=PlanSettings(Nmax=30, Nmin=10), outputs=space)
        ax = plot_fig4([plan]).axes[-1]
        assert ax.get_legend_handles_labels()[1] == expected


def test_a_robot_with_both_drive_kinds_labels_each_drive_in_its_unit():
    from parallel_gpc.errors import InvalidParameterError
    from parallel_gpc.model.output_space import OutputSpace

    space = OutputSpace(("x", "y"), (False, False), "N·m | N", ("hip", "slide"), (True, False))
    assert [space.drive_label(j) for j in range(2)] == ["hip [N·m]", "slide [N]"]
    assert OutputSpace(("x",), (False,)).drive_label(1) == "u2 [N·m]"  # a result without drive names
    with pytest.raises(InvalidParameterError, match="does not match the drive kinds"):
        OutputSpace(("x", "y"), (False, False), "N", ("hip", "slide"), (True, False))
    with pytest.raises(InvalidParameterError, match="give drive_angular"):
        OutputSpace(("x", "y"), (False, False), "N·m | N", ("hip", "slide"))


def test_fig3_draws_every_platform_edge_and_the_prismatic_rails(prr3):
    """Field test: plan_fig3 of a 3-PRR drew two of the platform's three edges (the leg carrying
    the platform was drawn to two closure frames) and no slide rails. Every closure edge of the
    platform and each prismatic drive's rail between its stroke limits are drawn, where the
    docs' geometry puts them (mechanisms.prr3_urdf: anchors, sliders and slide axes)."""
    import math

    import mechanisms as mech
    import numpy as np

    from parallel_gpc import PlanSettings, plan_point_to_point
    from parallel_gpc.model import stick_figure
    from parallel_gpc.plots import plot_fig3

    legs = [mech.prr_leg(i) for i in range(3)]
    A = np.array(prr3.description.pose_a)
    c, s = math.cos(A[2]), math.sin(A[2])
    anchors_at_A = [np.array([[c, -s], [s, c]]) @ anchor + A[:2] for anchor, _, _ in legs]
    rails = [(slider - mech.PRR_STROKE * axis, slider + mech.PRR_STROKE * axis) for _, slider, axis in legs]

    def same_points(got, expected):
        got, expected = np.asarray(got), np.asarray(expected)
        assert len(got) == len(expected)
        for point in expected:  # in any order
            assert np.min(np.linalg.norm(got - point, axis=1)) < 1e-9, (point, got)

    figure = stick_figure(prr3)
    same_points(figure.platform[:, :2], [anchor for anchor, _, _ in legs])
    assert len(figure.legs) == 3 and figure.rail_stroke == (True, True, True)
    same_points([leg[-1, :2] for leg in figure.legs], [anchor for anchor, _, _ in legs])  # each leg reaches the platform
    same_points(figure.rails[:, :, :2].reshape(-1, 2), np.reshape(rails, (-1, 2)))

    plan = plan_point_to_point(prr3, A, np.array(prr3.description.pose_b),
                               PlanSettings(Nmax=20, Nmin=8, Ts=0.01, settle_steps=2), mode="b")
    ax = plot_fig3([plan], prr3).axes[0]
    outline = next(line for line in ax.lines if line.get_label() == "platform")
    xy = np.column_stack(outline.get_data())
    assert len(xy) == 4 and np.allclose(xy[0], xy[-1])  # closed: three edges
    same_points(xy[:3], anchors_at_A)
    drawn = [np.column_stack(line.get_data()) for line in ax.lines if line.get_linewidth() == 4]
    same_points(np.vstack(drawn), np.reshape(rails, (-1, 2)))
