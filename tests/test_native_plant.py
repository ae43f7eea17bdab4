"""The compiled plant step (``parallel_gpc._native.Plant``) against the Python reference
(:class:`ConstrainedPlant` with ``native=False``, RK4 of ``pin.constraintDynamics`` through the
bindings) on every embedded robot and on test mechanisms with task-space outputs, a weld closure,
a spherical joint (nq ≠ nv) and universal joints."""

from __future__ import annotations

import os

import numpy as np
import pinocchio as pin
import pytest

from parallel_gpc import ParallelRobot
from parallel_gpc.errors import InvalidParameterError, NonFiniteError
from parallel_gpc.model.native import native_module, native_status
from parallel_gpc.model.plant import ConstrainedPlant

import mechanisms as mech
import mechanisms_ups as ups

EMBEDDED = ["planar_4rrr", "planar_3rrr", "delta_3rus", "hexapod_6ups", "hexapod_8ups"]
#: test mechanisms: task-space position output (point closure), the same with a weld closure,
#: a task-space pose output with a spherical joint (nq ≠ nv), universal joints (6-UPS)
BUILT = {
    "fivebar": lambda: (mech.fivebar_urdf(), mech.fivebar_sidecar(), ".urdf", ".toml"),
    "fivebar_weld": lambda: (mech.fivebar_urdf(split=True), mech.fivebar_sidecar(split=True), ".urdf", ".toml"),
    "rps_spherical": lambda: (mech.rps_urdf(True), mech.rps_sidecar(True), ".urdf", ".yaml"),
    "ups_universal": lambda: (ups.ups_urdf(True), ups.ups_sidecar(True), ".urdf", ".yaml"),
}
SAMPLE = 1e-3  # s
STEPS = 50


@pytest.fixture(scope="module", autouse=True)
def compiled_core():
    if native_module() is None:
        if os.environ.get("CI"):
            pytest.fail(f"the compiled core must be built in CI: {native_status()}")
        print(f"skipping the compiled-plant tests: {native_status()}")
        pytest.skip(native_status())


@pytest.fixture(scope="module", params=EMBEDDED + list(BUILT))
def any_robot(request, tmp_path_factory) -> ParallelRobot:
    if request.param in BUILT:
        model, sidecar, model_suffix, sidecar_suffix = BUILT[request.param]()
        folder = tmp_path_factory.mktemp(request.param)
        return ParallelRobot.load(mech.write(folder, request.param, model, sidecar, model_suffix, sidecar_suffix))
    return ParallelRobot.load(request.param)


def _drive_case(robot: ParallelRobot, seed: int = 3):
    """(X0, u, platform_force): a moving start, drive torques of a few % of the static ones
    around them, and a platform force (a task-space force acts as Hᵀ f, a joint-space one on
    the output rows) — all nonzero."""
    rng = np.random.default_rng(seed)
    X0 = np.concatenate([robot.home_pose, rng.uniform(-0.05, 0.05, robot.n_y)])
    q = robot.q_home
    T, _ = robot.velocity_map(q)
    B_r = T.T @ robot.drive_selection
    g_r = T.T @ pin.computeGeneralizedGravity(robot.model, robot.model.createData(), q)
    u_static = np.linalg.lstsq(B_r, g_r, rcond=None)[0]  # holds the platform against gravity
    scale = max(1.0, float(np.max(np.abs(u_static))))
    u = u_static + rng.uniform(-0.05, 0.05, robot.n_u) * scale
    force = rng.uniform(-0.02, 0.02, robot.n_y) * scale
    return X0, u, force


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def test_compiled_and_python_plants_agree_over_50_samples(any_robot):
    X0, u, force = _drive_case(any_robot)
    ref = ConstrainedPlant(any_robot, X0, Ts=SAMPLE, platform_force=force, native=False)
    fast = ConstrainedPlant(any_robot, X0, Ts=SAMPLE, platform_force=force, native=True)
    assert ref.compiled is None and fast.compiled is not None
    for _ in range(STEPS):
        X_ref, X_fast = ref.step(u), fast.step(u)
    moved = np.linalg.norm(X_ref - X0)
    assert moved > 1e-4  # the state changed: the agreement below is not that of two idle plants
    assert _relative(X_fast, X_ref) <= 1e-10
    assert _relative(fast.q, ref.q) <= 1e-10 and _relative(fast.v, ref.v) <= 1e-10
    forces = ref.constraint_forces()
    assert forces.shape == (3 * len(any_robot.closure_frames),) and np.linalg.norm(forces) > 1e-3
    assert _relative(fast.constraint_forces(), forces) <= 1e-10
    for plant in (ref, fast):  # projected onto the closures: positions and velocities
        closure = any_robot.closure_kinematics(plant.q)
        assert np.max(np.abs(closure.residual)) < 1e-10
        assert np.max(np.abs(closure.jacobian @ plant.v)) < 1e-10 * max(1.0, np.max(np.abs(plant.v)))


