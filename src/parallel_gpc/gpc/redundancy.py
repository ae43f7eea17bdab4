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

#: relative singular value of B_d below which a direction of u counts as null(B_d) (internal).
NULL_RTOL = 1e-8


def null_basis(B: np.ndarray) -> np.ndarray | None:
    """(m − rank, m) orthonormal rows spanning null(B) of an (n, m) B, or None at full column rank.

    LAPACK ``dgesdd`` directly: the same factorization as ``numpy.linalg.svd(B)`` (bit-identical
    here) at half its per-call cost, which the incremental forms pay on every step."""
    _, s, Vt, info = lapack.dgesdd(B, compute_uv=1, full_matrices=1)
    if info != 0:  # pragma: no cover - LAPACK convergence failure: numpy's path and its error
        _, s, Vt = np.linalg.svd(B)
    rank = int(np.sum(s > NULL_RTOL * s[0])) if s.size and s[0] > 0 else 0
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
