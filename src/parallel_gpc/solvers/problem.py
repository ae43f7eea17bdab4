"""Least-squares problem and solve result shared by every back end (the square-root form of eq. (15)–(16))."""

from __future__ import annotations

import contextlib
import io

import numpy as np
from dataclasses import dataclass, field

from ..errors import InvalidParameterError

#: relative pivot size below which a column of A counts as dependent (rank-revealing QR).
RANK_RTOL = 1e-10
#: relative Tikhonov term added to the scaled QP Hessian (approximates the min-norm solution).
QP_REGULARIZATION = 1e-10
#: feasibility tolerance (N·m, relative to the limit) when checking limits.
LIMIT_TOL = 1e-7
#: reciprocal condition (estimate, 1-norm) of the unpivoted triangular factor above which the
#: fast QR path trusts full rank; below it the rank-revealing (pivoted) path decides.
FAST_QR_RCOND = 1e-8
#: a bound of this magnitude or more is no bound (the free side of a one-sided row; a slack's upper bound).
UNBOUNDED = 1e20

@dataclass(frozen=True)
class MinNormOf:
    """Which minimizer a rank-deficient problem returns: the one with the smallest ‖M v + offset‖.

    Attributes:
        M: (n, n) lower-triangular invertible matrix.
        offset: (n,) vector.
        block: when M is the cumulative-sum map kron(tri(n/block), I_block), its block size
            (the QR back end then applies M⁻¹ as block differences); None for a general M.
    """

    M: np.ndarray
    offset: np.ndarray
    block: int | None = None


