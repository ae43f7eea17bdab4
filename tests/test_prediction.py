"""The LTV condenser and the three prediction forms against step-by-step simulation."""

from __future__ import annotations

import numpy as np
import pytest

from parallel_gpc.errors import InvalidParameterError
from parallel_gpc.model import native_module, native_status
from parallel_gpc.gpc import (
    Horizons,
    absolute_prediction,
    condense,
    incremental_prediction,
    simulative_prediction,
)
from parallel_gpc.gpc.prediction import deviation_gain, deviation_response


def _random_system(rng, n=4, m=3, p=2, N=None):
    A = np.eye(n) + 0.1 * rng.normal(size=(n, n) if N is None else (N, n, n))
    B = rng.normal(size=(n, m) if N is None else (N, n, m))
    c = 0.01 * rng.normal(size=n if N is None else (N, n))
    C = rng.normal(size=(p, n))
    return A, B, c, C


def _simulate(A, B, c, C, x0, inputs):
    """Oracle: iterate x(i+1) = A_i x(i) + B_i u(i) + c_i, return outputs y(1..N)."""
    N = len(inputs)
    A = np.broadcast_to(A, (N, *np.shape(A)[-2:]))
    B = np.broadcast_to(B, (N, *np.shape(B)[-2:]))
    c = np.broadcast_to(c, (N, np.shape(c)[-1]))
    x, ys = np.array(x0, dtype=float), []
    for i in range(N):
        x = A[i] @ x + B[i] @ inputs[i] + c[i]
        ys.append(C @ x)
    return np.array(ys)


@pytest.mark.parametrize("N,No,Nu", [(8, 0, 8), (8, 3, 8), (8, 0, 3), (10, 4, 2), (1, 0, 1)])
def test_absolute_prediction_equals_simulation_with_held_inputs(N, No, Nu):
    rng = np.random.default_rng(N + 10 * No + 100 * Nu)
    A, B, c, C = _random_system(rng)
    x0 = rng.normal(size=4)
    v = rng.normal(size=(Nu, 3))
    pred = absolute_prediction(A, B, c, C, x0, Horizons(N, No, Nu))
    inputs = np.vstack([v, np.repeat(v[-1:], N - Nu, axis=0)])  # held after Nu
    expected = _simulate(A, B, c, C, x0, inputs)[No:]
    np.testing.assert_allclose(pred.outputs(v.reshape(-1)), expected.reshape(-1), rtol=0, atol=1e-10)


@pytest.mark.parametrize("N,No,Nu", [(8, 0, 8), (9, 2, 4), (6, 5, 1)])
def test_incremental_prediction_equals_simulation_of_cumulated_inputs(N, No, Nu):
    rng = np.random.default_rng(7 + N)
    A, B, c, C = _random_system(rng)
    x0, u_prev = rng.normal(size=4), rng.normal(size=3)
    dv = rng.normal(size=(Nu, 3))
    pred = incremental_prediction(A, B, c, C, x0, u_prev, Horizons(N, No, Nu))
    du = np.vstack([dv, np.zeros((N - Nu, 3))])  # Δu = 0 after Nu
    inputs = u_prev + np.cumsum(du, axis=0)
    expected = _simulate(A, B, c, C, x0, inputs)[No:]
    np.testing.assert_allclose(pred.outputs(dv.reshape(-1)), expected.reshape(-1), rtol=0, atol=1e-10)
    np.testing.assert_allclose((pred.u_base + pred.u_map @ dv.reshape(-1)).reshape(-1, 3), inputs[:Nu], atol=1e-12)


