"""An independent oracle of the NMPC problem of :mod:`parallel_gpc.gpc.nmpc`: CasADi + IPOPT.

The discrete map Φ(X, u) = A_d(X) X + B_d(X) u + c_d(X) enters CasADi as an external
``casadi.Callback`` whose Jacobian is its own (five-point central differences in X, step 1e-3;
central differences in u, exact for a map affine in u) — not the library's Jacobians. The
problem is written from its definition (single shooting over v = Δu, u = u_sim⁰ + cumsum(v),
Qy-weighted outputs and Qu-weighted v), the input limits as linear constraints on u, an output box
as nonlinear constraints on the outputs of the rollout (a soft one with its own slack variables
and their exact penalty, as the library defines it), and solved by
IPOPT (limited-memory Hessian, tight tolerances). The benchmark benchmarks/bench_nmpc.py
runs the same formulation in closed loop (IPOPT and CasADi's SQP).
"""

from __future__ import annotations

import casadi as ca
import numpy as np


def _phi(model, Ts, x, u):
    Ad, Bd, cd = model.discrete(x, Ts)
    return Ad @ x + Bd @ u + cd


class _PhiJacobian(ca.Callback):
    def __init__(self, name, model, Ts, opts):
        ca.Callback.__init__(self)
        self.model, self.Ts = model, Ts
        self.n, self.m = model.n_x, model.n_u
        self.construct(name, opts)

    def get_n_in(self):
        return 3

    def get_n_out(self):
        return 2

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense((self.n, self.m, self.n)[i], 1)

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(self.n, (self.n, self.m)[i])

    def eval(self, arg):
        x, u = np.array(arg[0]).ravel(), np.array(arg[1]).ravel()
        f = lambda xx, uu: _phi(self.model, self.Ts, xx, uu)  # noqa: E731
        JX = np.empty((self.n, self.n))
        for k in range(self.n):
            h = 1e-3 * max(1.0, abs(x[k]))
            e = np.zeros(self.n)
            e[k] = h
            JX[:, k] = (-f(x + 2 * e, u) + 8 * f(x + e, u) - 8 * f(x - e, u) + f(x - 2 * e, u)) / (12 * h)
        JU = np.empty((self.n, self.m))
        for k in range(self.m):
            e = np.zeros(self.m)
            e[k] = 1.0
            JU[:, k] = (f(x, u + e) - f(x, u - e)) / 2.0
        return [ca.DM(JX), ca.DM(JU)]


class _Phi(ca.Callback):
    def __init__(self, name, model, Ts, opts=None):
        ca.Callback.__init__(self)
        self.model, self.Ts = model, Ts
        self.n, self.m = model.n_x, model.n_u
        self.construct(name, opts or {})

    def get_n_in(self):
        return 2

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense((self.n, self.m)[i], 1)

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(self.n, 1)

    def eval(self, arg):
        x, u = np.array(arg[0]).ravel(), np.array(arg[1]).ravel()
        return [ca.DM(_phi(self.model, self.Ts, x, u))]

    def has_jacobian(self):
        return True

    def get_jacobian(self, name, inames, onames, opts):
        self._jac = _PhiJacobian(name, self.model, self.Ts, opts)
        return self._jac