@dataclass
class LeastSquaresProblem:
    """``min ‖A v − b‖² + cᵀv`` subject to ``lb ≤ v ≤ ub`` and ``lo ≤ L v ≤ hi`` (either may be None).

    Attributes:
        A: (r, n); b: (r,); lb, ub: (n,) or None; L: (k, n) or None; lo, hi: (k,) or None
            (±:data:`UNBOUNDED` or beyond: that side free).
        c: (n,) linear cost term or None (the exact L1 penalty of slack variables; only the QP
            back ends take it).
        n_slack: the last ``n_slack`` entries of v are slack variables s ≥ 0 of soft limits
            (:func:`with_inequalities`); the decision variables proper are the first n − n_slack.
        slack_unit: (n_slack,) what one unit of each slack variable is in its limit's unit
            (violation = slack · slack_unit), or None.
        base: the problem before :func:`with_inequalities` added rows (its unconstrained
            minimizer, with zero slack, solves this one whenever it keeps every row), or None.
        min_norm_of: when A is rank-deficient, the QR back end returns the minimizer with the
            smallest ‖M v + offset‖ (see :class:`MinNormOf`); None: the smallest ‖v‖.
        nonzero_rows: number of leading rows of A (and b) that can be nonzero; the rows below
            are zero and the back ends skip them. None: all rows.
        tail_diag: (n,) when the last n rows are ``[diag(tail_diag) | b = 0]`` (a diagonal
            regularization block), else None.
        tail_positive: True when ``tail_diag`` is given and all its entries are > 0 (A then
            has full column rank: one minimizer).
    """

    A: np.ndarray
    b: np.ndarray
    lb: np.ndarray | None = None
    ub: np.ndarray | None = None
    L: np.ndarray | None = None
    lo: np.ndarray | None = None
    hi: np.ndarray | None = None
    min_norm_of: MinNormOf | None = None
    nonzero_rows: int | None = None
    tail_diag: np.ndarray | None = field(default=None, repr=False)
    tail_positive: bool = False
    c: np.ndarray | None = None
    n_slack: int = 0
    slack_unit: np.ndarray | None = field(default=None, repr=False)
    base: "LeastSquaresProblem | None" = field(default=None, repr=False)

    def leading_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """(A, b) without the rows known to be zero (views, no copy)."""
        if self.nonzero_rows is not None and self.nonzero_rows < self.A.shape[0]:
            return self.A[:self.nonzero_rows], self.b[:self.nonzero_rows]
        return self.A, self.b

    @property
    def n(self) -> int:
        return self.A.shape[1]

    @property
    def constrained(self) -> bool:
        return self.lb is not None or self.L is not None

    @property
    def n_decision(self) -> int:
        """The number of decision variables proper (without the slack variables)."""
        return self.A.shape[1] - self.n_slack

    def cost(self, v: np.ndarray) -> float:
        """‖A v − b‖² + cᵀv at v (n,)."""
        r = self.A @ v - self.b
        return float(r @ r) + (0.0 if self.c is None else float(self.c @ v))

    def violation(self, v: np.ndarray) -> float:
        """Largest limit violation of v (0 when feasible), in the units of the limits."""
        worst = 0.0
        if self.lb is not None:
            worst = max(worst, float(np.max(self.lb - v, initial=0)), float(np.max(v - self.ub, initial=0)))
        if self.L is not None:
            Lv = self.L @ v
            worst = max(worst, float(np.max(self.lo - Lv, initial=0)), float(np.max(Lv - self.hi, initial=0)))
        return worst

    def feasible(self, v: np.ndarray) -> bool:
        """True when v keeps every limit within :data:`LIMIT_TOL` (relative to the largest bound; rows
        added by :func:`with_inequalities` each relative to its own bound, and slack ≥ 0)."""
        if self.base is not None:
            n, k = self.base.n, 0 if self.base.L is None else self.base.L.shape[0]
            Lv = self.L[k:] @ v
            return (self.base.feasible(v[:n]) and bool(np.all(v[n:] >= 0.0))
                    and bool(np.all(Lv - self.hi[k:] <= LIMIT_TOL * (1.0 + np.abs(self.hi[k:]))))
                    and bool(np.all(self.lo[k:] - Lv <= LIMIT_TOL * (1.0 + np.abs(self.lo[k:])))))
        scale = 1.0
        for arr in (self.ub, self.hi):
            finite = None if arr is None else np.abs(arr[np.abs(arr) < UNBOUNDED])
            if finite is not None and finite.size:
                scale = max(scale, float(np.max(finite)))
        return self.violation(v) <= LIMIT_TOL * scale

    def active(self, v: np.ndarray, tol: float = 1e-6) -> bool:
        """True when a limit is (nearly) active at v (a slack variable at 0 is no active limit)."""
        n = self.n_decision
        if self.lb is not None:
            lb, ub, x = self.lb[:n], self.ub[:n], v[:n]
            if np.any(x - lb <= tol * (1 + np.abs(lb))) or np.any(ub - x <= tol * (1 + np.abs(ub))):
                return True
        if self.L is not None:
            Lv = self.L @ v
            return bool(np.any(Lv - self.lo <= tol * (1 + np.abs(self.lo))) or
                        np.any(self.hi - Lv <= tol * (1 + np.abs(self.hi))))
        return False


