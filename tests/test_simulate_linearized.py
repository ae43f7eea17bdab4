"""The rollout and its stage Jacobians in one call (ReducedModel.simulate_linearized; compiled:
_native.simulate_linearized in native/src/stage_jacobian.cpp, the Jacobians of the finished stages on a
pool thread while the calling thread rolls out): the numbers of simulate_factorized then stage_jacobians
(the reference, also the Python path's), on one and two threads; a rollout that leaves the workspace
raises the error of simulate_factorized and leaves the model update and its threads usable; and the
NMPC iterations, which use it, give the inputs of the two calls."""

from __future__ import annotations

import numpy as np
import pytest

import mechanisms as mech

from parallel_gpc import ControllerState, GPCController, Horizons, ParallelRobot, ReducedModel, Weights
from parallel_gpc.errors import InvalidParameterError, UnreachablePoseError
from parallel_gpc.limits import Limits
from parallel_gpc.model import native_update
from parallel_gpc.model.native import native_module

TS = 0.002
N_STEPS = 4


@pytest.fixture
def threads(monkeypatch):
    """set(n): the compiled model updates built next run their stage loops on n threads."""
    def set_threads(n):
        monkeypatch.setenv(native_update.THREADS_ENV, str(n))
        native_update.compiled_threads.cache_clear()
    yield set_threads
    native_update.compiled_threads.cache_clear()


@pytest.fixture
def on_threads():
    """The helpers used even on a loaded machine (else ThreadPool::free_cores may leave them out)."""
    module = native_module()
    if module is not None and hasattr(module, "adapt_threads"):
        module.adapt_threads(False)
        yield
        module.adapt_threads(True)
    else:
        yield


def _move(robot, K):
    """(X0, u (K, n_u), offset) of a fast move with inputs that vary along the horizon (mechanisms.fast_move)."""
    X0, u = mech.fast_move(robot, K)
    return X0, u, 1e-5 * np.cos(np.arange(2 * robot.n_y))


def _two_calls(model, X0, u, offset, start):
    A, B, c, X = model.simulate_factorized(X0, u, TS, offset)
    return A, B, c, X, model.stage_jacobians(X, u, TS, start=start)


def _close(a, b, rtol=1e-12):
    scale = max(np.abs(b).max(initial=0.0), 1.0)
    return a.shape == b.shape and np.abs(a - b).max(initial=0.0) <= rtol * scale


@pytest.mark.parametrize("name", ["planar_4rrr", "delta_3rus"])
@pytest.mark.parametrize("n", [1, 2])
@pytest.mark.parametrize("K, start", [(20, 1), (6, 0), (2, 1), (1, 1)])
def test_the_fused_call_equals_the_rollout_then_the_jacobians(name, n, K, start, threads, on_threads):
    """Twice in a row (the second rollout warm-started by the first, as the line search's), with an
    offset: the trajectory, its factorization and the Jacobians of both paths agree to rounding."""
    robot = ParallelRobot.load(name)
    X0, u, offset = _move(robot, K)
    ReducedModel(robot).simulate_factorized(X0, u, TS)  # the robot's first assembly (its own warm start)
    threads(n)
    fused, separate = ReducedModel(robot), ReducedModel(robot)
    for shift in (0.0, 1e-3):
        got = fused.simulate_linearized(X0, u + shift, TS, offset, start=start)
        ref = _two_calls(separate, X0, u + shift, offset, start)
        assert len(got) == 5 and got[4].shape == (K - start, 2 * robot.n_y, 2 * robot.n_y)
        for a, b in zip(got, ref):
            assert _close(a, b), name
    # the model updates are left alike: the next step off the trajectory gives the same numbers
    X_off = got[3][K - 1] + 1e-4 * np.r_[np.ones(robot.n_y), np.zeros(robot.n_y)]
    for a, b in zip(fused.discrete(X_off, TS), separate.discrete(X_off, TS)):
        assert _close(a, b)


