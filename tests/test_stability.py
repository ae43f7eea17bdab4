"""Closed-loop poles of the unconstrained controller (gpc/stability.py) against the controller's own steps.

Oracle: the closed loop run step by step (GPCController.step on a linear plant equal to its model) from
random states; x̄(k+1) = A_cl x̄(k) is regressed from those steps, and its eigenvalues must be the
analysis' poles. On a robot: the dead-beat law (Qu = 0) cancels the ZOH zero at z = −1 of every form.
"""

import numpy as np
import pytest
import scipy.linalg

from parallel_gpc.errors import InvalidParameterError
from parallel_gpc.gpc import DiscreteLinearModel, GPCController, Horizons, Weights
from parallel_gpc.gpc.stability import STABLE_MARGIN, closed_loop_poles, spectral_radius
from parallel_gpc.model import ReducedModel
from parallel_gpc.results import load_result

LINEAR_FORMS = ("absolute", "incremental", "incremental-delayed")


def double_integrators(m: int, Ts: float = 0.01) -> DiscreteLinearModel:
    """Two ZOH double integrators (outputs p₁, p₂) driven by m inputs: m = 2 with a velocity coupling
    that moves their zeros off −1; m = 3 plain, with one redundant drive (null(B_d) of dimension 1)."""
    n = 4
    Ad = np.eye(n)
    Ad[0, 2] = Ad[1, 3] = Ts
    mix = np.array([[1.0, 0.0, 1.0], [0.0, 1.0, -0.5]])[:, :m]
    Bd = np.vstack([0.5 * Ts**2 * mix, Ts * mix])
    if m == 2:
        Bd[2:] += 0.3 * Ts * np.array([[0.0, 0.2], [0.1, 0.0]])  # not a pure integrator chain
    C = np.hstack([np.eye(2), np.zeros((2, 2))])
    return DiscreteLinearModel(Ad, Bd, C, Ts=Ts)


def identified_poles(ctrl: GPCController, model: DiscreteLinearModel, seed: int = 0) -> np.ndarray:
    """Eigenvalues of A_cl regressed from the controller's steps on the plant x(k+1) = A x(k) + B u(k)."""
    rng = np.random.default_rng(seed)
    n, m = model.n_x, model.n_u
    Ad, Bd, _ = model.discrete(np.zeros(n), ctrl.Ts)
    w = np.zeros((ctrl.horizons.N, model.n_y))
    before, after = [], []
    for _ in range(3 * (n + m)):
        ctrl.reset(rng.normal(size=m))
        X = rng.normal(size=n)
        states = []
        for _ in range(3):
            u = ctrl.step(X, w).u
            # x̄ = [X; u(k−1)] (incremental), [X; u(k)] (delayed: the input applied now), X (absolute)
            states.append((X, u))
            X = Ad @ X + Bd @ u
        for (X0, u0), (X1, u1), (X2, u2) in zip(states, states[1:], states[2:]):
            if ctrl.form == "absolute":
                before.append(X1), after.append(X2)
            elif ctrl.form == "incremental":
                before.append(np.concatenate([X1, u0])), after.append(np.concatenate([X2, u1]))
            else:
                before.append(np.concatenate([X1, u1])), after.append(np.concatenate([X2, u2]))
    A_cl = np.linalg.lstsq(np.array(before), np.array(after), rcond=None)[0].T
    return np.linalg.eigvals(A_cl)


def transmission_zeros(model: DiscreteLinearModel) -> np.ndarray:
    """Finite z where the Rosenbrock pencil [[A − zI, B], [C, 0]] (square plant) loses rank."""
    Ad, Bd, _ = model.discrete(np.zeros(model.n_x), model.Ts)
    n, m, p = model.n_x, model.n_u, model.n_y
    M = np.block([[Ad, Bd], [model.C, np.zeros((p, m))]])
    E = np.zeros_like(M)
    E[:n, :n] = np.eye(n)
    z = scipy.linalg.eigvals(M, E)
    return z[np.isfinite(z)]


def same_spectrum(a: np.ndarray, b: np.ndarray, tol: float) -> bool:
    return a.shape == b.shape and all(np.abs(b - z).min() <= tol for z in a) and all(np.abs(a - z).min() <= tol for z in b)


@pytest.mark.parametrize("form", LINEAR_FORMS)
@pytest.mark.parametrize("qu", [0.0, 3e-3])
def test_the_poles_are_those_of_the_controllers_own_closed_loop(form, qu):
    model = double_integrators(2)
    ctrl = GPCController.build(model, 0.01, Horizons(8), Weights(1.0, qu), form=form, disturbance_gain=0.0)
    poles = closed_loop_poles(ctrl, np.zeros(model.n_x))
    assert same_spectrum(poles, identified_poles(ctrl, model), 1e-6), (poles, identified_poles(ctrl, model))
    if qu == 0.0:  # dead-beat: the law cancels the plant's transmission zeros (here one outside the unit circle)
        zeros = transmission_zeros(model)
        assert zeros.shape == (2,) and np.abs(zeros).max() > 1.0
        assert all(np.abs(poles - z).min() <= 1e-6 for z in zeros)
        assert spectral_radius(poles) == pytest.approx(np.abs(zeros).max(), rel=1e-9)
    else:
        assert spectral_radius(poles) < 1.0 - 1e-3


