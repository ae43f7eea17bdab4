"""The LTV MPC problem of the benchmark in the ``qpmpc`` package's terms, and a peer that solves
it with ``qpmpc.solve_mpc`` (the comparison rows of :mod:`parallel_gpc.bench.harness`)."""

from __future__ import annotations

import numpy as np

#: velocity coordinates are scaled by this in the qpmpc problem: qpmpc weighs the whole state
#: with one scalar, our criterion only the pose; the scaled velocities weigh ε² = 1e-12.
QPMPC_VELOCITY_SCALE = 1e-6


class QpmpcPeer:
    """The LTV MPC problem in the ``qpmpc`` package's terms (see :func:`qpmpc_problem`)."""

    def __init__(self, solver: str):
        import qpmpc  # noqa: F401

        self.solver = solver
        self.name = f"qpmpc:{solver}"

    def solve(self, problem) -> np.ndarray | None:
        from qpmpc import solve_mpc

        plan = solve_mpc(problem, solver=self.solver, **({"eps_abs": 1e-10, "eps_rel": 0.0}
                                                           if self.solver == "proxqp" else {}))
        return None if plan.is_empty else plan.inputs.reshape(-1)


def qpmpc_problem(A_seq, B_seq, c_seq, X0, w, wdot, w0, tau, qu, scale=1.0):
    """Our absolute LTV problem as a ``qpmpc.MPCProblem``.

    qpmpc's model has no affine term and one scalar weight per cost: the state becomes
    x' = S [X; 1] with S = diag(I, ε I, 1) (the constant 1 carries c_i; velocities scaled by
    ε = :data:`QPMPC_VELOCITY_SCALE` so that their error weighs ε²), stage + terminal weight κ on
    x'(1..N) against [w; ε ẇ; 1], input weight κ·Qu², and the box ±τ as D u ≤ e. κ = ``scale``
    multiplies the whole cost (same minimizer): qpmpc does not scale its QP, so the caller picks
    κ ≈ 1/max diag(GᵀG) as a user tuning it once would (our back ends scale every QP).
    """
    from qpmpc import MPCProblem

    N, n, m = B_seq.shape
    ny = n // 2
    s = np.concatenate([np.ones(ny), np.full(ny, QPMPC_VELOCITY_SCALE), [1.0]])
    A_list, B_list = [], []
    for i in range(N):
        At = np.zeros((n + 1, n + 1))
        At[:n, :n] = A_seq[i]
        At[:n, n] = c_seq[i]
        At[n, n] = 1.0
        A_list.append(s[:, None] * At / s[None, :])
        B_list.append(s[:, None] * np.vstack([B_seq[i], np.zeros((1, m))]))
    targets = np.hstack([np.vstack([w0, w[:-1]]), np.vstack([np.zeros(ny), wdot[:-1]]), np.ones((N, 1))]) * s
    goal = np.concatenate([w[-1], wdot[-1], [1.0]]) * s
    D = np.vstack([np.eye(m), -np.eye(m)])
    e = np.concatenate([tau, tau])
    return MPCProblem(
        transition_state_matrix=A_list, transition_input_matrix=B_list, ineq_state_matrix=None,
        ineq_input_matrix=D, ineq_vector=e, nb_timesteps=N, terminal_cost_weight=scale,
        stage_state_cost_weight=scale, stage_input_cost_weight=scale * qu * qu,
        initial_state=np.append(X0, 1.0) * s, goal_state=goal, target_states=targets.reshape(-1),
    )
