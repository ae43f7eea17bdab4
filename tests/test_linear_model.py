"""GPC on a plain discrete linear model against textbook oracles written here: finite-horizon LQ
by backward Riccati recursion, batch least squares from step-by-step simulation, and the DARE
gain of infinite-horizon LQR."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import block_diag, solve_discrete_are

from parallel_gpc.limits import Limits
from parallel_gpc import DiscreteLinearModel, GPCController, Horizons, Weights
from parallel_gpc.errors import InvalidParameterError, ShapeError
from parallel_gpc.gpc import ControlModel

TS = 0.1
# a lightly damped, open-loop unstable 4-state system with 2 inputs
A = np.array([[1.0, TS, 0.0, 0.0],
              [0.05, 1.0, 0.02, 0.0],
              [0.0, 0.0, 1.0, TS],
              [0.0, 0.03, -0.04, 0.98]])
B = np.array([[0.005, 0.0], [TS, 0.01], [0.0, 0.005], [0.02, TS]])
C2 = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])  # positions only
QY = np.array([[2.0, 0.3], [0.3, 1.0]])  # square-root weights (Qy non-diagonal)
QU = np.diag([0.4, 0.2])


def _riccati_first_gain(A_, B_, Q, R, N):
    """K_0 of min Σ_{j=1}^{N} x(j)ᵀ Q x(j) + Σ_{j=0}^{N−1} u(j)ᵀ R u(j): u(0) = −K_0 x(0)."""
    P = Q.copy()  # cost-to-go at j = N
    for j in range(N - 1, -1, -1):
        K = np.linalg.solve(R + B_.T @ P @ B_, B_.T @ P @ A_)
        P = (Q if j >= 1 else 0.0 * Q) + A_.T @ P @ (A_ - B_ @ K)
    return K


def _plant(model_A, model_B, c=None):
    c = np.zeros(len(model_A)) if c is None else c
    return lambda x, u: model_A @ x + model_B @ u + c


@pytest.mark.parametrize("form", ["absolute", "incremental"])
def test_closed_loop_equals_finite_horizon_riccati(form):
    """No = 0, Nu = N, w = 0, Qu > 0: every u(k) of the receding-horizon loop is the first
    move of the finite-horizon LQ problem (backward Riccati recursion, written here)."""
    N = 12
    Q = C2.T @ QY.T @ QY @ C2
    R = QU.T @ QU
    if form == "absolute":
        K = _riccati_first_gain(A, B, Q, R, N)
    else:  # state [x; u(k−1)], input Δu
        Aa = np.block([[A, B], [np.zeros((2, 4)), np.eye(2)]])
        Ba = np.vstack([B, np.eye(2)])
        K = _riccati_first_gain(Aa, Ba, block_diag(Q, np.zeros((2, 2))), R, N)
    model = DiscreteLinearModel(A, B, C2, Ts=TS)
    ctl = GPCController.build(model, TS, Horizons(N), Weights(QY, QU), form=form, disturbance_gain=0.0)
    x, u_prev, step = np.array([0.3, -0.2, 0.1, 0.4]), np.zeros(2), _plant(A, B)
    for _ in range(15):
        u = ctl.step(x, np.zeros((N, 2))).u
        expected = -K @ x if form == "absolute" else u_prev - K @ np.concatenate([x, u_prev])
        np.testing.assert_allclose(u, expected, rtol=1e-9, atol=1e-12)
        x, u_prev = step(x, u), u
    assert np.linalg.norm(x) < 0.4  # the loop is regulating


def _batch_oracle(form, c, x0, u_prev, w, H: Horizons, Wy, Wu):
    """u(k) from stacked least squares, the prediction built by simulating the model step by step
    (f = response to v = 0, column j of G = response to v = e_j minus f) and solved by lstsq."""
    m = B.shape[1]

    def outputs(v):
        blocks = v.reshape(H.Nu, m)
        x, u, ys = x0.copy(), u_prev.copy(), []
        for i in range(H.N):
            j = min(i, H.Nu - 1)
            if form == "absolute":
                u = blocks[j]
            elif i < H.Nu:
                u = u + blocks[i]
            x = A @ x + B @ u + c
            ys.append(C2 @ x)
        return np.concatenate(ys[H.No:])

    n = H.Nu * m
    f = outputs(np.zeros(n))
    G = np.column_stack([outputs(e) - f for e in np.eye(n)])
    Qy_big = np.kron(np.eye(H.n_rows), Wy)
    lhs = np.vstack([Qy_big @ G, np.kron(np.eye(H.Nu), Wu)])
    rhs = np.concatenate([Qy_big @ (w.reshape(-1) - f), np.zeros(n)])
    v = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    return v[:m] if form == "absolute" else u_prev + v[:m]


@pytest.mark.parametrize("form", ["absolute", "incremental"])
@pytest.mark.parametrize("N,No,Nu", [(10, 0, 10), (14, 3, 5), (8, 2, 1)])
def test_first_move_equals_batch_least_squares(form, N, No, Nu):
    """Affine term, reference, No > 0, Nu < N, non-diagonal Qy, Qu > 0."""
    rng = np.random.default_rng(N * 100 + No * 10 + Nu)
    c = rng.normal(size=4) * 0.01
    H = Horizons(N, No, Nu)
    model = DiscreteLinearModel(A, B, C2, c, Ts=TS)
    ctl = GPCController.build(model, TS, H, Weights(QY, QU), form=form, u0=[0.3, -0.1], disturbance_gain=0.0)
    x0, w = rng.normal(size=4), rng.normal(size=(N, 2))
    u = ctl.step(x0, w).u
    expected = _batch_oracle(form, c, x0, np.array([0.3, -0.1]), w[No:], H, QY, QU)
    np.testing.assert_allclose(u, expected, rtol=1e-9, atol=1e-12)


def test_long_horizon_full_state_output_equals_dare_lqr_gain():
    """C = I (outputs are the whole state, n_y = n_x), No = 0, Nu = N → the DARE gain with
    Q = QyᵀQy, R = QuᵀQu: u = −K x."""
    Qy = np.diag([2.0, 0.5, 1.0, 0.3])
    model = DiscreteLinearModel(A, B, np.eye(4), Ts=TS)
    P = solve_discrete_are(A, B, Qy.T @ Qy, QU.T @ QU)
    K_lqr = np.linalg.solve(QU.T @ QU + B.T @ P @ B, B.T @ P @ A)
    N = 150
    ctl = GPCController.build(model, TS, Horizons(N), Weights(Qy, QU))
    K_gpc = np.empty((2, 4))
    for i in range(4):  # the law is linear in x: u = −K x
        ctl.reset()
        K_gpc[:, i] = -ctl.step(np.eye(4)[i], np.zeros((N, 4))).u
    np.testing.assert_allclose(K_gpc, K_lqr, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("form", ["absolute", "incremental", "nonlinear"])
def test_full_state_output_with_limits_tracks_and_respects_them(form):
    """n_y = n_x (this crashed in the conditioning check before): a QP-limited loop to a set point."""
    model = DiscreteLinearModel(A, B, np.eye(4), Ts=TS)
    ctl = GPCController.build(model, TS, Horizons(20), Weights([1.0, 0.1, 1.0, 0.1], 0.05), form=form, limits=Limits(torque=2.0))
    target = np.linalg.solve(np.eye(4) - A, B @ [0.3, -0.2])  # an equilibrium, held by u = [0.3, −0.2]
    x, step = np.zeros(4), _plant(A, B)
    for _ in range(200):
        info = ctl.step(x, np.tile(target, (20, 1)))
        assert not info.fallback and np.max(np.abs(info.u)) <= 2.0
        x = step(x, info.u)
    # the absolute form keeps an offset (Qu penalizes the steady input); integral action removes it
    assert np.linalg.norm(x - target) < (1e-6 if form != "absolute" else 0.2)
    if form != "absolute":
        np.testing.assert_allclose(info.u, [0.3, -0.2], atol=1e-5)


def test_state_dependent_model_from_function():
    """A model given as X ↦ (A, B, c): the nonlinear form pre-simulates with it and regulates;
    the absolute and incremental forms use its value at the measured state."""
    def fn(x):
        Ax = A.copy()
        Ax[1, 0] += 0.1 * np.tanh(x[0])  # stiffness that depends on the state
        return Ax, B, None

    model = DiscreteLinearModel.from_function(fn, C2, 2, Ts=TS)
    assert isinstance(model, ControlModel)
    x0 = np.array([0.4, 0.0, -0.2, 0.0])
    A_seq, B_seq, c_seq, X_seq = model.simulate_factorized(x0, np.ones((5, 2)), TS)
    for i in range(5):
        np.testing.assert_array_equal(A_seq[i], fn(X_seq[i])[0])
        np.testing.assert_allclose(X_seq[i + 1], fn(X_seq[i])[0] @ X_seq[i] + B @ np.ones(2), rtol=0, atol=1e-15)
    lti = DiscreteLinearModel(*fn(x0)[:2], C2, Ts=TS)  # the model frozen at x0: same first move
    for form in ("absolute", "incremental"):
        u_ltv = GPCController.build(model, TS, Horizons(10), Weights(1.0, 0.1), form=form).step(x0, np.zeros((10, 2))).u
        u_lti = GPCController.build(lti, TS, Horizons(10), Weights(1.0, 0.1), form=form).step(x0, np.zeros((10, 2))).u
        np.testing.assert_array_equal(u_ltv, u_lti)
    ctl = GPCController.build(model, TS, Horizons(15), Weights(1.0, 0.1), form="nonlinear")
    x, u = x0.copy(), None
    for _ in range(150):
        u = ctl.step(x, np.zeros((15, 2))).u
        Ax, Bx, _ = fn(x)
        x = Ax @ x + Bx @ u
    assert np.linalg.norm(C2 @ x) < 1e-6


def test_sample_time_mismatch_is_one_clear_error():
    model = DiscreteLinearModel(A, B, C2, Ts=TS)
    with pytest.raises(InvalidParameterError, match=r"0\.05.*0\.1"):
        GPCController.build(model, 0.05, Horizons(5))
    with pytest.raises(InvalidParameterError, match=r"0\.2"):
        model.discrete(np.zeros(4), 0.2)


@pytest.mark.parametrize("args, error", [
    ((A[:3], B, C2), ShapeError),
    ((A, B[:3], C2), ShapeError),
    ((A, B, C2[:, :3]), ShapeError),
    ((A, B, C2, np.ones(3)), ShapeError),
    ((A * np.nan, B, C2), Exception),
])
def test_bad_linear_models_are_rejected(args, error):
    with pytest.raises(error):
        DiscreteLinearModel(*args, Ts=TS)


def test_model_function_returning_wrong_shapes_is_reported():
    model = DiscreteLinearModel.from_function(lambda x: (A[:3, :3], B, None), C2, 2, Ts=TS)
    ctl = GPCController.build(model, TS, Horizons(5))
    with pytest.raises(ShapeError, match=r"\(3, 3\)"):
        ctl.step(np.zeros(4), np.zeros((5, 2)))


def test_an_object_without_the_protocol_is_rejected():
    class NoSim:
        n_x, n_y, n_u, C = 2, 1, 1, np.array([[1.0, 0.0]])

        def discrete(self, X, Ts):
            return np.eye(2), np.ones((2, 1)), np.zeros(2)

    GPCController.build(NoSim(), TS, Horizons(3))  # enough for the linear forms
    with pytest.raises(InvalidParameterError, match="simulate_factorized"):
        GPCController.build(NoSim(), TS, Horizons(3), form="nonlinear")
    with pytest.raises(InvalidParameterError, match="'n_x'.*ControlModel"):
        GPCController.build(object(), TS, Horizons(3))
