"""The compiled limited step's warm start against its Python twin.

The compiled step (``_native.RiccatiActive``) keeps the controller's last active set (``keep``) and
starts a warm step from it: the set shifted by one stage, for the forms whose limited arcs' edges move
from step to step (:data:`~parallel_gpc.gpc.stagewise.EDGE_FORMS`) with those edges moved again while
that brought the last step nearer its set, then the plain shift when a moved start does not settle.
The Python path (:meth:`StagewiseSolver._next_start`, ``_plain_after``, ``_keep_set`` and
:func:`~parallel_gpc.solvers.shift_active_set`) is the reference: the same starts, hence the same sets
and sweeps on every step.
"""

from __future__ import annotations

import numpy as np
import pytest

from parallel_gpc import GPCController, Horizons, ParallelRobot, ReducedModel, Weights
from parallel_gpc.gpc.references import SCurve, path_for
from parallel_gpc.gpc.riccati import RiccatiPath
from parallel_gpc.limits import Limits
from parallel_gpc.model.native import native_module
from parallel_gpc.solvers import shift_active_set
from closed_loop_states import closed_loop_states

TS = 0.002
HAS_STEP = native_module() is not None and hasattr(native_module(), "RiccatiActive") and hasattr(
    native_module(), "shift_active_set")


def _arcs(rng, nd: int, m: int) -> np.ndarray:
    """A random set (nd, m): per component, runs of 1–8 stages, each free (−1) or held by row 2j or 2j + 1."""
    fixed = np.empty((nd, m), np.int64)
    for j in range(m):
        i = 0
        while i < nd:
            run = int(rng.integers(1, 9))
            fixed[i:i + run, j] = rng.choice([-1, 2 * j, 2 * j + 1])
            i += run
    return fixed


def _moved_edges(rng, fixed: np.ndarray) -> np.ndarray:
    """The set of a step before ``fixed`` (unshifted): ``fixed`` one stage later, its runs' edges moved
    by −3..3 stages (the entries beyond taking the run's neighbour's value) and now and then one entry flipped."""
    before = np.concatenate([fixed[:1], fixed[:-1]])  # fixed was before shifted by one stage
    nd, m = before.shape
    for j in range(m):
        edges = np.flatnonzero(before[1:, j] != before[:-1, j]) + 1
        for e in edges:
            d = int(rng.integers(-3, 4))
            lo, hi = sorted((e, min(max(e + d, 0), nd)))
            before[lo:hi, j] = before[e - 1, j] if d > 0 else before[min(e, nd - 1), j]
        if rng.random() < 0.3:
            before[rng.integers(nd), j] = rng.choice([-1, 2 * j, 2 * j + 1])
    return before


@pytest.mark.skipif(not HAS_STEP, reason="the compiled core has no RiccatiActive.keep")
def test_the_compiled_shift_moves_the_edges_as_its_python_twin():
    """``_native.shift_active_set`` (the compiled step's warm start) against
    :func:`~parallel_gpc.solvers.shift_active_set` on random sets of arcs whose edges moved from the step
    before by −3..3 stages (holes and flips among them): the same set every time, with and without the
    set before, and the moved edges' set differs from the plain shift on most of them (the rule acts)."""
    native = native_module()
    rng = np.random.default_rng(7)
    differ = 0
    for case in range(400):
        nd, m = int(rng.integers(2, 40)), int(rng.integers(1, 4))
        fixed = _arcs(rng, nd, m)
        before = _moved_edges(rng, fixed)
        plain = shift_active_set(fixed)
        np.testing.assert_array_equal(native.shift_active_set(fixed), plain)
        moved = shift_active_set(fixed, before)
        np.testing.assert_array_equal(native.shift_active_set(fixed, before), moved, err_msg=f"case {case}")
        differ += not np.array_equal(moved, plain)
    assert differ >= 200


@pytest.mark.skipif(not HAS_STEP, reason="the compiled core has no RiccatiActive.keep")
@pytest.mark.parametrize("form", ["incremental", "nonlinear"])
def test_compiled_warm_steps_start_as_the_python_path(form):
    """planar_4rrr, N = 40 (the moved edges' rule on), the torque limit at half
    the largest unconstrained |u| along the path, on the states of an unlimited closed loop: the compiled
    step, which chooses its warm start itself, and the Python path take the same method, sweeps and set on
    every step, their plans the same to 1e-8; the Python path starts from the moved edges on some steps
    (the rule is exercised)."""
    robot = ParallelRobot.load("planar_4rrr")
    model = ReducedModel(robot)
    N, weights = 40, Weights(1.0, 1e-5)
    ref = path_for("auto", robot.home_pose, robot.output_angular, SCurve().duration)
    states = closed_loop_states(robot, model, ref, N, weights, TS)
    free = GPCController.build(model, TS, Horizons(N), weights, form=form, solver="riccati")
    limits = Limits(torque=0.5 * max(float(np.abs(free.step(X, w).u).max()) for X, w in states))
    ctls = [GPCController.build(model, TS, Horizons(N), weights, form=form, solver="riccati", limits=limits)
            for _ in range(2)]
    python = ctls[0]
    python._riccati = RiccatiPath(python._criterion, python.model.C, form, native=False, limits=python._qp_limits,
                                  Ts=TS)
    moved_steps = 0
    for k, (X, w) in enumerate(states):
        infos = [ctl.step(X, w) for ctl in ctls]
        py, cc = (ctl._riccati.constrained for ctl in ctls)
        assert all(info.result.ok for info in infos), [info.result.message for info in infos]
        assert (py.method, py.iterations) == (cc.method, cc.iterations), k
        assert np.array_equal(py.active_set, cc.active_set), k
        assert np.abs(ctls[1].plan - python.plan).max() <= 1e-8 * np.abs(python.plan).max()
        moved_steps += py._edges
    assert ctls[1]._riccati.constrained._step is not None  # the compiled step solved
    assert moved_steps >= 1
