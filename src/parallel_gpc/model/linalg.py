"""Small dense linear-algebra helpers of the model's hot paths."""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack


def fast_index(idx: np.ndarray):
    """A slice equal to the integer index array ``idx`` when it is an arithmetic progression
    (basic slicing is several times cheaper than fancy indexing in the hot paths), else ``idx``."""
    idx = np.asarray(idx, dtype=int)
    if idx.size == 0:
        return idx
    if idx.size == 1:
        return slice(int(idx[0]), int(idx[0]) + 1)
    step = int(idx[1] - idx[0])
    if step > 0 and np.all(np.diff(idx) == step):
        return slice(int(idx[0]), int(idx[-1]) + 1, step)
    return idx


def svd_thin(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Thin SVD ``a = U diag(s) Vt`` by LAPACK ``dgesdd`` (same factorization as
    ``numpy.linalg.svd(a, full_matrices=False)``, without its per-call overhead)."""
    U, s, Vt, info = lapack.dgesdd(a, compute_uv=1, full_matrices=0)
    if info != 0:  # pragma: no cover - LAPACK convergence failure: take numpy's path and its error
        return np.linalg.svd(a, full_matrices=False)
    return U, s, Vt


def spd_solve(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A⁻¹ B for a symmetric positive definite A (Cholesky; LU if A is not numerically SPD)."""
    _, X, info = lapack.dposv(A, B)
    if info != 0:
        _, _, X, info = lapack.dgesv(A, B)
        if info != 0:
            raise np.linalg.LinAlgError(f"singular reduced mass matrix (LAPACK info {info})")
    return X