def test_compiled_accelerations_equal_constraint_dynamics(any_robot):
    """One call of the compiled dynamics against ``pin.constraintDynamics`` (the tests' own
    constraint models, the plant's default Baumgarte gains) at states off the closures, with the
    task-space force Hᵀ f added by hand."""
    X0, u, force = _drive_case(any_robot, seed=5)
    plant = ConstrainedPlant(any_robot, X0, Ts=SAMPLE, platform_force=force, native=True)
    model = any_robot.model
    cms = mech.closure_constraint_models(any_robot)
    for cm in cms:
        cm.setBaumgarteCorrectorParameters(pin.BaumgarteCorrectorParameters(100.0, 20.0))
    task = any_robot.task_output is not None
    rng = np.random.default_rng(6)
    for _ in range(3):
        q = any_robot.integrate(plant.q, rng.uniform(-1e-3, 1e-3, model.nv))
        v = plant.v + rng.uniform(-0.05, 0.05, model.nv)
        tau = plant._S @ u
        if task:
            expected_tau = tau + any_robot.output_jacobian(q).T @ force
        else:
            tau[any_robot.y_idx] += force
            expected_tau = tau
        expected = mech.constraint_dynamics(model, q, v, expected_tau, cms)
        got = plant.compiled.accelerations(q, v, tau, force if task else np.zeros(0))
        assert _relative(got, expected) <= 1e-9


def test_saturation_is_applied_and_counted_on_the_compiled_path(robot4):
    X0 = np.concatenate([robot4.home_pose, np.zeros(3)])
    limited = ConstrainedPlant(robot4, X0, Ts=SAMPLE, torque_limit=0.5, native=True)
    reference = ConstrainedPlant(robot4, X0, Ts=SAMPLE, torque_limit=0.5, native=False)
    u = np.array([2.0, -0.2, 0.3, -3.0])
    for _ in range(5):
        a, b = limited.step(u), reference.step(u)
    assert limited.saturated == reference.saturated == 5
    assert _relative(a, b) <= 1e-12


def test_diverging_compiled_plant_names_the_inputs(robot4):
    plant = ConstrainedPlant(robot4, np.concatenate([robot4.home_pose, np.zeros(3)]), Ts=SAMPLE,
                             platform_force=[1e300, 0.0, 0.0], native=True)
    with pytest.raises(NonFiniteError, match=r"diverged within one sample Ts = 0\.001 s") as info:
        plant.step(np.array([1.0, 2.0, 3.0, 4.0]))
    assert "u = [1.0, 2.0, 3.0, 4.0]" in str(info.value)
    assert "platform_force = [1e+300, 0.0, 0.0]" in str(info.value)


def test_native_switch(robot4, monkeypatch):
    X0 = np.concatenate([robot4.home_pose, np.zeros(3)])
    assert ConstrainedPlant(robot4, X0, Ts=SAMPLE).compiled is not None  # default: used when built
    with pytest.raises(InvalidParameterError, match=r"native = 'yes'; valid: None \(automatic\), True or False"):
        ConstrainedPlant(robot4, X0, Ts=SAMPLE, native="yes")
    monkeypatch.setenv("PARALLEL_GPC_NATIVE", "0")
    assert ConstrainedPlant(robot4, X0, Ts=SAMPLE).compiled is None
    with pytest.raises(InvalidParameterError, match=r"native=True asks for the compiled plant.*PARALLEL_GPC_NATIVE=0"):
        ConstrainedPlant(robot4, X0, Ts=SAMPLE, native=True)


def test_compiled_plant_refuses_wrong_sizes(robot4):
    plant = ConstrainedPlant(robot4, np.concatenate([robot4.home_pose, np.zeros(3)]), Ts=SAMPLE, native=True).compiled
    nq, nv = robot4.model.nq, robot4.model.nv
    with pytest.raises(ValueError, match=rf"sizes {nq - 1}, {nv}, {nv}; the model needs nq = {nq}"):
        plant.integrate(np.zeros(nq - 1), np.zeros(nv), np.zeros(nv), np.zeros(0), SAMPLE, 2)
    with pytest.raises(ValueError, match=r"Ts = -0\.001000 s and substeps = 2; valid: Ts > 0"):
        plant.integrate(np.zeros(nq), np.zeros(nv), np.zeros(nv), np.zeros(0), -SAMPLE, 2)
    with pytest.raises(ValueError, match=r"f_task must be empty"):
        plant.integrate(np.zeros(nq), np.zeros(nv), np.zeros(nv), np.zeros(3), SAMPLE, 2)


def test_projection_far_from_the_closures_takes_the_validated_path(robot4):
    """A drift too large for the warm Newton (residual > 1e-2) is projected by assemble()."""
    plant = ConstrainedPlant(robot4, np.concatenate([robot4.home_pose, [0.1, -0.1, 0.2]]), Ts=SAMPLE, native=True)
    q, v = plant.q.copy(), plant.v + 0.3  # velocities off the closures too
    q[robot4.z_idx] += 0.05  # rad: every dependent joint off its assembled value
    assert robot4.assemble_warm(robot4.platform_pose(q), q, plant._pinv) is None
    plant._project(q, v)
    closure = robot4.closure_kinematics(plant.q)
    assert np.max(np.abs(closure.residual)) < 1e-12 and np.max(np.abs(closure.jacobian @ plant.v)) < 1e-12
    np.testing.assert_array_equal(robot4.platform_pose(plant.q), robot4.platform_pose(q))
    np.testing.assert_allclose(robot4.output_velocity(plant.q, plant.v), v[robot4.y_idx], rtol=1e-14)


