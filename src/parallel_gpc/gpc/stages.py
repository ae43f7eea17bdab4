"""The controller's stage models (one owner: the Riccati recursion, the stage-wise constrained
solvers and the benchmark's LTV row build them here; ``Riccati::stage`` and ``RiccatiActive`` in C++,
through native/src/stage_model.hpp, are the compiled twins).

Stage models z(i+1) = Ā_i z(i) + B̄_i v(i) + c̄_i, output ŷ = C̄ z, C̄ = [C 0], of each form: see
:mod:`parallel_gpc.gpc.riccati`.
"""

from __future__ import annotations

import numpy as np

from .prediction import Horizons

__all__ = ["stage_models", "FORM_CODES"]

#: form codes of the compiled ``_native.Riccati``
FORM_CODES = {"absolute": 0, "incremental": 1, "incremental-delayed": 2, "nonlinear": 3}


def stage_models(form: str, A, B, c, C, x0, u0, horizons: Horizons):
    """The stage models of :mod:`parallel_gpc.gpc.riccati`'s docstring (the Python twin of native/src/stage_model.hpp).

    Args:
        form: one of :data:`FORM_CODES`.
        A: (n, n) or (N, n, n); B: (n, m) or (N, n, m); c: (n,), (N, n) or None (nonlinear: ignored).
        C: (p, n) output matrix. x0: (n,) state (nonlinear: ignored, δx = 0).
        u0: (m,) the input in the state (incremental: u(k−1); delayed: u(k); otherwise ignored).
        horizons: N, No, Nu.

    Returns:
        (Ā (N, nz, nz), B̄ (N, nz, m), c̄ (N, nz), C̄ (p, nz), z0 (nz,)).
    """
    N, Nu = horizons.N, horizons.Nu
    C = np.asarray(C, float)
    n = C.shape[1]
    A = np.broadcast_to(np.asarray(A, float), (N, n, n))
    B = np.asarray(B, float)
    m = B.shape[-1]
    B = np.broadcast_to(B, (N, n, m))
    c = np.zeros((N, n)) if c is None or form == "nonlinear" else np.broadcast_to(np.asarray(c, float), (N, n))
    if form == "absolute" and Nu == N:
        return A.copy(), B.copy(), c.copy(), C, np.asarray(x0, float).copy()
    nz = n + m
    Ab, Bb, cb = np.zeros((N, nz, nz)), np.zeros((N, nz, m)), np.zeros((N, nz))
    Ab[:, :n, :n], cb[:, :n] = A, c
    held = np.arange(N) >= Nu if form == "absolute" else np.ones(N, bool)
    Ab[held, :n, n:] = B[held]
    Ab[held, n:, n:] = np.eye(m)
    if form != "incremental-delayed":
        Bb[:, :n] = B
    Bb[:, n:] = np.eye(m)
    z0 = np.zeros(nz)
    if form != "nonlinear":
        z0[:n] = x0
    if form in ("incremental", "incremental-delayed"):
        z0[n:] = u0
    return Ab, Bb, cb, np.hstack([C, np.zeros((C.shape[0], m))]), z0