def with_inequalities(problem: LeastSquaresProblem, G: np.ndarray, h: np.ndarray, slack_of: np.ndarray,
                      penalty: float, quadratic: float) -> LeastSquaresProblem:
    """``problem`` with the one-sided rows ``G v ≤ h`` added, some of them soft.

    A row with ``slack_of[i] = j ≥ 0`` is soft: ``G_i v − s_j ≤ h_i`` with a slack s_j ≥ 0 (rows
    may share one: the two sides of a range never both bind) costing ``penalty``·s_j (the exact
    L1 penalty: s = 0 whenever the hard problem is feasible and ``penalty`` exceeds the row's
    Lagrange multiplier) plus ``quadratic``·s_j² (the slack's Hessian, > 0). A row with
    ``slack_of[i] = −1`` is hard. The slack variables are new last columns, each in the unit of
    its row divided by the row's norm (``slack_unit``); the problem's
    structure hints (a diagonal regularization tail) are kept. Each row is divided by its norm in
    v (the same inequality, equilibrated).

    Args:
        problem: the problem in v (no slack yet), n columns.
        G: (k, n); h: (k,) finite. slack_of: (k,) int, −1 or a slack index 0..n_s−1.
        penalty: ρ > 0 (cost per unit of violation). quadratic: ε > 0 (cost per unit²).

    Returns:
        A new problem in x = [v; s], (n + n_s) columns.
    """
    if problem.n_slack:
        raise InvalidParameterError("the problem has slack variables already: add all inequalities at once")
    n = problem.n
    slack_of = np.asarray(slack_of, dtype=int)
    ns = int(slack_of.max(initial=-1)) + 1
    G = np.asarray(G, dtype=float)
    norm = np.linalg.norm(G, axis=1)
    norm[norm == 0.0] = 1.0
    # rows of unit norm in v: a solver's feasibility tolerance then means the same for every row;
    # slack j measured in the same unit, t_j = s_j / ‖G_i‖ (rows sharing a slack have one norm):
    # its Hessian ε‖G_i‖² then sits beside the criterion's, not 10¹³ away
    unit = np.ones(ns)
    soft = slack_of >= 0
    unit[slack_of[soft]] = norm[soft]
    top = problem.A.shape[0] - n if problem.tail_diag is not None else problem.A.shape[0]
    rows = problem.A.shape[0] + (ns if problem.tail_diag is None else 0)
    A = np.zeros((rows + (0 if problem.tail_diag is None else ns), n + ns))
    b = np.zeros(A.shape[0])
    A[:problem.A.shape[0], :n] = problem.A
    b[:problem.b.shape[0]] = problem.b
    root = np.sqrt(quadratic) * unit
    tail = None
    if problem.tail_diag is not None:  # [A_top; diag(d)] → [A_top 0; diag(d, √ε)]: still a diagonal tail
        A[top:top + n, :n] = 0.0
        tail = np.concatenate([problem.tail_diag, root])
        A[top:, :] = np.diag(tail)
    else:
        A[problem.A.shape[0]:, n:] = np.diag(root)
    L_slack = np.zeros((len(h), ns))
    L_slack[np.flatnonzero(soft), slack_of[soft]] = -norm[soft]
    L_new = np.hstack([G, L_slack]) / norm[:, None]
    h = np.asarray(h, dtype=float) / norm
    Ls, los, his = [], [], []
    if problem.L is not None:
        Ls.append(np.hstack([problem.L, np.zeros((problem.L.shape[0], ns))]))
        los.append(problem.lo)
        his.append(problem.hi)
    Ls.append(L_new)
    los.append(np.full(len(h), -UNBOUNDED))
    his.append(np.asarray(h, dtype=float))
    lb = ub = None
    if problem.lb is not None or ns:  # the slack variables' s ≥ 0 (v unbounded unless it had a box)
        lb = np.full(n + ns, -UNBOUNDED) if problem.lb is None else np.concatenate([problem.lb, np.zeros(ns)])
        ub = np.full(n + ns, UNBOUNDED) if problem.ub is None else np.concatenate([problem.ub, np.full(ns, UNBOUNDED)])
        lb[n:] = 0.0
    c = np.zeros(n + ns)
    if problem.c is not None:
        c[:n] = problem.c
    c[n:] = penalty * unit
    return LeastSquaresProblem(A, b, lb, ub, np.vstack(Ls), np.concatenate(los), np.concatenate(his),
                               min_norm_of=None, nonzero_rows=None, tail_diag=tail,
                               tail_positive=problem.tail_positive and quadratic > 0, c=c, n_slack=ns,
                               slack_unit=unit, base=problem)


