"""The compiled ZOH exponential kernels (native/src/zoh.cpp: TopRowsExpm of the rollout, TopRowsExpmDerivative
of the stage Jacobians) against independent oracles: scipy.linalg.expm and scipy.linalg.expm_frechet on the full
(n, n) matrices, a long-double Taylor series of the exponential, and the Python reference
model/discretization.py (expm, expm_derivative_action), to 1e-12 relative (against scipy 1e-12·‖M‖ above
‖M‖ = 1: its own error). The matrices have the ZOH structure of a robot ([[0, Ts·I, 0], [Z·Ts]]: leading zero columns, the
directions on the ẏ rows only) or none; the row counts the kernels compile (4, 6, 12) and others (the run-time
fallback); norms without scaling (a 2 ms sample) and with up to 2^6 squarings."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from parallel_gpc.model.discretization import DEGREE_NORMS, expm, expm_derivative_action
from parallel_gpc.model.native import native_module

RTOL = 1e-12
#: (m top rows, n columns): the compiled row counts 4, 6, 12 and the run-time fallback 5, 3
SHAPES = [(4, 7), (6, 11), (6, 10), (12, 19), (5, 9), (3, 3)]
#: Frobenius norms of M_top: a 2 ms ZOH matrix (no squaring), θ = 0.5 exactly, then s = 2, s = 6 and s = 10 (a robot
#: with light links at 2 ms); at s = 6 and 10 the derivative goes through the squarings (2^s − 1 > n:
#: discretization.frechet_by_squaring), below along the vector
NORMS = [0.006, 0.5, 1.7, 25.0, 418.0]


def _case(m, n, norm, robot, seed):
    """(M_top (m, n), D (m, m, n), xi (n,)) of the given norm; robot: the ZOH structure (the first m/2 columns
    zero, the position rows Ts·[0 I 0], the directions on the last m/2 rows and columns m/2..)."""
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((m, n))
    D = rng.standard_normal((m, m, n))
    if robot:
        ny = m // 2
        M[:, :ny] = 0.0
        M[:ny] = 0.0
        M[:ny, ny:2 * ny] = np.eye(ny)
        D[:, :ny] = 0.0
        D[:, :, :ny] = 0.0
        D[ny:, :, 2 * ny:] = 0.0  # the ẏ directions move only the ẏ columns (Z is linear in ẏ)
    M *= norm / np.linalg.norm(M)
    D *= norm / np.linalg.norm(D[0])
    return M, D, rng.standard_normal(n)


def _full(top, n):
    out = np.zeros((n, n))
    out[:top.shape[0]] = top
    return out


def _oracle(M, D, xi):
    """(top rows of e^M, dE[:, k] = top rows of L(M, D_k) xi) by scipy on the full matrices."""
    m, n = M.shape
    full = _full(M, n)
    E = scipy.linalg.expm(full)[:m]
    dE = np.column_stack([(scipy.linalg.expm_frechet(full, _full(Dk, n), compute_expm=False) @ xi)[:m] for Dk in D])
    return E, dE


def _expm_long(M_top):
    """Top rows of e^M by a Taylor series of M/2^10 in long double (64-bit mantissa) and ten squarings: a third
    oracle, more accurate than scipy's Padé exponential at large norms (which errs by ~2e-12 at ‖M‖ = 25)."""
    m, n = M_top.shape
    A = _full(M_top, n).astype(np.longdouble) / 2**10
    E = P = np.eye(n, dtype=np.longdouble)
    for k in range(1, 40):
        P = P @ A / k
        E = E + P
    for _ in range(10):
        E = E @ E
    return E[:m].astype(float)


def _close(got, ref, rtol=RTOL):
    assert got.shape == ref.shape
    assert np.abs(got - ref).max() <= rtol * np.abs(ref).max()


def _scipy_rtol(norm):
    """scipy's own error grows with the norm: 1e-12 up to ‖M‖ = 1, then in proportion."""
    return RTOL * max(1.0, norm)


