"""The active set's acceptance when the gradient's terms cancel.

Near an equilibrium that the plan barely moves (a small input weight, the state on its reference), the
costates ν are what is left of q + Q z after five or more digits cancel, and R v and Bᵀν are tiny: the
free components' gradient R v + Bᵀν is then rounding of terms many orders larger than the gradient's own
scale. A settled set is accepted when that gradient is within ``AS_ROUNDING`` of its terms
(:func:`~parallel_gpc.solvers.stagewise_active._terms_scale`), in the Python reference and the compiled
solve alike, and the plan is the equality-constrained optimum (no row active) solved densely here.
"""

from __future__ import annotations

import numpy as np
import pytest

import parallel_gpc.solvers.stagewise_active as active_module
from parallel_gpc.model.native import native_module
from parallel_gpc.solvers import AS_MAX_ITER, StageQP, input_rows_of

HAS_COMPILED = native_module() is not None and hasattr(native_module(), "stagewise_active")


def _near_equilibrium(seed: int, N: int = 60, nz: int = 4, m: int = 2) -> StageQP:
    """Input rows far from binding (|v_j| ≤ 1e3), z = z_r an equilibrium with v = 0 and the costs' minimum
    (q = −Q z_r), the start 1e-6 off it, R = 2e-8 I: the plan's v ~1e-4, ν ~1e-6 from terms ~1."""
    rng = np.random.default_rng(seed)
    A = np.eye(nz) + 0.01 * rng.standard_normal((N, nz, nz))
    B = 1e-2 * rng.standard_normal((N, nz, m))
    z_r = 0.5 + rng.random(nz)
    c = np.array([z_r - A[i] @ z_r for i in range(N)])
    Q, q = np.array([np.eye(nz)] * (N + 1)), np.tile(-z_r, (N + 1, 1))
    Fz, Fv = np.zeros((N, 2 * m, nz)), np.zeros((N, 2 * m, m))
    for j in range(m):
        Fv[:, j, j], Fv[:, m + j, j] = 1.0, -1.0
    return StageQP(A, B, c, z_r + 1e-6 * rng.standard_normal(nz), Q, q, 2e-8 * np.eye(m), N, Fz, Fv,
                   np.full((N, 2 * m), 1e3), np.zeros((N, 2 * m), bool), 5.0, 0.1)


def _equality_optimum(qp: StageQP) -> np.ndarray:
    """v (N, m) minimizing Σ ½ zᵀQz + qᵀz (i = 1..N) + ½ vᵀRv subject to the dynamics: one dense KKT system."""
    N, nz, m = qp.A.shape[0], qp.A.shape[1], qp.R.shape[0]
    nx, nv = N * nz, N * m
    H = np.zeros((nx + nv, nx + nv))
    g = np.zeros(nx + nv)
    for i in range(N):
        H[i * nz:(i + 1) * nz, i * nz:(i + 1) * nz] = qp.Q[i + 1]
        g[i * nz:(i + 1) * nz] = qp.q[i + 1]
        H[nx + i * m:nx + (i + 1) * m, nx + i * m:nx + (i + 1) * m] = qp.R
    E = np.zeros((nx, nx + nv))
    b = np.zeros(nx)
    for i in range(N):  # z(i+1) − A z(i) − B v(i) = c(i)
        E[i * nz:(i + 1) * nz, i * nz:(i + 1) * nz] = np.eye(nz)
        if i:
            E[i * nz:(i + 1) * nz, (i - 1) * nz:i * nz] = -qp.A[i]
        E[i * nz:(i + 1) * nz, nx + i * m:nx + (i + 1) * m] = -qp.B[i]
        b[i * nz:(i + 1) * nz] = qp.c[i] + (qp.A[0] @ qp.z0 if i == 0 else 0.0)
    K = np.block([[H, E.T], [E, np.zeros((nx, nx))]])
    sol = np.linalg.solve(K, np.concatenate([-g, b]))
    return sol[nx:nx + nv].reshape(N, m)


@pytest.mark.parametrize("seed", [0, 3, 4])
def test_a_gradient_at_rounding_of_its_terms_is_accepted(seed, monkeypatch):
    qp = _near_equilibrium(seed)
    rows = input_rows_of(qp)
    v_ref = _equality_optimum(qp)
    with monkeypatch.context() as patch:  # relative to the gradient's own scale alone: rejected
        patch.setattr(active_module, "AS_ROUNDING", 0.0)
        assert active_module.solve_active_set(qp, rows).status == "unconverged"
    sol = active_module.solve_active_set(qp, rows)
    assert sol.status == "optimal" and sol.residual <= 1e-6
    assert np.abs(sol.v - v_ref).max() <= 1e-7 * np.abs(v_ref).max()
    if HAS_COMPILED:
        c = np.ascontiguousarray
        v, z, lam, fixed, iterations, ok, residual, message = native_module().stagewise_active(
            c(qp.A), c(qp.B), c(qp.c), c(qp.z0), c(qp.Q), c(qp.q), c(qp.R), qp.n_decide, c(qp.Fz), c(qp.f),
            c(rows.comp, np.int64), c(rows.sign), None, AS_MAX_ITER)
        assert ok and residual <= 1e-6, message
        assert np.abs(v - v_ref).max() <= 1e-7 * np.abs(v_ref).max()