def with_equalities(problem: LeastSquaresProblem, E: np.ndarray, e: np.ndarray) -> LeastSquaresProblem:
    """``problem`` with the hard equality rows ``E v = e`` added (rows of L with lo = hi), each
    divided by its norm in v.

    Args:
        problem: the problem in x = [v; s] (slack columns, if any, get zero coefficients).
        E: (k, n_decision); e: (k,) finite.

    Returns:
        A new problem with the same columns; its ``base`` is the problem before any row was added.
    """
    E = np.asarray(E, dtype=float)
    n, nd = problem.n, problem.n_decision
    if E.ndim != 2 or E.shape[1] != nd:
        raise InvalidParameterError(f"equality rows have shape {E.shape}; expected (k, {nd})")
    norm = np.linalg.norm(E, axis=1)
    norm[norm == 0.0] = 1.0
    rows = np.zeros((E.shape[0], n))
    rows[:, :nd] = E / norm[:, None]
    e = np.asarray(e, dtype=float) / norm
    L = rows if problem.L is None else np.vstack([problem.L, rows])
    lo = e if problem.lo is None else np.concatenate([problem.lo, e])
    hi = e.copy() if problem.hi is None else np.concatenate([problem.hi, e])
    base = problem.base if problem.base is not None else problem
    return LeastSquaresProblem(problem.A, problem.b, problem.lb, problem.ub, L, lo, hi,
                               min_norm_of=problem.min_norm_of if problem.base is None else None,
                               nonzero_rows=problem.nonzero_rows, tail_diag=problem.tail_diag,
                               tail_positive=problem.tail_positive, c=problem.c, n_slack=problem.n_slack,
                               slack_unit=problem.slack_unit, base=base)


def refuse_limits(solver: str, problem: LeastSquaresProblem) -> None:
    """Raise when an unconstrained back end (``qr``, ``cholesky``) is handed a problem with limits:
    its answer would be "unconstrained" while breaking them.

    Raises:
        InvalidParameterError: naming the back end and what enforces limits instead.
    """
    if problem.constrained or problem.c is not None:
        raise InvalidParameterError(
            f"solver {solver!r} cannot enforce the problem's limits (it would ignore them); use a QP back end such "
            "as 'qr-first:daqp-direct', 'daqp-direct' or 'bvls' (box limits), or drop the limits")


def cumulative_block(problem: LeastSquaresProblem) -> int | None:
    """m when the problem's only limits are ``lo ≤ M v ≤ hi`` with M = kron(tri, I_m) square
    (the incremental forms' torque limit over the control horizon: a box on s = M v), else None."""
    mn, L = problem.min_norm_of, problem.L
    if L is None or problem.lb is not None or mn is None or not mn.block or L.shape != (problem.n, problem.n):
        return None
    M = mn.M
    same = L is M or M.base is L or (L.base is not None and L.base is M.base) or np.array_equal(L, M)
    return mn.block if same else None


def from_cumulative(s: np.ndarray, m: int) -> np.ndarray:
    """v = M⁻¹ s for M = kron(tri, I_m): block differences (a new array)."""
    v = np.array(s, dtype=float)
    v[m:] -= v[:-m].copy()
    return v


# ---------------------------------------------------------------------------- results
@dataclass
class SolveResult:
    """Outcome of one least-squares / QP solve.

    Attributes:
        v: (n,) solution (N·m or N·m per sample); NaN-free whenever ``ok``.
        cost: J = ‖A v − b‖² at v.
        status: ``"optimal"`` (a QP back end's solution that passed the KKT check of
            :mod:`parallel_gpc.solvers.kkt`), ``"unconstrained"`` (QR, limits inactive or absent),
            ``"inaccurate"`` (a back end's solution that failed the KKT check),
            ``"infeasible"``, ``"failed"`` or ``"fallback"`` (set by the controller).
        solver: back-end name.
        iterations: solver iterations (None if the back end does not report them).
        solve_time: wall time of the solve in s.
        active_limits: True when a limit is active at v.
        message: details (e.g. the solver's own status text).
    """

    v: np.ndarray
    cost: float
    status: str
    solver: str
    iterations: int | None = None
    solve_time: float = 0.0
    active_limits: bool = False
    message: str = ""

    @property
    def ok(self) -> bool:
        return self.status in ("optimal", "unconstrained")