@pytest.mark.parametrize("form", ["incremental", "incremental-delayed"])
def test_inputs_that_move_nothing_are_no_pole_on_the_unit_circle(form):
    """A redundant drive: the controller adds the increments to u without its null(B_d) part."""
    model = double_integrators(3)
    ctrl = GPCController.build(model, 0.01, Horizons(8), Weights(1.0, 3e-3), form=form, disturbance_gain=0.0)
    poles = closed_loop_poles(ctrl, np.zeros(model.n_x))
    assert poles.shape == (7,)
    assert spectral_radius(poles) < 1.0 - 1e-3  # the null direction of u: a pole at 0, not at 1
    assert np.abs(poles).min() <= 1e-9


def test_the_dead_beat_law_of_a_robot_has_a_pole_at_minus_one(robot4):
    model = ReducedModel(robot4)  # redundant drives: 4 for 3 outputs
    X = np.concatenate([robot4.home_pose, [0.05, -0.03, 0.2]])  # moving: the Coriolis terms enter A_d
    for form in LINEAR_FORMS:
        paper = closed_loop_poles(GPCController.build(model, 0.002, Horizons(20), Weights(1.0, 0.0), form=form), X)
        assert np.abs(paper + 1.0).min() <= 1e-3 and spectral_radius(paper) >= 1.0 - STABLE_MARGIN
        damped = closed_loop_poles(GPCController.build(model, 0.002, Horizons(20), Weights(1.0, 1e-6), form=form), X)
        assert spectral_radius(damped) < 0.9


def test_the_nonlinear_form_is_refused():
    model = double_integrators(2)
    ctrl = GPCController.build(model, 0.01, Horizons(8), Weights(1.0, 1e-3), form="nonlinear")
    with pytest.raises(InvalidParameterError, match="nonlinear"):
        closed_loop_poles(ctrl, np.zeros(model.n_x))


@pytest.mark.parametrize("qu, noted", [("0", True), ("1e-6", False)])
def test_track_notes_the_undamped_pole_of_the_dead_beat_law(tmp_path, capsys, qu, noted):
    from parallel_gpc.cli import main

    assert main(["track", "--robot", "planar_4rrr", "--forms", "absolute", "incremental-delayed", "--N", "10",
                 "--Qu", qu, "--reference", "hold", "--duration", "0.02", "--no-progress", "--out", str(tmp_path)]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("note (")]
    assert len(lines) == int(noted)
    if noted:
        assert lines[0].startswith("note (absolute, incremental-delayed): ") and "z = -1.0000" in lines[0]
    pole = load_result(tmp_path / "track_incremental-delayed.npz").meta["closed_loop_pole"]
    assert (abs(complex(*pole) + 1.0) <= 1e-6) == noted and (abs(complex(*pole)) < 0.9) != noted


def test_the_tracking_study_analyzes_the_poles_only_when_asked(robot4):
    """Sweep cells and comparisons run the study without ``poles``: no analysis, no meta field."""
    from parallel_gpc.studies import TrackingSettings, run_tracking

    settings = TrackingSettings.from_flat(robot="planar_4rrr", reference="hold", duration=0.01, N=5, Qu=0.0)
    plain = run_tracking(settings, ("incremental",), progress=False, robot=robot4)["incremental"]
    asked = run_tracking(settings, ("incremental",), progress=False, robot=robot4, poles=True)["incremental"]
    assert "closed_loop_pole" not in plain.meta
    assert abs(complex(*asked.meta["closed_loop_pole"]) + 1.0) <= 1e-6  # Qu = 0: the dead-beat law's z = −1


def test_the_note_reads_a_slow_unstable_pole_as_the_horizons_not_as_qu_zero():
    """A pole outside the circle on the positive real side (a short horizon for a heavy robot: the Gepetto 5-bar's
    +1.0057 ± 0.0746j at N = 20, Qu = 1e-3) is not the dead-beat law's z = −1: the note says so and does not
    advise a larger Qu; the z = −1 pole keeps its reading."""
    from parallel_gpc.cli.track import undamped_note

    slow = undamped_note({"incremental": [1.00568, 0.07459]}, 0.002, 20)
    assert "horizon N·Ts = 40 ms" in slow and "a small Qu > 0 damps it" not in slow and "5.891 Hz" in slow
    deadbeat = undamped_note({"absolute": [-1.0000001, 0.0]}, 0.002, 20)
    assert "a small Qu > 0 damps it" in deadbeat and "horizon" not in deadbeat
    assert undamped_note({"absolute": [0.5, 0.1], "nonlinear": None}, 0.002, 20) == ""