def test_the_compiled_fused_call_equals_the_python_reference(threads, on_threads):
    robot = ParallelRobot.load("delta_3rus")
    X0, u, offset = _move(robot, 9)
    threads(2)
    got = ReducedModel(robot).simulate_linearized(X0, u, TS, offset, start=1)
    ref = ReducedModel(robot, native=False).simulate_linearized(X0, u, TS, offset, start=1)
    for a, b in zip(got, ref):
        assert _close(a, b, 1e-8)


@pytest.mark.parametrize("n", [1, 2])
def test_a_rollout_that_leaves_the_workspace_fails_as_simulate_and_the_next_call_works(n, threads, on_threads):
    """Inputs far beyond the robot's: the rollout fails midway (the Jacobians of its first stages may have
    been computed meanwhile on the pool thread); the error is simulate_factorized's class, and the same model
    then rolls out and linearizes a feasible plan as a fresh one does."""
    robot = ParallelRobot.load("planar_4rrr")
    X0, u, offset = _move(robot, 20)
    wild = u.copy()
    wild[8:] *= 2e4  # from stage 8 on: the platform leaves the workspace some stages later
    with pytest.raises(UnreachablePoseError) as expected:
        ReducedModel(robot).simulate_factorized(X0, wild, TS)
    threads(n)
    model = ReducedModel(robot)
    for _ in range(2):
        with pytest.raises(type(expected.value)):
            model.simulate_linearized(X0, wild, TS, None, start=1)
        got = model.simulate_linearized(X0, u, TS, offset, start=1)
        ref = _two_calls(ReducedModel(robot), X0, u, offset, 1)
        for a, b in zip(got, ref):
            assert _close(a, b, 1e-9)


def test_bad_start_is_one_clear_error():
    robot = ParallelRobot.load("planar_4rrr")
    X0, u, offset = _move(robot, 3)
    with pytest.raises(InvalidParameterError, match="start = 4 is not a stage"):
        ReducedModel(robot).simulate_linearized(X0, u, TS, None, start=4)


class _TwoCalls:
    """A user's model without simulate_linearized (the protocol's optional member): the iterations call
    simulate_factorized then stage_jacobians."""

    def __init__(self, model):
        self._model = model

    def __getattr__(self, name):
        if name == "simulate_linearized":
            raise AttributeError(name)
        return getattr(self._model, name)


class _Counted(_TwoCalls):
    """The model with simulate_linearized, counting its calls."""

    def __init__(self, model):
        super().__init__(model)
        self.fused = 0

    def simulate_linearized(self, *args, **kw):
        self.fused += 1
        return self._model.simulate_linearized(*args, **kw)


@pytest.mark.parametrize("limits", [Limits(), Limits(torque=15.0)])
def test_nmpc_iterations_apply_the_inputs_of_the_two_calls(limits, threads, on_threads):
    """Closed loops in lockstep on planar_4rrr (converged NMPC, N = 10, from a fast state): the controller
    whose model rolls out and linearizes in one call applies the inputs of the one that makes the two calls
    (to rounding), and the fused call is what its iterations use."""
    robot = ParallelRobot.load("planar_4rrr")
    threads(2)
    X = np.array([0.5, 0.4, 0.1, 0.8, -0.5, 1.0])
    N, target = 10, np.array([0.51, 0.39, 0.12])
    plan = np.tile([1.0, -1.0, 0.5, 0.2], (N, 1))
    models = [_Counted(ReducedModel(robot)), _TwoCalls(ReducedModel(robot))]
    ctrls = []
    for model in models:
        ctrl = GPCController.build(model, TS, Horizons(N), Weights(1.0, 1e-3), form="nonlinear", iterations=20,
                                   tolerance=1e-10, limits=limits, disturbance_gain=0.0)
        ctrl.restore(ControllerState(plan[0], plan[:N], np.zeros(2 * robot.n_y)))
        ctrls.append(ctrl)
    plant = ReducedModel(robot, native=False)
    for _ in range(N_STEPS):
        fused, two = (ctrl.step(X, np.tile(target, (N, 1))) for ctrl in ctrls)
        assert fused.iterations == two.iterations > 1
        assert np.abs(fused.u - two.u).max() <= 1e-9 * max(1.0, np.abs(two.u).max())
        A, B, c = plant.discrete(X, TS)
        X = A @ X + B @ two.u + c
    assert models[0].fused > 0
