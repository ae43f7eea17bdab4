"""Square-root least squares of the GPC criterion and its QP back ends (DESIGN §3, §5).

The criterion (5) with square-root weights is ``J = ‖A v − b‖²`` with, eq. (15)–(16),

    A = [Qy·G; Qu],   b = [Qy·(w − f); 0].

* :class:`QRSolver` — the reference: Householder QR and back substitution, eq. (17)–(19)
  (the paper's (19) prints (R₁)ᵀ; it means R₁⁻¹). ``‖c_z‖² = J``. When A is rank-deficient
  (Qu = 0 with redundant drives) it returns the minimum-norm solution through a complete
  orthogonal decomposition — exactly "no drive fighting".
* :class:`QpsolversBackend` — ``qpsolvers.solve_qp`` for any installed solver, scaled, with
  drive torque limits (box on v, or linear inequalities ``u_lo ≤ u_base + L v ≤ u_hi``).
* :class:`OSQPBackend`, :class:`ProxQPBackend`, :class:`DAQPBackend` — persistent direct APIs
  (set up once, updated and warm-started every step).
* :class:`QRFirst` — solves by QR and calls the QP only when the QR solution violates a limit.

Every solve returns a :class:`SolveResult` (status, iterations, time, cost, active limits); a
failed solve is reported in the result, never swallowed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
from scipy.linalg import lapack

from .errors import InfeasibleLimitsError, InvalidParameterError, ShapeError, SolverNotFoundError
from .prediction import Prediction

#: relative pivot size below which a column of A counts as dependent (rank-revealing QR).
RANK_RTOL = 1e-10
#: relative Tikhonov term added to the scaled QP Hessian (approximates the min-norm solution).
QP_REGULARIZATION = 1e-10
#: feasibility tolerance (N·m, relative to the limit) when checking limits.
LIMIT_TOL = 1e-7
#: reciprocal condition (estimate, 1-norm) of the unpivoted triangular factor above which the
#: fast QR path trusts full rank; below it the rank-revealing (pivoted) path decides.
FAST_QR_RCOND = 1e-8


# ---------------------------------------------------------------------------- weights
def _weight_block(name: str, value, size: int) -> np.ndarray:
    """Square-root weight as a (size, size) matrix from a scalar, a (size,) vector or a matrix."""
    arr = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise InvalidParameterError(f"weight {name} = {value!r} contains NaN or inf; it must be finite")
    if arr.ndim == 0:
        arr = np.full(size, float(arr))
    if arr.ndim == 1:
        if arr.shape != (size,):
            raise ShapeError(f"weight {name} has shape {arr.shape}; expected a scalar, ({size},) or ({size}, {size})")
        if np.any(arr < 0):
            raise InvalidParameterError(f"weight {name} = {arr.tolist()} has negative entries; weights must be ≥ 0")
        return np.diag(arr)
    if arr.shape != (size, size):
        raise ShapeError(f"weight {name} has shape {arr.shape}; expected a scalar, ({size},) or ({size}, {size})")
    if not np.allclose(arr, arr.T, atol=1e-12 * max(1.0, np.abs(arr).max())) or np.linalg.eigvalsh(
        0.5 * (arr + arr.T)).min() < -1e-12 * max(1.0, np.abs(arr).max()):
        raise InvalidParameterError(
            f"weight {name} must be a symmetric positive semi-definite matrix; eigenvalues are "
            f"{np.round(np.linalg.eigvals(arr), 6).tolist()}"
        )
    return arr


@dataclass(frozen=True)
class Weights:
    """Square-root weights of the criterion (5): J = Σ‖Qy (ŷ − w)‖² + Σ‖Qu v‖².

    Attributes:
        Qy: output weight: scalar, (p,) per channel, or (p, p) symmetric PSD matrix.
        Qu: input (absolute form) or increment (incremental forms) weight, same forms, (m,).
    """

    Qy: object = 1.0
    Qu: object = 0.0

    def blocks(self, p: int, m: int) -> tuple[np.ndarray, np.ndarray]:
        """(p, p) and (m, m) square-root weight matrices (validated)."""
        return _weight_block("Qy", self.Qy, p), _weight_block("Qu", self.Qu, m)


# ---------------------------------------------------------------------------- problem
@dataclass
class LeastSquaresProblem:
    """``min ‖A v − b‖²`` subject to ``lb ≤ v ≤ ub`` and ``lo ≤ L v ≤ hi`` (either may be None).

    Attributes:
        A: (r, n); b: (r,); lb, ub: (n,) or None; L: (k, n) or None; lo, hi: (k,) or None.
        min_norm_of: (M, m0) with M (n, n) lower-triangular invertible: when A is
            rank-deficient, the QR back end returns the minimizer with the smallest ‖M v + m0‖
            (incremental forms: the smallest absolute drive torques u, not the smallest Δu).
    """

    A: np.ndarray
    b: np.ndarray
    lb: np.ndarray | None = None
    ub: np.ndarray | None = None
    L: np.ndarray | None = None
    lo: np.ndarray | None = None
    hi: np.ndarray | None = None
    min_norm_of: tuple[np.ndarray, np.ndarray] | None = None
    #: structure known to :func:`build_problem` (private hint for the back ends): ``rows`` =
    #: number of leading rows of A that can be nonzero (the Qu block is zero below them),
    #: ``tail_diag`` = diagonal of the Qu block when it is diagonal (``tail_positive``: all > 0,
    #: so A has full column rank), ``cumulative`` = m when ``min_norm_of[0]`` is the
    #: cumulative-sum map kron(tri, I_m).
    _structure: dict | None = field(default=None, repr=False, compare=False)

    @property
    def n(self) -> int:
        return self.A.shape[1]

    @property
    def constrained(self) -> bool:
        return self.lb is not None or self.L is not None

    def cost(self, v: np.ndarray) -> float:
        r = self.A @ v - self.b
        return float(r @ r)

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
        scale = 1.0
        for arr in (self.ub, self.hi):
            if arr is not None and arr.size:
                scale = max(scale, float(np.max(np.abs(arr))))
        return self.violation(v) <= LIMIT_TOL * scale

    def active(self, v: np.ndarray, tol: float = 1e-6) -> bool:
        """True when a limit is (nearly) active at v."""
        if self.lb is not None and (np.any(v - self.lb <= tol * (1 + np.abs(self.lb))) or
                                    np.any(self.ub - v <= tol * (1 + np.abs(self.ub)))):
            return True
        if self.L is not None:
            Lv = self.L @ v
            return bool(np.any(Lv - self.lo <= tol * (1 + np.abs(self.lo))) or
                        np.any(self.hi - Lv <= tol * (1 + np.abs(self.hi))))
        return False


def _limit_vector(name: str, value, m: int) -> np.ndarray:
    arr = np.broadcast_to(np.asarray(value, dtype=float), (m,)).copy() if np.ndim(value) == 0 else np.asarray(value, dtype=float)
    if arr.shape != (m,):
        raise ShapeError(f"{name} has shape {arr.shape}; expected a scalar or ({m},)")
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise InfeasibleLimitsError(f"{name} = {arr.tolist()} must be finite and > 0 (symmetric limits ±value)")
    return arr


def build_problem(pred: Prediction, w: np.ndarray, weights: Weights, n_outputs: int, n_inputs: int,
                  torque_limit=None, du_limit=None) -> LeastSquaresProblem:
    """Stack the square-root system (15)–(16) and the limits.

    Args:
        pred: the prediction ŷ = f + G v.
        w: reference outputs over the penalized rows, (n_rows, p) or (n_rows·p,) (m, rad).
        weights: square-root weights Qy, Qu.
        n_outputs, n_inputs: p and m.
        torque_limit: symmetric drive torque limit |u| ≤ τ (N·m), scalar or (m,), or None.
        du_limit: symmetric increment limit |Δu| ≤ δ (N·m per sample), incremental forms only.

    Raises:
        ShapeError: w has the wrong shape. InvalidParameterError: Δu limits on the absolute form.
    """
    p, m = n_outputs, n_inputs
    H = pred.horizons
    w = np.asarray(w, dtype=float)
    if w.size != H.n_rows * p:
        raise ShapeError(f"reference w has shape {w.shape}; expected ({H.n_rows}, {p}) for N − No = {H.n_rows} rows")
    wy, Wy, Qu_block, qu_diag, qu_zero = _stacked_weights(weights, p, m, H.n_rows, H.Nu)
    r, n = H.n_rows * p, H.Nu * m
    A = np.empty((r + n, n))
    b = np.empty(r + n)
    if wy is not None:  # diagonal Qy: kron(I, Qy) scales rows
        np.multiply(pred.G, wy[:, None], out=A[:r])
        np.subtract(w.reshape(-1), pred.f, out=b[:r])
        b[:r] *= wy
    else:
        A[:r] = (Wy @ pred.G.reshape(H.n_rows, p, n)).reshape(r, n)
        b[:r] = (Wy @ (w.reshape(H.n_rows, p) - pred.f.reshape(H.n_rows, p)).T).T.reshape(-1)
    A[r:] = Qu_block
    b[r:] = 0.0
    structure = {"rows": r if qu_zero else r + n, "tail_diag": qu_diag, "cumulative": None,
                 "tail_positive": qu_diag is not None and bool(np.all(qu_diag > 0))}
    prob = LeastSquaresProblem(A, b, _structure=structure)
    if torque_limit is not None:
        tau = np.tile(_limit_vector("torque_limit", torque_limit, m), len(pred.u_base) // m)
        if pred.kind == "absolute":
            prob.lb, prob.ub = -tau, tau
        else:
            prob.L, prob.lo, prob.hi = pred.u_map, -tau - pred.u_base, tau - pred.u_base
    if pred.kind != "absolute":
        prob.min_norm_of = (pred.u_map[:n], pred.u_base[:n])
        if _is_cumulative_map(pred.u_map, H.Nu, m):
            structure["cumulative"] = m
    if du_limit is not None:
        if pred.kind == "absolute":
            raise InvalidParameterError("du_limit applies to the incremental forms (v = Δu); the absolute form has v = u")
        d = np.tile(_limit_vector("du_limit", du_limit, m), H.Nu)
        prob.lb, prob.ub = -d, d
    return prob


#: last stacked weights per (Weights object, sizes): validated once, reused every step.
_WEIGHT_CACHE: dict = {}


def _stacked_weights(weights: Weights, p: int, m: int, n_rows: int, Nu: int):
    """Validated, stacked weights: (wy tiled or None, Qy block, kron(I, Qu), Qu diagonal tiled or
    None, Qu == 0). Cached on the (frozen) :class:`Weights` object."""
    key = (id(weights), p, m, n_rows, Nu)
    hit = _WEIGHT_CACHE.get(key)
    if hit is not None and hit[0] is weights:
        return hit[1]
    Wy, Wu = weights.blocks(p, m)
    diag_y = not np.any(Wy - np.diag(np.diag(Wy)))
    diag_u = not np.any(Wu - np.diag(np.diag(Wu)))
    wy = np.tile(np.diag(Wy), n_rows) if diag_y else None
    qu_diag = np.tile(np.diag(Wu), Nu) if diag_u else None
    Qu_block = np.diag(qu_diag) if diag_u else np.kron(np.eye(Nu), Wu)
    value = (wy, Wy, Qu_block, qu_diag, not np.any(Wu))
    for arr in value:
        if isinstance(arr, np.ndarray):
            arr.setflags(write=False)
    if len(_WEIGHT_CACHE) > 64:
        _WEIGHT_CACHE.clear()
    _WEIGHT_CACHE[key] = (weights, value)
    return value


def _is_cumulative_map(u_map: np.ndarray, Nu: int, m: int) -> bool:
    """True when the first Nu·m rows of u_map are kron(tri(Nu), I_m) (the prediction forms' map)."""
    from .prediction import _cumulative_map

    if u_map.shape[1] != Nu * m or u_map.shape[0] < Nu * m:
        return False
    ref = _cumulative_map(Nu, Nu, m)
    top = u_map[:Nu * m]
    return top is ref or (u_map.base is not None and u_map.base is ref.base) or bool(np.array_equal(top, ref))


# ---------------------------------------------------------------------------- results
@dataclass
class SolveResult:
    """Outcome of one least-squares / QP solve.

    Attributes:
        v: (n,) solution (N·m or N·m per sample); NaN-free whenever ``ok``.
        cost: J = ‖A v − b‖² at v.
        status: ``"optimal"``, ``"unconstrained"`` (QR, limits inactive or absent),
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


# ---------------------------------------------------------------------------- QR
def qr_least_squares(A: np.ndarray, b: np.ndarray, method: str = "lapack") -> tuple[np.ndarray, float, int]:
    """Minimum-norm least-squares solution of A v ≈ b by QR, eq. (17)–(19).

    Column-pivoted Householder QR ``A P = Q R`` (LAPACK geqp3) reveals the rank r. Full rank:
    ``R₁ v = c₁`` by back substitution. Rank-deficient: a complete orthogonal decomposition
    ``[R₁₁ R₁₂] = T Zᵀ`` gives the minimum-norm v. The lost part gives ``J = ‖c_z‖²``.

    Args:
        A: (r, n); b: (r,).
        method: ``"lapack"`` (default): LAPACK drivers called directly — unpivoted Householder
            QR (``geqrf``/``ormqr``/``trtrs``; of Aᵀ when A is wide, giving the minimum-norm
            solution of a full-row-rank system) whenever its triangular factor is well
            conditioned (``trcon`` estimate > :data:`FAST_QR_RCOND`), else the pivoted path;
            ``"pivoted"``: always the rank-revealing pivoted QR / complete orthogonal
            decomposition above; ``"numpy"``: ``numpy.linalg.qr`` and a triangular solve
            (``numpy.linalg.lstsq`` when rank-deficient). All give the same v to rounding.

    Returns:
        (v, J, numerical rank).
    """
    if method == "lapack":
        out = _qr_lapack(A, b)
        return out if out is not None else _qr_pivoted(A, b)
    if method == "pivoted":
        return _qr_pivoted(A, b)
    if method == "numpy":
        return _qr_numpy(A, b)
    raise InvalidParameterError(f"QR method {method!r} is not one of 'lapack', 'pivoted', 'numpy'")


def _qr_pivoted(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float, int]:
    n = A.shape[1]
    Q, R, piv = sla.qr(A, mode="economic", pivoting=True, check_finite=False)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > RANK_RTOL * d[0])) if d.size and d[0] > 0 else 0
    c1 = Q[:, :rank].T @ b
    v = np.zeros(n)
    if rank == n:
        v[piv] = sla.solve_triangular(R, c1, check_finite=False)
    elif rank > 0:
        Z, T = np.linalg.qr(R[:rank].T, mode="reduced")  # R[:rank] = Tᵀ Zᵀ
        v[piv] = Z @ sla.solve_triangular(T, c1, trans="T", check_finite=False)
    return v, max(float(b @ b - c1 @ c1), 0.0), rank


def _qr_lapack(A: np.ndarray, b: np.ndarray):
    """Unpivoted Householder QR through LAPACK; None when the factor is (nearly) singular."""
    r, n = A.shape
    if n == 0 or r == 0:
        return None
    if r >= n:  # tall: A = Q R, v = R⁻¹ (Qᵀ b)[:n], J = ‖(Qᵀ b)[n:]‖²
        qr, tau, _, info = lapack.dgeqrf(A)
        if info != 0:
            return None
        R = qr[:n]
        rcond, info = lapack.dtrcon(R, norm="1", uplo="U", diag="N")
        if info != 0 or not rcond > FAST_QR_RCOND:
            return None
        c, _, info = lapack.dormqr("L", "T", qr, tau, b[:, None], max(1, 64 * n))
        if info != 0:
            return None
        c = c[:, 0]
        v, info = lapack.dtrtrs(R, c[:n])
        if info != 0:
            return None
        tail = c[n:]
        return v, float(tail @ tail), n
    # wide: Aᵀ = Q R, the minimum-norm solution of A v = b is v = Q R⁻ᵀ b (J = 0)
    qr, tau, _, info = lapack.dgeqrf(A.T)
    if info != 0:
        return None
    R = qr[:r]
    rcond, info = lapack.dtrcon(R, norm="1", uplo="U", diag="N")
    if info != 0 or not rcond > FAST_QR_RCOND:
        return None
    y, info = lapack.dtrtrs(R, b, trans=1)
    if info != 0:
        return None
    z = np.zeros((n, 1))
    z[:r, 0] = y
    v, _, info = lapack.dormqr("L", "N", qr, tau, z, max(1, 64 * r), overwrite_c=1)
    if info != 0:
        return None
    return v[:, 0], 0.0, r


def _qr_diag_tail(G: np.ndarray, b: np.ndarray, d: np.ndarray):
    """min ‖G v − b‖² + ‖diag(d) v‖² by Householder QR of [diag(d); G] that keeps the diagonal
    block's structure (LAPACK ``tpqrt``/``tpmqrt``: about half the work of a dense QR of the
    stacked matrix); None when the triangular factor is not well conditioned."""
    n = G.shape[1]
    R, V, T, info = lapack.dtpqrt(0, min(n, 32), np.diag(d), G)
    if info != 0:
        return None
    rcond, info = lapack.dtrcon(R, norm="1", uplo="U", diag="N")
    if info != 0 or not rcond > FAST_QR_RCOND:
        return None
    c1, cz, info = lapack.dtpmqrt(0, V, T, np.zeros((n, 1)), b[:, None], trans="T")
    if info != 0:
        return None
    v, info = lapack.dtrtrs(R, c1)
    if info != 0:
        return None
    cz = cz[:, 0]
    return v[:, 0], float(cz @ cz), n


def _qr_numpy(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float, int]:
    """numpy.linalg only: Householder QR and a triangular solve; lstsq (SVD) if rank-deficient."""
    r, n = A.shape
    if r >= n:
        Q, R = np.linalg.qr(A)
        d = np.abs(np.diag(R))
        if d.size and d.min() > 1e3 * RANK_RTOL * d.max():
            c1 = Q.T @ b
            v = np.linalg.solve(R, c1)
            return v, max(float(b @ b - c1 @ c1), 0.0), n
    v, _, rank, _ = np.linalg.lstsq(A, b, rcond=RANK_RTOL)
    res = A @ v - b
    return v, float(res @ res), int(rank)


class QRSolver:
    """Unconstrained square-root solve by QR (the reference back end). Ignores limits.

    Args:
        method: QR implementation, see :func:`qr_least_squares` (default ``"lapack"``).
    """

    name = "qr"

    def __init__(self, method: str = "lapack"):
        if method not in ("lapack", "pivoted", "numpy"):
            raise InvalidParameterError(f"QR method {method!r} is not one of 'lapack', 'pivoted', 'numpy'")
        self.method = method
        if method != "lapack":
            self.name = f"qr-{method}"

    def solve(self, problem: LeastSquaresProblem, warm_start: np.ndarray | None = None) -> SolveResult:
        t0 = time.perf_counter()
        A, b = problem.A, problem.b
        st = problem._structure
        if st is not None and st["rows"] < A.shape[0]:  # drop the zero Qu rows (Qu = 0)
            A, b = A[:st["rows"]], b[:st["rows"]]
        out = None
        if st is not None and st.get("tail_positive") and self.method == "lapack":
            # A = [Qy G; diag(d)], d > 0: full column rank, one minimizer (no minimum-norm
            # transform needed); QR of the triangular-pentagonal pair [diag(d); Qy G]
            top = A.shape[0] - A.shape[1]
            out = _qr_diag_tail(A[:top], b[:top], st["tail_diag"])
        if out is not None:
            v, cost, rank = out
        elif problem.min_norm_of is None:
            v, cost, rank = qr_least_squares(A, b, self.method)
        else:  # s = M v + m0; the minimum-norm s among the minimizers (same v when A has full rank)
            M, m0 = problem.min_norm_of
            m = st["cumulative"] if st is not None else None
            if m:  # M = kron(tri, I_m): A M⁻¹ and M⁻¹ are block differences
                AMinv = A.copy()
                AMinv[:, :-m] -= A[:, m:]
            else:
                AMinv = sla.solve_triangular(M, A.T, trans="T", lower=True, check_finite=False).T
            s, cost, rank = qr_least_squares(AMinv, b + AMinv @ m0, self.method)
            if m:
                v = s - m0
                v[m:] -= (s - m0)[:-m]
            else:
                v = sla.solve_triangular(M, s - m0, lower=True, check_finite=False)
        dt = time.perf_counter() - t0
        return SolveResult(v, cost, "unconstrained", self.name, None, dt, False,
                           f"rank {rank} of {problem.n}" if rank < problem.n else "")


# ---------------------------------------------------------------------------- QP
def _scaled_qp(problem: LeastSquaresProblem):
    """Hessian P = AᵀA and gradient q = −Aᵀb scaled to max(diag P) = 1, plus a tiny ridge."""
    A, b = problem.A, problem.b
    st = problem._structure
    tail = None
    if st is not None:
        if st["rows"] < A.shape[0]:  # Qu = 0: only the leading rows are nonzero
            A, b = A[:st["rows"]], b[:st["rows"]]
        elif st["tail_diag"] is not None:  # A = [Qy G; diag(d)], b = [·; 0]: P = (Qy G)ᵀ(Qy G) + diag(d²)
            top = A.shape[0] - A.shape[1]
            A, b, tail = A[:top], b[:top], st["tail_diag"]
    P = A.T @ A
    q = A.T @ b
    diag = P.reshape(-1)[::P.shape[0] + 1]  # a view on the diagonal of P
    if tail is not None:
        diag += tail * tail
    scale = 1.0 / max(float(diag.max()), 1e-300)
    P *= scale
    diag += QP_REGULARIZATION
    q *= -scale
    return P, q, scale


def installed_qp_solvers() -> list[str]:
    """QP solvers available through qpsolvers on this machine."""
    import qpsolvers

    return sorted(qpsolvers.available_solvers)


class QpsolversBackend:
    """``qpsolvers.solve_problem`` with any installed solver (rebuilt every call).

    Args:
        solver: qpsolvers solver name (``osqp``, ``proxqp``, ``daqp``, …).
        **settings: passed to the solver (default: tight tolerances for OSQP/ProxQP).
    """

    _DEFAULTS = {
        "osqp": dict(eps_abs=1e-10, eps_rel=1e-10, polishing=True, max_iter=20000, verbose=False),
        "proxqp": dict(eps_abs=1e-10, eps_rel=0.0),
    }

    def __init__(self, solver: str, **settings):
        available = installed_qp_solvers()
        if solver not in available:
            raise SolverNotFoundError(f"QP solver {solver!r} is not installed; installed: {available}")
        self.solver = solver
        self.name = f"qpsolvers:{solver}"
        self.settings = {**self._DEFAULTS.get(solver, {}), **settings}

    def solve(self, problem: LeastSquaresProblem, warm_start: np.ndarray | None = None) -> SolveResult:
        import qpsolvers

        t0 = time.perf_counter()
        P, q, _ = _scaled_qp(problem)
        G = h = None
        if problem.L is not None:
            G = np.vstack([problem.L, -problem.L])
            h = np.concatenate([problem.hi, -problem.lo])
        if self.solver == "osqp":  # OSQP takes CSC matrices; convert here rather than warn
            import scipy.sparse as sp

            P = sp.csc_matrix(P)
            G = None if G is None else sp.csc_matrix(G)
        qp = qpsolvers.Problem(P, q, G, h, None, None, problem.lb, problem.ub)
        settings = self.settings
        if self.solver == "osqp" and not problem.constrained:  # nothing to polish (and OSQP 1.1 says so on stdout)
            settings = {**settings, "polishing": False}
        try:
            sol = qpsolvers.solve_problem(qp, solver=self.solver, initvals=warm_start, **settings)
        except Exception as exc:  # a solver's own exception becomes a reported failure
            return _failed(problem, self.name, "failed", None, time.perf_counter() - t0, f"{type(exc).__name__}: {exc}")
        dt = time.perf_counter() - t0
        if not sol.found or sol.x is None or not np.all(np.isfinite(sol.x)):
            return _failed(problem, self.name, "infeasible", None, dt, f"{self.solver} found no solution")
        return _solved(problem, self.name, sol.x, _iterations_from_extras(sol.extras), dt)


def _failed(problem: LeastSquaresProblem, name: str, kind: str, iterations, dt: float, message: str) -> SolveResult:
    """A reported failure: NaN solution, infinite cost, status ``kind`` (never swallowed)."""
    return SolveResult(np.full(problem.n, np.nan), np.inf, kind, name, iterations, dt, message=message)


def _solved(problem: LeastSquaresProblem, name: str, x, iterations, dt: float) -> SolveResult:
    """A successful QP solve: cost and active limits evaluated on the original problem."""
    v = np.asarray(x, dtype=float)
    return SolveResult(v, problem.cost(v), "optimal", name, iterations, dt, problem.active(v))


def _iterations_from_extras(extras) -> int | None:
    info = extras.get("info") if isinstance(extras, dict) else None
    for attr in ("iter", "iterations"):
        if info is not None and hasattr(info, attr):
            return int(getattr(info, attr))
    if isinstance(extras, dict) and "iterations" in extras:
        return int(extras["iterations"])
    return None


def _stacked_constraints(problem: LeastSquaresProblem):
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
    return np.vstack(rows), np.concatenate(lo), np.concatenate(hi)


class OSQPBackend:
    """Persistent OSQP: set up once per problem structure, then updated and warm-started."""

    name = "osqp-direct"

    def __init__(self, eps: float = 1e-10, max_iter: int = 20000):
        import osqp  # noqa: F401  (fail early with ImportError if missing)

        self.eps, self.max_iter = eps, max_iter
        self._solver = None
        self._shape = None

    def solve(self, problem: LeastSquaresProblem, warm_start: np.ndarray | None = None) -> SolveResult:
        import osqp
        import scipy.sparse as sp

        t0 = time.perf_counter()
        P, q, _ = _scaled_qp(problem)
        C, lo, hi = _stacked_constraints(problem)
        shape = (P.shape, C.shape)
        if self._shape != shape:  # dense patterns (upper triangle of P, all of C): updates keep them
            n = P.shape[0]
            self._P_pattern = sp.csc_matrix(np.triu(np.ones((n, n))))
            self._P_take = np.concatenate([np.arange(j + 1) * n + j for j in range(n)])  # column-major upper
            self._C_pattern = sp.csc_matrix(np.ones(C.shape)) if C.size else sp.csc_matrix(C)
        P_up = self._P_pattern.copy()
        P_up.data = P.reshape(-1)[self._P_take]
        C_csc = self._C_pattern.copy()
        if C.size:
            C_csc.data = C.T.reshape(-1)
        if self._solver is None or self._shape != shape:
            self._solver = osqp.OSQP()
            self._solver.setup(P=P_up, q=q, A=C_csc, l=lo, u=hi, eps_abs=self.eps, eps_rel=self.eps,
                               polishing=bool(C.size), max_iter=self.max_iter, verbose=False, warm_starting=True)
            self._shape = shape
        else:
            self._solver.update(q=q, l=lo, u=hi, Px=P_up.data, Ax=C_csc.data if C.size else None)
        if warm_start is not None and np.all(np.isfinite(warm_start)):
            self._solver.warm_start(x=warm_start)
        res = self._solver.solve(raise_error=False)
        dt = time.perf_counter() - t0
        status = str(res.info.status)
        if "solved" not in status or "inaccurate" in status or not np.all(np.isfinite(res.x)):
            kind = "infeasible" if "infeasible" in status else "failed"
            return _failed(problem, self.name, kind, int(res.info.iter), dt, f"OSQP status: {status}")
        return _solved(problem, self.name, res.x, int(res.info.iter), dt)


class ProxQPBackend:
    """Persistent ProxQP dense solver, warm-started with the previous solution."""

    name = "proxqp-direct"

    def __init__(self, eps: float = 1e-10, max_iter: int = 10000):
        import proxsuite  # noqa: F401

        self.eps, self.max_iter = eps, max_iter
        self._qp = None
        self._shape = None

    def solve(self, problem: LeastSquaresProblem, warm_start: np.ndarray | None = None) -> SolveResult:
        import proxsuite

        t0 = time.perf_counter()
        P, q, _ = _scaled_qp(problem)
        C, lo, hi = _stacked_constraints(problem)
        shape = (P.shape, C.shape)
        if self._qp is None or self._shape != shape:
            self._qp = proxsuite.proxqp.dense.QP(problem.n, 0, C.shape[0])
            s = self._qp.settings
            s.eps_abs, s.eps_rel, s.max_iter, s.verbose = self.eps, 0.0, self.max_iter, False
            s.initial_guess = proxsuite.proxqp.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT
            self._qp.init(P, q, None, None, C if C.size else None, lo if C.size else None, hi if C.size else None)
            self._shape = shape
        else:
            self._qp.update(P, q, None, None, C if C.size else None, lo if C.size else None, hi if C.size else None)
        self._qp.solve()
        dt = time.perf_counter() - t0
        info = self._qp.results.info
        status = str(info.status)
        v = np.asarray(self._qp.results.x).copy()
        if "SOLVED" not in status.upper() or "CLOSEST" in status.upper() or not np.all(np.isfinite(v)):
            kind = "infeasible" if "INFEASIBLE" in status.upper() else "failed"
            self._qp = None  # its warm start is now meaningless: set up afresh next time
            return _failed(problem, self.name, kind, int(info.iter), dt, f"ProxQP status: {status}")
        return _solved(problem, self.name, v, int(info.iter), dt)


class DAQPBackend:
    """DAQP dual active-set solver through its direct API.

    Warm start: the initial working set is the set of limits (nearly) active at the given warm
    start (the controller passes the previous solution shifted by one sample); without one,
    the previous solve's active set. Box limits are passed as DAQP's simple bounds.
    """

    name = "daqp-direct"

    def __init__(self):
        import daqp  # noqa: F401

        self._sense = None

    def solve(self, problem: LeastSquaresProblem, warm_start: np.ndarray | None = None) -> SolveResult:
        import daqp

        t0 = time.perf_counter()
        P, q, _ = _scaled_qp(problem)
        parts_lo, parts_hi = [], []
        if problem.lb is not None:  # simple bounds come first
            parts_lo.append(problem.lb)
            parts_hi.append(problem.ub)
        if problem.L is not None:
            A_in = problem.L if problem.L.flags.writeable else problem.L.copy()  # DAQP wants a writable buffer
            parts_lo.append(problem.lo)
            parts_hi.append(problem.hi)
        else:
            A_in = np.zeros((0, problem.n))
        lo = np.concatenate(parts_lo) if parts_lo else np.zeros(0)
        hi = np.concatenate(parts_hi) if parts_hi else np.zeros(0)
        kwargs = {}
        if warm_start is not None and warm_start.shape == (problem.n,) and np.all(np.isfinite(warm_start)):
            kwargs["primal_start"] = np.asarray(warm_start, dtype=float)
            sense = np.zeros(lo.shape, dtype=np.int32)
        elif self._sense is not None and self._sense.shape == lo.shape:
            sense = self._sense
        else:
            sense = np.zeros(lo.shape, dtype=np.int32)
        x, _, flag, info = daqp.solve(P, q, A_in, hi, lo, sense, **kwargs)
        dt = time.perf_counter() - t0
        if flag != 1 or not np.all(np.isfinite(x)):
            kind = "infeasible" if flag == -1 else "failed"
            return _failed(problem, self.name, kind, int(info.get("iterations", 0)), dt, f"DAQP exit flag {flag}")
        self._sense = (np.abs(np.asarray(info["lam"])) > 0).astype(np.int32) if "lam" in info else None
        return _solved(problem, self.name, x, int(info.get("iterations", 0)), dt)


class QRFirst:
    """Solve by QR; call the QP back end only when the QR solution violates a limit."""

    def __init__(self, qp_backend):
        self.qp = qp_backend
        self.qr = QRSolver()
        self.name = f"qr-first:{qp_backend.name}"

    def solve(self, problem: LeastSquaresProblem, warm_start: np.ndarray | None = None) -> SolveResult:
        res = self.qr.solve(problem)
        if not problem.constrained or problem.feasible(res.v):
            res.solver = self.name
            return res
        qp = self.qp.solve(problem, warm_start)
        qp.solve_time += res.solve_time
        qp.solver = self.name
        return qp


#: Back-end names accepted by :func:`make_solver` besides ``qpsolvers:<name>``.
DIRECT_BACKENDS = {"qr": QRSolver, "osqp-direct": OSQPBackend, "proxqp-direct": ProxQPBackend,
                   "daqp-direct": DAQPBackend}


def available_solvers() -> list[str]:
    """Every name :func:`make_solver` accepts on this machine."""
    names = list(DIRECT_BACKENDS) + [f"qpsolvers:{s}" for s in installed_qp_solvers()]
    names += [f"qr-first:{n}" for n in names if n != "qr"]
    return names


def make_solver(name: str):
    """Back end by name: ``qr``, ``osqp-direct``, ``proxqp-direct``, ``daqp-direct``,
    ``qpsolvers:<solver>`` (or a bare installed qpsolvers name such as ``osqp``), each
    optionally prefixed ``qr-first:``.

    Raises:
        SolverNotFoundError: unknown or uninstalled name (the message lists the valid ones).
    """
    if not isinstance(name, str):
        raise SolverNotFoundError(f"solver name {name!r} must be a string; available: {available_solvers()}")
    if name.startswith("qr-first:"):
        inner = make_solver(name[len("qr-first:"):])
        if isinstance(inner, QRSolver):
            raise SolverNotFoundError("qr-first needs a QP back end, not 'qr'")
        return QRFirst(inner)
    if name in DIRECT_BACKENDS:
        try:
            return DIRECT_BACKENDS[name]()
        except ImportError as exc:  # its Python package is missing on this machine
            raise SolverNotFoundError(
                f"solver {name!r} is not installed ({exc}); available: {available_solvers()}") from None
    qp_name = name[len("qpsolvers:"):] if name.startswith("qpsolvers:") else name
    if qp_name in installed_qp_solvers():
        return QpsolversBackend(qp_name)
    raise SolverNotFoundError(f"unknown solver {name!r}; available: {available_solvers()}")
