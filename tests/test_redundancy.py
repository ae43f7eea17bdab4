"""The null(B) basis of the no-drive-fighting rule (gpc.redundancy) against numpy's SVD, the
compiled basis against the LAPACK reference."""

from __future__ import annotations

import numpy as np
import pytest

from parallel_gpc.gpc.redundancy import NULL_RTOL, null_basis, remove_null, without_internal
from parallel_gpc.model.native import native_module

HAS_COMPILED = native_module() is not None and hasattr(native_module(), "null_basis")
NATIVE = [False, pytest.param(True, marks=pytest.mark.skipif(not HAS_COMPILED, reason="compiled core not available"))]


@pytest.mark.parametrize("native", NATIVE)
@pytest.mark.parametrize("shape", [(6, 8), (6, 4), (3, 4), (12, 16), (4, 6)])
def test_null_basis_spans_numpy_svd_null_space(shape, native):
    """The reference is numpy's own factorization row for row; the compiled one (Eigen's Jacobi
    SVD) spans the same subspace: the same orthogonal projector."""
    rng = np.random.default_rng(sum(shape))
    B = rng.standard_normal(shape)
    if shape == (6, 4):  # a robot's B_d: 4 drives, 3 platform coordinates (rank 3)
        B = rng.standard_normal((6, 3)) @ rng.standard_normal((3, 4))
    _, s, Vt = np.linalg.svd(B)
    rank = int(np.sum(s > NULL_RTOL * s[0]))
    basis = null_basis(B, native=native)
    if rank == shape[1]:
        assert basis is None
        return
    if not native:
        assert np.array_equal(basis, Vt[rank:])
    assert basis.shape == (shape[1] - rank, shape[1])
    np.testing.assert_allclose(basis.T @ basis, Vt[rank:].T @ Vt[rank:], atol=1e-12)
    assert np.allclose(B @ basis.T, 0.0, atol=1e-12)
    assert np.allclose(basis @ basis.T, np.eye(shape[1] - rank), atol=1e-12)


@pytest.mark.parametrize("native", NATIVE)
def test_null_basis_of_zero_and_non_finite_matrices(native):
    """All of R^m is null for B = 0 (no singular value above the tolerance); a B with NaN gets the
    reference's answer (numpy's LinAlgError) from the compiled path too."""
    zero = null_basis(np.zeros((3, 4)), native=native)
    np.testing.assert_allclose(zero.T @ zero, np.eye(4), atol=1e-14)
    with pytest.raises(np.linalg.LinAlgError):
        null_basis(np.array([[1.0, np.nan], [0.0, 1.0]]), native=native)


def test_rank_deficient_input_matrix_keeps_only_the_moving_part():
    rng = np.random.default_rng(3)
    B = rng.standard_normal((3, 2)) @ rng.standard_normal((2, 4))  # rank 2, 4 drives
    basis = null_basis(B)
    np.testing.assert_allclose(basis.T @ basis, null_basis(B, native=False).T @ null_basis(B, native=False),
                               atol=1e-12)  # compiled or not: the same subspace
    assert basis.shape == (2, 4)
    u = rng.standard_normal(4)
    clean = without_internal(u, B)
    assert np.allclose(B @ clean, B @ u, atol=1e-12)  # the same motion
    assert np.allclose(basis @ clean, 0.0, atol=1e-12)  # no internal part left
    assert remove_null(u, None) is u
