"""Rows that keep the drive torques out of null(B_d): no mutual drive fighting in any form.

A redundantly actuated robot (more drives than platform coordinates) has inputs that move
nothing: the component of u in null(B_r) only strains the mechanism (internal force). With
Qu = 0 the minimum-‖u‖ tie-break removes it; with Qu > 0 in the incremental forms Qu penalizes
Δu, which keeps whatever null-space component earlier inputs had, and it grows as B_r(X)
changes along the motion. :func:`without_internal` removes it from the base the increments
add to, and from the applied input, in every form and at every Qu.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack

from ..model import compiled_part

#: relative singular value of B_d below which a direction of u counts as null(B_d) (internal).
NULL_RTOL = 1e-8


def null_basis(B: np.ndarray, native: bool | None = None) -> np.ndarray | None:
    """(m − rank, m) orthonormal rows spanning null(B) of an (n, m) B, or None at full column rank.

    The rank counts the singular values above :data:`NULL_RTOL`·σ_max. The incremental forms pay
    this on every step: compiled (``_native.null_basis``, Eigen's Jacobi SVD read in place) when the core is
    available; the reference is LAPACK ``dgesdd`` directly (the factorization of
    ``numpy.linalg.svd(B)`` at half its per-call cost, mostly the wrapper's overhead at these sizes). The two
    bases span the same subspace (what :func:`remove_null` uses); their rows may differ by sign or,
    for a null space of dimension > 1, by a rotation.

    Args:
        B: (n, m) float array. native: None = compiled when available, False = the LAPACK
            reference, True = compiled or :class:`~parallel_gpc.errors.InvalidParameterError`.
    """
    compiled = compiled_part(native, "null_basis", "the compiled null(B) basis")
    if compiled is not None:
        try:
            basis = compiled(B, NULL_RTOL)
        except ValueError:  # NaN or inf in B: the reference's answer
            return _lapack_null_basis(B)
        return basis if basis.shape[0] else None
    return _lapack_null_basis(B)


def _lapack_null_basis(B: np.ndarray) -> np.ndarray | None:
    _, s, Vt, info = lapack.dgesdd(B, compute_uv=1, full_matrices=1)
    if info != 0:  # pragma: no cover - LAPACK convergence failure: numpy's path and its error
        _, s, Vt = np.linalg.svd(B)
    rank = int(np.count_nonzero(s > NULL_RTOL * s[0])) if s.size and s[0] > 0 else 0  # (np.sum: 3× the time)
    return Vt[rank:] if rank < B.shape[1] else None


def without_internal(u: np.ndarray, B: np.ndarray) -> np.ndarray:
    """u with its null(B) component removed: (m,) or (K, m) inputs (N·m), (n, m) B.

    The removed part moves nothing in the model (B·removed = 0), so the predicted motion is the
    same; the incremental forms take the result as the base the increments Δu add to, and Qu
    (which penalizes Δu) then keeps the inputs out of null(B).
    """
    return remove_null(np.asarray(u, dtype=float), null_basis(np.asarray(B, dtype=float)))


def remove_null(u: np.ndarray, basis: np.ndarray | None) -> np.ndarray:
    """u (N·m) without its component along the orthonormal rows ``basis`` of :func:`null_basis`
    (u itself when the basis is None); the controller computes the basis once per step."""
    return u if basis is None else u - (u @ basis.T) @ basis