@pytest.mark.parametrize("native", ["1", "0"])  # the compiled condensing and its Python reference
@pytest.mark.parametrize("N,No,Nu", [(8, 0, 8), (8, 2, 3), (7, 6, 1)])
def test_simulative_prediction_equals_ltv_simulation_about_the_presimulated_path(N, No, Nu, native, monkeypatch):
    monkeypatch.setenv("PARALLEL_GPC_NATIVE", native)
    rng = np.random.default_rng(3 + N + Nu)
    A_seq, B_seq, c_seq, C = _random_system(rng, N=N)
    x0 = rng.normal(size=4)
    u_sim = rng.normal(size=(N, 3))
    y_sim = _simulate(A_seq, B_seq, c_seq, C, x0, u_sim)  # the pre-simulation
    dv = rng.normal(size=(Nu, 3))
    pred = simulative_prediction(A_seq, B_seq, C, y_sim, u_sim, Horizons(N, No, Nu))
    du = np.vstack([dv, np.zeros((N - Nu, 3))])
    inputs = u_sim + np.cumsum(du, axis=0)  # u = u_sim + cumsum(Δu), eq. (10)–(11)
    expected = _simulate(A_seq, B_seq, c_seq, C, x0, inputs)[No:]
    np.testing.assert_allclose(pred.outputs(dv.reshape(-1)), expected.reshape(-1), rtol=0, atol=1e-10)
    np.testing.assert_allclose((pred.u_base + pred.u_map @ dv.reshape(-1)).reshape(-1, 3), inputs, atol=1e-12)


@pytest.mark.parametrize("N,No,Nu", [(20, 0, 20), (8, 2, 3), (6, 5, 1), (1, 0, 1)])
def test_compiled_deviation_condensing_equals_the_python_reference(N, No, Nu, monkeypatch):
    if not hasattr(native_module(), "condense_deviation"):
        pytest.skip(native_status())
    rng = np.random.default_rng(5 * N + No + Nu)
    A_seq, B_seq, _, C = _random_system(rng, n=6, m=4, p=3, N=N)
    y_sim, u_sim = rng.normal(size=(N, 3)), rng.normal(size=(N, 4))
    fast = simulative_prediction(A_seq, B_seq, C, y_sim, u_sim, Horizons(N, No, Nu))
    monkeypatch.setenv("PARALLEL_GPC_NATIVE", "0")
    reference = simulative_prediction(A_seq, B_seq, C, y_sim, u_sim, Horizons(N, No, Nu))
    assert fast.G.shape == reference.G.shape == ((N - No) * 3, Nu * 4)
    np.testing.assert_allclose(fast.G, reference.G, rtol=1e-12, atol=1e-12 * np.max(np.abs(reference.G)))
    assert np.array_equal(fast.f, reference.f) and np.array_equal(fast.u_map, reference.u_map)



@pytest.mark.parametrize("native", ["1", "0"])  # the compiled pass and its reference (deviation_gain(...) @ v)
@pytest.mark.parametrize("N,No,Nu", [(20, 0, 20), (8, 2, 3), (6, 5, 1), (1, 0, 1)])
def test_deviation_response_is_the_simulated_deviation(N, No, Nu, native, monkeypatch):
    """G v without G: the deviation model's outputs for the inputs of v, against step-by-step
    simulation of the deviation (from 0, δu = cumsum(Δu) held after Nu) and against G @ v."""
    monkeypatch.setenv("PARALLEL_GPC_NATIVE", native)
    rng = np.random.default_rng(17 * N + No + Nu)
    A_seq, B_seq, _, C = _random_system(rng, n=6, m=4, p=3, N=N)
    dv = rng.normal(size=(Nu, 4))
    H = Horizons(N, No, Nu)
    got = deviation_response(A_seq, B_seq, C, H, dv.reshape(-1))
    du = np.cumsum(np.vstack([dv, np.zeros((N - Nu, 4))]), axis=0)
    expected = _simulate(A_seq, B_seq, np.zeros(6), C, np.zeros(6), du)[No:].reshape(-1)
    scale = np.max(np.abs(expected))
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(got, deviation_gain(A_seq, B_seq, C, H) @ dv.reshape(-1), rtol=0, atol=1e-12 * scale)