@pytest.fixture(scope="module")
def compiled():
    module = native_module()
    if module is None or not hasattr(module, "expm_derivative_action"):
        pytest.skip("no compiled core with the ZOH kernels' entry points (PARALLEL_GPC_NATIVE=0 or an older build)")
    return module


@pytest.mark.parametrize("robot", [True, False])
@pytest.mark.parametrize("norm", NORMS)
@pytest.mark.parametrize("m, n", SHAPES)
def test_compiled_expm_top_equals_scipy_and_the_reference(compiled, m, n, norm, robot):
    M, _, _ = _case(m, n, norm, robot and m % 2 == 0, seed=m * 100 + n)
    E = compiled.expm_top(M, DEGREE_NORMS)
    _close(E, _expm_long(M))
    _close(E, scipy.linalg.expm(_full(M, n))[:m], _scipy_rtol(norm))
    _close(E, expm(_full(M, n))[:m])


@pytest.mark.parametrize("robot", [True, False])
@pytest.mark.parametrize("norm", NORMS)
@pytest.mark.parametrize("m, n", SHAPES)
def test_compiled_derivative_action_equals_scipy_frechet_and_the_reference(compiled, m, n, norm, robot):
    """Every direction's column of dE, and E, against expm_frechet applied to xi; the directions stacked on
    their nonzero rows (the ẏ rows of a robot's, all rows otherwise)."""
    M, D, xi = _case(m, n, norm, robot and m % 2 == 0, seed=m * 100 + n + 1)
    E, dE = compiled.expm_derivative_action(M, D, xi, DEGREE_NORMS)
    E_ref, dE_ref = _oracle(M, D, xi)
    _close(E, _expm_long(M))
    _close(E, E_ref, _scipy_rtol(norm))
    _close(dE, dE_ref, _scipy_rtol(norm))
    E_py, dE_py = expm_derivative_action(M, D, xi)
    _close(E, E_py)
    _close(dE, dE_py)


def test_compiled_derivative_action_with_zero_directions(compiled):
    """A direction that is zero everywhere gives a zero column; all directions zero: dE = 0 exactly."""
    M, D, xi = _case(6, 11, 0.3, True, seed=3)
    D[2] = 0.0
    E, dE = compiled.expm_derivative_action(M, D, xi, DEGREE_NORMS)
    assert np.all(dE[:, 2] == 0.0)
    _close(dE, _oracle(M, D, xi)[1])
    E0, dE0 = compiled.expm_derivative_action(M, np.zeros_like(D), xi, DEGREE_NORMS)
    assert np.all(dE0 == 0.0)
    _close(E0, E)


def test_compiled_kernels_reject_nonfinite_and_bad_shapes(compiled):
    M, D, xi = _case(6, 11, 0.3, True, seed=4)
    bad = M.copy()
    bad[4, 7] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        compiled.expm_top(bad, DEGREE_NORMS)
    with pytest.raises(ValueError, match="NaN"):
        compiled.expm_derivative_action(bad, D, xi, DEGREE_NORMS)
    with pytest.raises(ValueError, match="xi"):
        compiled.expm_derivative_action(M, D, xi[:-1], DEGREE_NORMS)
    with pytest.raises(ValueError, match="m ≤ n"):
        compiled.expm_top(M.T, DEGREE_NORMS)


@pytest.mark.parametrize("norm", NORMS)
def test_reference_derivative_action_equals_scipy_frechet(norm):
    """The Python reference itself (discretization.expm_derivative_action) against scipy: the oracle chain
    the compiled kernels are held to does not rest on the reference alone."""
    M, D, xi = _case(6, 11, norm, True, seed=5)
    E, dE = expm_derivative_action(M, D, xi)
    E_ref, dE_ref = _oracle(M, D, xi)
    _close(E, _expm_long(M))
    _close(E, E_ref, _scipy_rtol(norm))
    _close(dE, dE_ref, _scipy_rtol(norm))
