"""The compiled stage Jacobians on several threads (native/src/stage_jacobian.cpp, thread_pool.cpp):
the same numbers bit for bit as on one thread whatever the split (several robots, stage counts not
divisible by the threads, one stage), the model update left as the loop on one thread leaves it, a
stage's error raised as on one thread, and the one owner of the thread count (PARALLEL_GPC_THREADS,
validated where it enters). On the Python reference path the variable is never read."""

from __future__ import annotations

import numpy as np
import pytest

import mechanisms as mech
import mechanisms_ups as ups
from parallel_gpc import ParallelRobot, ReducedModel
from parallel_gpc.errors import InvalidParameterError, NonFiniteError
from parallel_gpc.model import native_update
from parallel_gpc.model.native import native_module

TS = 0.002


@pytest.fixture
def threads(monkeypatch):
    """set(n): the compiled model updates built next run their stage loops on n threads (None: unset)."""
    def set_threads(n):
        if n is None:
            monkeypatch.delenv(native_update.THREADS_ENV, raising=False)
        else:
            monkeypatch.setenv(native_update.THREADS_ENV, str(n))
        native_update.compiled_threads.cache_clear()
    yield set_threads
    native_update.compiled_threads.cache_clear()  # monkeypatch restores the variable; read it again


@pytest.fixture
def compiled():
    """The compiled stage loop, on the threads asked even on a loaded machine (which would otherwise run
    the stages on one thread, ThreadPool::free_cores, and leave the helpers untested)."""
    module = native_module()
    if not hasattr(module, "adapt_threads"):
        pytest.skip("the compiled core has no threaded stage_jacobians (PARALLEL_GPC_NATIVE=0 or an older build)")
    module.adapt_threads(False)
    yield
    module.adapt_threads(True)


@pytest.fixture(scope="module")
def universal_ups(tmp_path_factory):
    """A 6-UPS hexapod with universal base joints: the Coriolis path of RNEA derivatives (a joint
    with two degrees of freedom), not the one-pass tangent rates."""
    folder = tmp_path_factory.mktemp("ups")
    return ParallelRobot.load(mech.write(folder, "ups_universal", ups.ups_urdf(True), ups.ups_sidecar(True),
                                         ".urdf", ".yaml"))


def _robots(universal_ups):
    return [ParallelRobot.load(name) for name in ("planar_4rrr", "delta_3rus", "hexapod_6ups")] + [universal_ups]


def _run(model, X0, u, start, calls=3):
    """Pre-simulate, then the stage Jacobians `calls` times (the stages are handed out anew each time),
    then one model update off the trajectory (its Newton starts from the warm start the call left)."""
    traj = model.simulate_factorized(X0, u, TS)[3]
    J = [model.stage_jacobians(traj, u, TS, start=start) for _ in range(calls)]
    after = model.discrete(traj[len(u) - 1] + 1e-4 * np.r_[np.ones(model.n_y), np.zeros(model.n_y)], TS)
    return traj, J, after


@pytest.mark.parametrize("K, start", [(20, 1), (7, 0), (5, 1), (1, 0), (2, 1)])
def test_threaded_stage_jacobians_equal_one_thread_bit_for_bit(K, start, threads, compiled, universal_ups):
    """2, 3 and 4 threads against 1 on four robots (revolute, spherical-universal, prismatic legs,
    universal base joints): every Jacobian equal to the last bit, at every call (the split differs
    from call to call), and the model update's warm start after the call as on one thread."""
    for robot in _robots(universal_ups):
        X0, u = mech.fast_move(robot, K)
        # a robot's first assembly from home may take its validated path (the robot's own warm start):
        # after it, every new model pre-simulates the same trajectory to the last bit
        ReducedModel(robot).simulate_factorized(X0, u, TS)
        threads(1)
        traj, one, after_one = _run(ReducedModel(robot), X0, u, start)
        assert one[0].shape == (K - start, 2 * robot.n_y, 2 * robot.n_y) and np.all(np.isfinite(one[0]))
        for n in (2, 3, 4):
            threads(n)
            traj_n, many, after_many = _run(ReducedModel(robot), X0, u, start)
            assert np.array_equal(traj_n, traj)  # the pre-simulation runs on one thread: the same states
            for J in many + one[1:]:
                assert np.array_equal(J, one[0]), (robot.name, n)
            for a, b in zip(after_many, after_one):
                assert np.array_equal(a, b), (robot.name, n)


def test_threaded_stage_jacobians_equal_the_python_reference(threads, compiled):
    """Not only consistent: the threaded Jacobians equal the Python loop (the reference) to the
    rounding of two paths, as the compiled one-thread ones do (tests/test_nmpc.py)."""
    robot = ParallelRobot.load("delta_3rus")
    X0, u = mech.fast_move(robot, 9)
    threads(3)
    model = ReducedModel(robot)
    traj = model.simulate_factorized(X0, u, TS)[3]
    J = model.stage_jacobians(traj, u, TS)
    J_ref = ReducedModel(robot, native=False).stage_jacobians(traj, u, TS)
    assert np.abs(J - J_ref).max() <= 1e-8 * np.abs(J_ref).max()


