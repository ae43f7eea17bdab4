"""The null(B) basis of the no-drive-fighting rule (gpc.redundancy) against numpy's SVD."""

from __future__ import annotations

import numpy as np
import pytest

from parallel_gpc.gpc.redundancy import NULL_RTOL, null_basis, remove_null, without_internal


@pytest.mark.parametrize("shape", [(6, 8), (6, 4), (3, 4), (12, 16)])
def test_null_basis_equals_numpy_svd_rows(shape):
    B = np.random.default_rng(sum(shape)).standard_normal(shape)
    _, s, Vt = np.linalg.svd(B)
    rank = int(np.sum(s > NULL_RTOL * s[0]))
    basis = null_basis(B)
    if rank == shape[1]:
        assert basis is None
        return
    assert np.array_equal(basis, Vt[rank:])
    assert np.allclose(B @ basis.T, 0.0, atol=1e-12)
    assert np.allclose(basis @ basis.T, np.eye(shape[1] - rank), atol=1e-12)


def test_rank_deficient_input_matrix_keeps_only_the_moving_part():
    rng = np.random.default_rng(3)
    B = rng.standard_normal((3, 2)) @ rng.standard_normal((2, 4))  # rank 2, 4 drives
    basis = null_basis(B)
    assert basis.shape == (2, 4)
    u = rng.standard_normal(4)
    clean = without_internal(u, B)
    assert np.allclose(B @ clean, B @ u, atol=1e-12)  # the same motion
    assert np.allclose(basis @ clean, 0.0, atol=1e-12)  # no internal part left
    assert remove_null(u, None) is u