def test_condense_matches_eq7_block_toeplitz_for_lti():
    rng = np.random.default_rng(11)
    A, B, _, C = _random_system(rng)
    N = 5
    f, G = condense(A, B, None, C, np.ones(4), Horizons(N), hold_inputs=True)
    for i in range(N):
        np.testing.assert_allclose(f[2 * i:2 * i + 2], C @ np.linalg.matrix_power(A, i + 1) @ np.ones(4), atol=1e-12)
        for j in range(N):
            block = G[2 * i:2 * i + 2, 3 * j:3 * j + 3]
            expected = C @ np.linalg.matrix_power(A, i - j) @ B if j <= i else np.zeros((2, 3))
            np.testing.assert_allclose(block, expected, atol=1e-12)


@pytest.mark.parametrize("kwargs", [dict(N=0), dict(N=5, No=5), dict(N=5, No=-1), dict(N=5, Nu=6), dict(N=5, Nu=0),
                                    dict(N=2.5)])
def test_invalid_horizons_raise(kwargs):
    with pytest.raises(InvalidParameterError):
        Horizons(**kwargs)


@pytest.mark.parametrize("ltv", [False, True])
@pytest.mark.parametrize("N,No,Nu", [(8, 0, 8), (9, 2, 4), (6, 4, 1)])
def test_delayed_incremental_prediction_equals_simulation_with_the_increment_one_sample_later(N, No, Nu, ltv):
    """Eq. (8)–(9) as printed: state [X(k); u(k)], B̄ = [0; I]: u(k) is given, u(k+1+i) =
    u(k) + Σ_{j≤i} Δu(k+j); both condenser paths (time-invariant and per-step matrices)."""
    rng = np.random.default_rng(41 + N + 3 * Nu + 7 * ltv)
    A, B, c, C = _random_system(rng, N=N if ltv else None)
    x0, u_now = rng.normal(size=4), rng.normal(size=3)
    dv = rng.normal(size=(Nu, 3))
    pred = incremental_prediction(A, B, c, C, x0, u_now, Horizons(N, No, Nu), delayed=True)
    du = np.vstack([dv, np.zeros((N - Nu, 3))])
    inputs = np.vstack([u_now, u_now + np.cumsum(du, axis=0)[:N - 1]])  # realized one sample later
    expected = _simulate(A, B, c, C, x0, inputs)[No:]
    np.testing.assert_allclose(pred.outputs(dv.reshape(-1)), expected.reshape(-1), rtol=0, atol=1e-10)
    # the constrained inputs are u(k+1) … u(k+Nu)
    np.testing.assert_allclose((pred.u_base + pred.u_map @ dv.reshape(-1)).reshape(-1, 3),
                               u_now + np.cumsum(dv, axis=0), atol=1e-12)
    if No == 0:  # ŷ(k+1) does not depend on v
        assert not np.any(pred.G[:2])


@pytest.mark.parametrize("K, Nu, m", [(20, 20, 4), (160, 160, 4), (160, 60, 4), (120, 120, 3), (7, 3, 2)])
def test_the_inputs_of_a_cumulative_map_are_its_product(K, Nu, m):
    """Prediction.inputs: u_base + u_map v, by running sums of the increments for the forms' large
    cumulative maps (held after Nu), by the product for the others; the same numbers to rounding."""
    from parallel_gpc.gpc.prediction import Horizons, Prediction, cumulative_map

    rng = np.random.default_rng(K + Nu + m)
    u_map, u_base, v = cumulative_map(K, Nu, m), rng.standard_normal(K * m), rng.standard_normal(Nu * m)
    pred = Prediction(np.zeros(0), np.zeros((0, Nu * m)), u_base, u_map, Horizons(K, 0, Nu), "simulative")
    dense = u_base + u_map @ v
    np.testing.assert_allclose(pred.inputs(v), dense, rtol=0, atol=1e-13 * np.abs(dense).max())
    other = Prediction(np.zeros(0), np.zeros((0, Nu * m)), u_base, np.array(u_map), Horizons(K, 0, Nu), "simulative")
    np.testing.assert_allclose(other.inputs(v), dense, rtol=0, atol=1e-13 * np.abs(dense).max())  # a copy: product