def test_states_off_the_presimulation_run_on_one_thread(threads, compiled):
    """States that are not the last pre-simulation's (each assembly starts from the stage before):
    the loop on one thread, the same numbers with any thread count."""
    robot = ParallelRobot.load("planar_4rrr")
    X0, u = mech.fast_move(robot, 6)
    out = {}
    for n in (1, 2):
        threads(n)
        model = ReducedModel(robot)
        traj = model.simulate_factorized(X0, u, TS)[3]
        out[n] = model.stage_jacobians(traj[:6] + 1e-6, u, TS)
    assert np.array_equal(out[1], out[2])


def test_a_stage_error_on_a_worker_thread_is_raised_as_on_one_thread(threads, compiled):
    """An infinite sample time fails in every stage (the Python error called back from the worker
    threads, which take the GIL for it): one NonFiniteError as on one thread, and the threads serve
    the next call as before."""
    robot = ParallelRobot.load("planar_4rrr")
    X0, u = mech.fast_move(robot, 8)
    ReducedModel(robot).simulate_factorized(X0, u, TS)  # the robot's first assembly (see above)
    out = {}
    for n in (1, 4):
        threads(n)
        model = ReducedModel(robot)
        traj = model.simulate_factorized(X0, u, TS)[3]
        for _ in range(3):
            with pytest.raises(NonFiniteError, match="matrix exponential of a matrix with NaN or inf entries"):
                model.stage_jacobians(traj, u, np.inf)
        out[n] = model.stage_jacobians(traj, u, TS)
    assert np.array_equal(out[4], out[1])


@pytest.mark.parametrize("text, n", [("1", 1), (" 3 ", 3), ("64", 64)])
def test_the_thread_count_is_a_whole_number(text, n):
    assert native_update.thread_count(text) == n


def test_the_default_thread_count_is_two_at_most():
    cores = native_update.available_cores()
    assert native_update.thread_count(None) == native_update.thread_count("") == min(2, cores) >= 1


@pytest.mark.parametrize("text", ["0", "-1", "two", "1.5", "65", "²", "1e3"])
def test_a_bad_thread_count_is_one_clear_error(text):
    with pytest.raises(InvalidParameterError) as info:
        native_update.thread_count(text)
    message = str(info.value)
    assert f"PARALLEL_GPC_THREADS = {text!r}" in message and "valid: a whole number 1..64" in message


def test_a_bad_variable_stops_the_first_compiled_model_update(threads, compiled, robot4):
    """Read once, where it enters (the first compiled model update), not in a stage loop later."""
    threads("many")
    with pytest.raises(InvalidParameterError, match="PARALLEL_GPC_THREADS = 'many'"):
        ReducedModel(robot4).discrete(np.r_[robot4.home_pose, np.zeros(robot4.n_y)], TS)


def test_the_python_reference_path_never_reads_the_variable(threads, robot4):
    threads("many")
    reference = ReducedModel(robot4, native=False)
    X0, u = mech.fast_move(robot4, 3)
    traj = reference.simulate_factorized(X0, u, TS)[3]
    assert reference.stage_jacobians(traj, u, TS).shape == (3, 6, 6)


def test_the_thread_count_is_read_once(threads, compiled, robot4, monkeypatch):
    threads(2)
    assert native_update.compiled_threads() == 2
    monkeypatch.setenv(native_update.THREADS_ENV, "bad")  # not read again in this process
    assert native_update.compiled_threads() == 2
    ReducedModel(robot4).discrete(np.r_[robot4.home_pose, np.zeros(robot4.n_y)], TS)



def _child_jacobians(model, traj, u, queue):
    queue.put(model.stage_jacobians(traj, u, TS))


def test_a_forked_child_makes_its_own_threads(threads, compiled):
    """The pool's threads do not exist in a forked child (multiprocessing's fork, a sweep's workers): the
    child's threaded call runs (on a pool of its own) and gives the parent's numbers."""
    import multiprocessing
    robot = ParallelRobot.load("planar_4rrr")
    X0, u = mech.fast_move(robot, 9)
    threads(2)
    model = ReducedModel(robot)
    traj = model.simulate_factorized(X0, u, TS)[3]
    J = model.stage_jacobians(traj, u, TS)  # the parent's pool is running
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    child = context.Process(target=_child_jacobians, args=(model, traj, u, queue))
    child.start()
    J_child = queue.get(timeout=120)
    child.join(timeout=60)
    assert child.exitcode == 0 and np.array_equal(J_child, J)
