"""The compiled active set's block products on stages with a held input, against the Python reference.

On a stage whose model is Ā = [[X, Y], [0, I]], B̄ = [[W], [I]] (the held input of the incremental,
delayed and nonlinear forms), the compiled sweep, forward pass and multipliers of the fixed stage
sizes (nz = 10, m = 4: planar_4rrr's incremental stage) leave out the zero blocks and add the
identity's terms (``Held`` in native/src/stagewise_active.cpp); on any other stage they multiply the
full matrices. A random problem of that size with the structure on most stages and broken on a few
(one entry of the zero block, of Ā's identity, of B̄'s identity) must give the Python reference's
sets, sweeps, plan, states and multipliers: a stage taken for held that is not one changes the plan
by the broken entry's effect (1e-2 here), far above the 1e-9 compared.
"""

from __future__ import annotations

import numpy as np
import pytest

from parallel_gpc.model.native import native_module
from parallel_gpc.solvers import AS_MAX_ITER, AS_WARM_MAX_ITER, StageQP, input_rows_of, solve_active_set

HAS_COMPILED = native_module() is not None and hasattr(native_module(), "stagewise_active")
NX, M = 6, 4  # the fixed-size stage of the compiled sweep: nz = 10, m = 4


def _held_qp(seed: int, broken: dict[int, str]) -> StageQP:
    """A random LQ problem of N = 14 stages (12 deciding) with torque rows on the held input plus v
    (|z[nx:] + v| ≤ f) binding along the horizon; ``broken``: stage → which block of the held
    structure that stage's model breaks ("zero": Ā's bottom-left, "A": Ā's identity, "B": B̄'s)."""
    rng = np.random.default_rng(seed)
    N, nd, nz = 14, 12, NX + M
    A = np.zeros((N, nz, nz))
    A[:, :NX, :NX] = np.eye(NX) + 0.05 * rng.standard_normal((N, NX, NX))
    A[:, :NX, NX:] = 0.3 * rng.standard_normal((N, NX, M))
    A[:, NX:, NX:] = np.eye(M)
    B = np.zeros((N, nz, M))
    B[:, :NX] = A[:, :NX, NX:]
    B[:, NX:] = np.eye(M)
    for i, block in broken.items():
        if block == "zero":
            A[i, NX + 1, 2] = 1e-2
        elif block == "A":
            A[i, NX + 2, NX + 2] = 1.01
        else:
            B[i, NX + 3, 1] = 1e-2
    c = np.zeros((N, nz))
    c[:, :NX] = 0.01 * rng.standard_normal((N, NX))
    Cm = rng.standard_normal((NX, nz))
    Q = np.array([Cm.T @ Cm] * (N + 1))
    q = 4.0 * rng.standard_normal((N + 1, nz))
    k = 2 * M
    I = np.eye(M)
    Fz, Fv, f = np.zeros((N, k, nz)), np.zeros((N, k, M)), np.full((N, k), np.inf)
    Fv[:nd] = np.concatenate([I, -I])
    Fz[:nd, :, NX:] = np.concatenate([I, -I])
    f[:nd] = 0.3 + 0.1 * rng.random((nd, k))
    z0 = 0.1 * rng.standard_normal(nz)
    return StageQP(A, B, c, z0, Q, q, 1e-2 * np.eye(M), nd, Fz, Fv, f, np.zeros((N, k), bool))


@pytest.mark.skipif(not HAS_COMPILED, reason="the compiled core has no stagewise_active")
@pytest.mark.parametrize("broken", [{}, {3: "zero"}, {5: "A", 9: "B"}, {0: "B", 11: "zero", 13: "A"}])
@pytest.mark.parametrize("seed", [0, 1])
def test_held_stages_give_the_python_references_solution(seed, broken):
    """Cold (a sweep per change of the set) and from the solution's set: the same sets and sweeps, plan, states and multipliers
    ≤ 1e-9 relative; the rows bind on several stages (the fixed components' terms are exercised)."""
    qp = _held_qp(seed, broken)
    rows = input_rows_of(qp)
    c = np.ascontiguousarray
    cold = solve_active_set(qp, rows)
    assert cold.status == "optimal" and 3 <= (cold.fixed >= 0).sum() < cold.fixed.size
    for start in (None, cold.fixed):
        py = solve_active_set(qp, rows, start)
        v, z, lam, fixed, iterations, ok, residual, message = native_module().stagewise_active(
            c(qp.A), c(qp.B), c(qp.c), c(qp.z0), c(qp.Q), c(qp.q), c(qp.R), qp.n_decide, c(qp.Fz), c(qp.f),
            c(rows.comp, np.int64), c(rows.sign), None if start is None else c(start, np.int64),
            AS_MAX_ITER if start is None else AS_WARM_MAX_ITER)
        assert ok and py.status == "optimal" and iterations == py.iterations, (message, py.message)
        np.testing.assert_array_equal(fixed, py.fixed)
        for got, ref in ((v, py.v), (z, py.z), (lam, py.lam)):
            assert np.abs(got - ref).max() <= 1e-9 * max(1.0, np.abs(ref).max())