def test_compiled_plant_takes_mass_scale_and_gravity_from_the_robot(robot4):
    """The model reaches C++ serialized: a heavier robot under another gravity gives the Python
    plant's states, and not the nominal robot's."""
    heavy = robot4.with_mass_scale(1.3)
    heavy.model.gravity.linear = np.array([1.0, -4.0, -9.81])
    X0 = np.concatenate([robot4.home_pose, [0.05, -0.02, 0.1]])
    u = np.array([0.5, -0.3, 0.2, 0.4])
    runs = [ConstrainedPlant(r, X0, Ts=SAMPLE, native=n) for r, n in ((heavy, True), (heavy, False), (robot4, True))]
    for _ in range(20):
        fast, ref, nominal = (p.step(u) for p in runs)
    assert _relative(fast, ref) <= 1e-10
    assert _relative(nominal, ref) > 1e-4


def test_compiled_plants_in_threads_give_the_sequential_states(robot4):
    """Plant.integrate releases the GIL: plants stepped in parallel threads share no state."""
    from concurrent.futures import ThreadPoolExecutor

    X0 = np.concatenate([robot4.home_pose, [0.05, -0.02, 0.1]])
    inputs = [np.array([0.5, -0.3, 0.2, 0.4]) * s for s in (1.0, -2.0, 3.0)]

    def run(u):
        plant = ConstrainedPlant(robot4.with_mass_scale(1.0), X0, Ts=SAMPLE, native=True)  # one robot per thread
        for _ in range(30):
            X = plant.step(u)
        return X

    sequential = [run(u) for u in inputs]
    with ThreadPoolExecutor(3) as pool:
        parallel = list(pool.map(run, inputs))
    for a, b in zip(parallel, sequential):
        np.testing.assert_array_equal(a, b)


def test_compiled_projection_equals_the_python_projection(any_robot):
    """ModelUpdate.project (the plant's compiled projection) against the Python projection
    (``native=False``) from the same drifted states: q, v and T to ≤ 1e-12, sample after sample
    (each projection preconditioned by the previous one's K⁺)."""
    X0, _, _ = _drive_case(any_robot, seed=7)
    fast = ConstrainedPlant(any_robot, X0, Ts=SAMPLE, native=True)
    ref = ConstrainedPlant(any_robot, X0, Ts=SAMPLE, native=False)
    assert fast.projector is not None and ref.projector is None
    rng = np.random.default_rng(8)
    nv = any_robot.model.nv
    for _ in range(10):
        # a sample's drift off the closures: what the RK4 leaves for the projection
        q = any_robot.integrate(fast.q, 0.01 * fast.v + rng.uniform(-1e-6, 1e-6, nv))
        v = fast.v + rng.uniform(-1e-3, 1e-3, nv)
        assert np.max(np.abs(any_robot.closure_kinematics(q).residual)) > 1e-9  # a real projection
        ref.q, ref.v, ref._T, ref._pinv = fast.q, fast.v, fast._T, fast._pinv
        fast._project(q, v)
        ref._project(q, v)
        assert np.max(np.abs(fast.q - ref.q)) <= 1e-12
        assert np.max(np.abs(fast.v - ref.v)) <= 1e-12 * max(1.0, np.max(np.abs(ref.v)))
        assert np.max(np.abs(fast._T - ref._T)) <= 1e-12 * max(1.0, np.max(np.abs(ref._T)))
        assert np.max(np.abs(fast.input_matrix() - ref.input_matrix())) <= 1e-12 * max(1.0, np.max(np.abs(ref._T)))


def test_compiled_projection_goes_on_after_the_validated_path(robot4):
    """After a projection the warm Newton refuses (the Python path takes it), the compiled one
    resumes with that K⁺ as its preconditioner and equals the Python projection."""
    plant = ConstrainedPlant(robot4, np.concatenate([robot4.home_pose, [0.1, -0.1, 0.2]]), Ts=SAMPLE, native=True)
    ref = ConstrainedPlant(robot4, plant.X, Ts=SAMPLE, native=False)
    q = plant.q.copy()
    q[robot4.z_idx] += 0.05  # too far for the warm Newton
    assert plant.projector.project(q, plant.v, plant._pinv) is None
    plant._project(q, plant.v)
    ref._project(q, plant.v)
    np.testing.assert_array_equal(plant.q, ref.q)
    q = robot4.integrate(plant.q, 1e-3 * plant.v)
    ref.q, ref.v, ref._T, ref._pinv = plant.q, plant.v, plant._T, plant._pinv
    out = plant.projector.project(q, plant.v, plant._pinv)  # the warm path again
    assert out is not None
    ref._project(q, plant.v)
    assert np.max(np.abs(out[0] - ref.q)) <= 1e-12 and np.max(np.abs(out[1] - ref.v)) <= 1e-12