# ---------------------------------------------------------------------------- QP
def scaled_qp(problem: LeastSquaresProblem):
    """Hessian P = AᵀA and gradient q = −Aᵀb scaled to max(diag P) = 1, plus a tiny ridge."""
    A, b = problem.leading_rows()
    tail = None
    if A.shape[0] == problem.A.shape[0] and problem.tail_diag is not None:
        # A = [A_top; diag(d)], b = [b_top; 0]: P = A_topᵀ A_top + diag(d²)
        top = A.shape[0] - A.shape[1]
        A, b, tail = A[:top], b[:top], problem.tail_diag
    P = A.T @ A
    q = A.T @ b
    diag = P.reshape(-1)[::P.shape[0] + 1]  # a view on the diagonal of P
    if tail is not None:
        diag += tail * tail
    # the scale of the decision variables proper: slack columns leave the rest of the QP as it was
    scale = 1.0 / max(float(diag[:problem.n_decision].max(initial=0.0)), 1e-300)
    P *= scale
    diag += QP_REGULARIZATION
    q *= -scale
    if problem.c is not None:  # ‖A v − b‖² + cᵀv: gradient −2Aᵀb + c, halved with P = AᵀA
        q += 0.5 * scale * problem.c
    return P, q, scale


def failed_result(problem: LeastSquaresProblem, name: str, kind: str, iterations, dt: float, message: str) -> SolveResult:
    """A reported failure: NaN solution, infinite cost, status ``kind`` (never swallowed)."""
    return SolveResult(np.full(problem.n, np.nan), np.inf, kind, name, iterations, dt, message=message)


def iterations_from_extras(extras) -> int | None:
    info = extras.get("info") if isinstance(extras, dict) else None
    for attr in ("iter", "iterations"):
        if info is not None and hasattr(info, attr):
            return int(getattr(info, attr))
    if isinstance(extras, dict) and "iterations" in extras:
        return int(extras["iterations"])
    return None


def stacked_constraints(problem: LeastSquaresProblem):
    """All limits as lo ≤ C v ≤ hi (box rows first), with ±1e20 where unbounded."""
    rows, lo, hi = [], [], []
    if problem.lb is not None:
        rows.append(np.eye(problem.n))
        lo.append(problem.lb)
        hi.append(problem.ub)
    if problem.L is not None:
        rows.append(problem.L)
        lo.append(problem.lo)
        hi.append(problem.hi)
    if not rows:
        return np.zeros((0, problem.n)), np.zeros(0), np.zeros(0)
    C, lo, hi = np.vstack(rows), np.concatenate(lo), np.concatenate(hi)
    free = (lo <= -UNBOUNDED) & (hi >= UNBOUNDED)
    if free.any():  # rows bounding nothing (the box of v beside slack variables): left out
        C, lo, hi = C[~free], lo[~free], hi[~free]
    # a free side as ±inf (ProxQP and OSQP take it; a finite 1e20 upsets their infeasibility detection)
    return C, np.where(lo <= -UNBOUNDED, -np.inf, lo), np.where(hi >= UNBOUNDED, np.inf, hi)




class _Discard(io.TextIOBase):
    """A text stream that drops what is written."""

    def write(self, text: str) -> int:
        return len(text)


_DISCARD = _Discard()


def quiet_stdout():
    """Context manager: Python-level stdout dropped (a back end's prints during a solve)."""
    return contextlib.redirect_stdout(_DISCARD)


class PersistentQPBackend:
    """Shared part of the persistent QP back ends (OSQP, ProxQP): tolerance, iteration limit and
    the dense scaled QP of a problem with the shapes that decide whether a fresh setup is needed.

    Args:
        eps: absolute tolerance of the solver (in the scaled QP's units).
        max_iter: iteration limit of one solve.
    """

    def __init__(self, eps: float, max_iter: int):
        self.eps, self.max_iter = eps, max_iter
        self._shape = None

    @staticmethod
    def dense_qp(problem: LeastSquaresProblem):
        """(P, q, C, lo, hi, shape): scaled Hessian and gradient, stacked limits ``lo ≤ C v ≤ hi``
        and the (P, C) shapes that identify the problem structure."""
        P, q, _ = scaled_qp(problem)
        C, lo, hi = stacked_constraints(problem)
        return P, q, C, lo, hi, (P.shape, C.shape)