def ipopt_plan(model, Ts, X0, u0, w, Qy, Qu, N, No=0, torque=None, du=None, u_prev=None, disturbance=None,
               method="ipopt", max_iter=None, tol=1e-14, output_box=None, box_penalty=None):
    """The optimal v (Nu = N) of the NMPC problem by IPOPT (or CasADi's SQP, ``method="sqpmethod"``).

    Args:
        model: the reduced model; Ts: s; X0: (n_x,); u0: (N, m) u_sim⁰; w: (N − No, p) reference;
        Qy, Qu: scalar square-root weights; torque, du: scalars or (m,) (already tightened), or None;
        u_prev: (m,) u(k−1) for the du limit; disturbance: (n_x,) d or None.
        output_box: (p, 2) [lo, hi] per output (m, rad; ±inf: that side free) on the predicted
            outputs k+No+1..k+N, or None. box_penalty: None (a hard box) or ρ: the box is soft, one
            slack s ≥ 0 per output and step (lo − s ≤ y ≤ hi + s) costing ρ s + ρ·SOFT_QUADRATIC·s².
        method: "ipopt" (tight tolerances) or "sqpmethod" (qpOASES subproblems); max_iter: None
            (to convergence) or a cap (``1``: one SQP iteration); tol: IPOPT's tolerance (the
            oracle: 1e-14; the benchmark a control-rate 1e-8).

    Returns:
        (v (N·m,), J(v) (with the slack's penalty when soft), the solver's return status, its
        iteration count).
    """
    n, m = model.n_x, model.n_u
    phi = _Phi("phi", model, Ts)
    p = w.shape[1]
    n_s = (N - No) * p if output_box is not None and box_penalty is not None else 0
    V = ca.MX.sym("v", N * m + n_s)
    d = np.zeros(n) if disturbance is None else np.asarray(disturbance, dtype=float)
    x = ca.DM(X0)
    cost = 0
    us, ys = [], []
    acc = ca.DM.zeros(m)
    for i in range(N):
        acc = acc + V[i * m:(i + 1) * m]
        u = ca.DM(u0[i]) + acc
        us.append(u)
        x = phi(x, u) + ca.DM(d)
        if i + 1 > No:
            e = Qy * (x[:p] - ca.DM(w[i - No]))
            cost = cost + ca.dot(e, e)
            ys.append(x[:p])
    cost = cost + Qu ** 2 * ca.dot(V[:N * m], V[:N * m])
    S = V[N * m:]
    if n_s:
        from parallel_gpc.limits import SOFT_QUADRATIC
        cost = cost + box_penalty * ca.sum1(S) + box_penalty * SOFT_QUADRATIC * ca.dot(S, S)
    g, lbg, ubg = [], [], []
    if torque is not None:
        tau = np.broadcast_to(torque, (m,))
        for u in us:
            g.append(u)
            lbg += list(-tau)
            ubg += list(tau)
    if du is not None:
        delta = np.broadcast_to(du, (m,))
        prev = ca.DM(u_prev)
        for u in us:
            g.append(u - prev)
            lbg += list(-delta)
            ubg += list(delta)
            prev = u
    if output_box is not None:
        box = np.asarray(output_box, dtype=float)
        for j, y in enumerate(ys):
            s = S[j * p:(j + 1) * p] if n_s else 0
            for side, sign in ((0, -1.0), (1, 1.0)):  # sign·(y − bound) − s ≤ 0
                keep = np.isfinite(box[:, side])
                if keep.any():
                    rows = np.flatnonzero(keep).tolist()
                    g.append(sign * (y[rows] - ca.DM(box[rows, side])) - (s[rows] if n_s else 0))
                    lbg += [-np.inf] * len(rows)
                    ubg += [0.0] * len(rows)
    f0 = ca.Function("f", [V], [cost])
    scale = float(f0(np.zeros(N * m + n_s)))
    nlp = {"x": V, "f": cost / scale, "g": ca.vertcat(*g) if g else ca.MX(0, 1)}
    if method == "ipopt":
        opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.tol": tol, "ipopt.acceptable_iter": 0,
                "ipopt.hessian_approximation": "limited-memory", "ipopt.max_iter": max_iter or 3000,
                "ipopt.limited_memory_max_history": 50, "ipopt.bound_relax_factor": 0.0}
    else:
        opts = {"print_time": False, "print_header": False, "print_iteration": False, "print_status": False,
                "hessian_approximation": "limited-memory", "max_iter": max_iter or 200, "error_on_fail": False,
                "qpsol_options": {"printLevel": "none", "error_on_fail": False}}
    solver = ca.nlpsol("oracle", method, nlp, opts)
    sol = solver(x0=np.zeros(N * m + n_s), lbg=lbg, ubg=ubg, lbx=[-np.inf] * (N * m) + [0.0] * n_s)
    stats = solver.stats()
    return (np.array(sol["x"]).ravel()[:N * m], float(sol["f"]) * scale, stats["return_status"],
            int(stats.get("iter_count", 0)))
