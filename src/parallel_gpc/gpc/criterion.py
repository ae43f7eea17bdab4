"""The GPC criterion (5): square-root weights and the stacked least-squares problem (15)–(16)."""

from __future__ import annotations

import numpy as np
from dataclasses import dataclass

from ..errors import InvalidParameterError, ShapeError
from ..limits import Limits, as_limits
from ..solvers import LeastSquaresProblem, MinNormOf
from ..validation import check_allocation
from .prediction import Horizons, Prediction, cumulative_map


# ---------------------------------------------------------------------------- weights
def _weight_array(name: str, value) -> np.ndarray:
    """``value`` as a float array; strings, bools and non-numeric objects are refused."""
    arr = np.asarray(value, dtype=object) if not isinstance(value, np.ndarray) else value
    if arr.dtype.kind in "USObV" or arr.dtype.kind == "b":
        flat = arr.reshape(-1).tolist() if arr.dtype.kind == "O" else None
        ok = flat is not None and all(isinstance(x, (int, float, np.integer, np.floating))
                                      and not isinstance(x, (bool, np.bool_)) for x in flat)
        if not ok:
            raise InvalidParameterError(f"weight {name} = {value!r} must be a number, a vector or a matrix of numbers")
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):  # ragged nesting
        raise InvalidParameterError(f"weight {name} = {value!r} must be a number, a vector or a matrix of numbers") \
            from None


def _weight_block(name: str, value, size: int) -> np.ndarray:
    """Square-root weight as a (size, size) matrix from a scalar, a (size,) vector or a matrix."""
    arr = _weight_array(name, value)
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
    """Square-root weights of the criterion (5): J = Σ‖Qy (ŷ − w)‖² + Σ‖Qu v‖², the last
    predicted error weighted by Qf·Qy (a terminal weight).

    Attributes:
        Qy: output weight: scalar, (p,) per channel, or (p, p) symmetric PSD matrix.
        Qu: input (absolute form) or increment (incremental forms) weight, same forms, (m,).
        Qf: terminal factor ≥ 0 on the last predicted step's square-root output weight: its term is
            ‖diag(Qf) Qy (ŷ(k+N) − w(k+N))‖²; a scalar or (p,) per channel. Default 1: the paper's
            criterion, the same problem to the last bit.
    """

    Qy: object = 1.0
    Qu: object = 0.0
    Qf: object = 1.0

    def __post_init__(self):
        _weight_array("Qy", self.Qy)
        _weight_array("Qu", self.Qu)
        qf = _weight_array("Qf", self.Qf)
        if qf.ndim > 1 or not np.all(np.isfinite(qf)) or np.any(qf < 0):
            raise InvalidParameterError(f"terminal weight Qf = {self.Qf!r} must be a number or one per output, "
                                        "finite and ≥ 0 (1: no extra terminal weight)")

    def blocks(self, p: int, m: int) -> tuple[np.ndarray, np.ndarray]:
        """(p, p) and (m, m) square-root weight matrices (validated)."""
        return _weight_block("Qy", self.Qy, p), _weight_block("Qu", self.Qu, m)

    def terminal(self, p: int) -> np.ndarray | None:
        """(p,) the terminal factor per output, or None when it is 1 for every output (no terminal weight).

        Raises:
            ShapeError: a vector Qf that is not p long.
        """
        qf = np.asarray(self.Qf, dtype=float)
        if qf.ndim == 1 and qf.shape != (p,):
            raise ShapeError(f"terminal weight Qf has shape {qf.shape}; expected a scalar or ({p},)")
        qf = np.broadcast_to(qf, (p,)).copy()
        return None if np.all(qf == 1.0) else qf


# ---------------------------------------------------------------------------- problem
def check_problem_size(horizons: Horizons, p: int, m: int) -> None:
    """Refuse horizons whose dense problem would exceed the allocation limit, before allocating.

    The estimate: A of (15)-(16), (n_rows·p + Nu·m) × Nu·m, plus two (Nu·m)² matrices (the
    input map of the prediction and the QP Hessian).

    Raises:
        InvalidParameterError: naming N, Nu, the estimated size and the limit.
    """
    H = horizons
    rows, cols = H.n_rows * p + H.Nu * m, H.Nu * m
    check_allocation(f"the least-squares problem (15)-(16) with N = {H.N}, Nu = {H.Nu} ({rows} x {cols} plus "
                     "two square matrices of its width)", rows * cols + 2.0 * cols * cols,
                     "reduce the horizon N (or Nu)")



@dataclass(frozen=True, eq=False)
class Criterion:
    """The criterion (5) stacked for one controller: the weights validated and tiled over the
    horizons once, then reused by every step's :meth:`problem`.

    Args:
        weights: square-root weights Qy, Qu.
        horizons: N, No, Nu.
        n_outputs, n_inputs: p and m.

    Attributes (derived, read-only arrays):
        Wy: (p, p) output weight; wy: (n_rows·p,) its diagonal tiled when Wy is diagonal (the last
        block times the terminal factor Qf), else None. Wf: (p, p) diag(Qf) Wy, the last predicted
        step's weight, or None when Qf = 1.
        Qu_block: (Nu·m, Nu·m) kron(I, Qu); qu_diag: (Nu·m,) its diagonal when Qu is diagonal, else None.
        qu_zero: Qu = 0 (the regularization rows of A are zero).

    Raises:
        ShapeError, InvalidParameterError: a weight of the wrong shape, not finite, negative or
            not positive semi-definite.
    """

    weights: Weights
    horizons: Horizons
    n_outputs: int
    n_inputs: int

    def __post_init__(self):
        p, m, H = self.n_outputs, self.n_inputs, self.horizons
        check_problem_size(H, p, m)
        Wy, Wu = self.weights.blocks(p, m)
        qf = self.weights.terminal(p)
        diag_y = not np.any(Wy - np.diag(np.diag(Wy)))
        diag_u = not np.any(Wu - np.diag(np.diag(Wu)))
        qu_diag = np.tile(np.diag(Wu), H.Nu) if diag_u else None
        wy = np.tile(np.diag(Wy), H.n_rows) if diag_y else None
        if wy is not None and qf is not None:
            wy[-p:] *= qf
        derived = {"Wy": Wy, "wy": wy, "qu_diag": qu_diag, "Wf": None if qf is None else qf[:, None] * Wy,
                   "Qu_block": np.diag(qu_diag) if diag_u else np.kron(np.eye(H.Nu), Wu)}
        for name, arr in derived.items():
            if arr is not None:
                arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "qu_zero", not np.any(Wu))
        object.__setattr__(self, "qu_positive", qu_diag is not None and bool(np.all(qu_diag > 0)))

    def problem(self, pred: Prediction, w: np.ndarray, limits: Limits | None = None,
                u_prev: np.ndarray | None = None) -> LeastSquaresProblem:
        """Stack the square-root system (15)–(16) and the limits for one step.

        Args:
            pred: the prediction ŷ = f + G v (with these horizons).
            w: reference outputs over the penalized rows, (n_rows, p) or (n_rows·p,) (m, rad).
            limits: input :class:`~parallel_gpc.limits.Limits` sized to the m drives
                (:meth:`~parallel_gpc.limits.Limits.for_drives`), or None: the rows of
                :func:`input_rows` (torque on u = u_base + u_map v, the increment box on v).
            u_prev: (m,) u(k−1) (N·m); needed by the nonlinear form's increment limit.

        Raises:
            ShapeError: w has the wrong shape, or limits not sized to m drives.
            InvalidParameterError: an increment limit on the absolute form, the nonlinear form's
                increment limit without u_prev, or a prediction with other horizons.
        """
        p, m, H = self.n_outputs, self.n_inputs, self.horizons
        if pred.horizons is not H and pred.horizons != H:
            raise InvalidParameterError(f"prediction horizons {pred.horizons} differ from the criterion's {H}")
        w = np.asarray(w, dtype=float)
        if w.size != H.n_rows * p:
            raise ShapeError(f"reference w has shape {w.shape}; expected ({H.n_rows}, {p}) for N − No = {H.n_rows} rows")
        r, n = H.n_rows * p, H.Nu * m
        A = np.empty((r + n, n))
        b = np.empty(r + n)
        if self.wy is not None:  # diagonal Qy: kron(I, Qy) scales rows
            np.multiply(pred.G, self.wy[:, None], out=A[:r])
            np.subtract(w.reshape(-1), pred.f, out=b[:r])
            b[:r] *= self.wy
        else:
            A[:r] = (self.Wy @ pred.G.reshape(H.n_rows, p, n)).reshape(r, n)
            b[:r] = (self.Wy @ (w.reshape(H.n_rows, p) - pred.f.reshape(H.n_rows, p)).T).T.reshape(-1)
            if self.Wf is not None:  # the last predicted step: diag(Qf) Wy
                A[r - p:r] = self.Wf @ pred.G[r - p:]
                b[r - p:r] = self.Wf @ (w.reshape(-1)[r - p:] - pred.f[r - p:])
        A[r:] = self.Qu_block
        b[r:] = 0.0
        prob = LeastSquaresProblem(A, b, nonzero_rows=r if self.qu_zero else r + n, tail_diag=self.qu_diag,
                                   tail_positive=self.qu_positive)
        if pred.kind != "absolute":
            block = m if _is_cumulative_map(pred.u_map, H.Nu, m) else None
            prob.min_norm_of = MinNormOf(pred.u_map[:n], pred.u_base[:n], block)
        if limits is None:
            return prob
        tau, delta = limits.torque, limits.du
        if (tau is not None and tau.shape != (m,)) or (delta is not None and delta.shape != (m,)):
            raise ShapeError(f"limits {limits!r} are not sized to the {m} drives; pass limits.for_drives({m})")
        rows = input_rows(limits, pred.kind, H.Nu, len(pred.u_base) // m,
                          pred.u_base[:n].reshape(-1, m) if pred.kind == "simulative" else None, u_prev)
        if rows.torque is not None:
            tau = rows.torque.reshape(-1)
            if pred.kind == "absolute":
                prob.lb, prob.ub = -tau, tau
            else:
                prob.L, prob.lo, prob.hi = pred.u_map, -tau - pred.u_base, tau - pred.u_base
        if rows.du_lo is not None:
            prob.lb, prob.ub = rows.du_lo.reshape(-1), rows.du_hi.reshape(-1)
        return prob


@dataclass(frozen=True)
class InputRows:
    """The input kinds' rows of one step, the one definition the condensed layout
    (:meth:`Criterion.problem`) and the stage-wise layout (:func:`~parallel_gpc.gpc.stagewise.stage_problem`) use.

    Attributes:
        torque: (n_torque, m) τ of −τ ≤ u(k+i) ≤ τ, i < n_torque (N·m), or None.
        du_lo, du_hi: (Nu, m) box on the decision v(i) = Δu(k+i) that keeps
            −δ ≤ u(k+i) − u(k+i−1) ≤ δ (the nonlinear form's shifted by its drift), or None.
    """

    torque: np.ndarray | None
    du_lo: np.ndarray | None
    du_hi: np.ndarray | None


def input_rows(limits: Limits, kind: str, Nu: int, n_torque: int, u_sim: np.ndarray | None = None,
               u_prev: np.ndarray | None = None) -> InputRows:
    """The :class:`InputRows` of ``limits`` (sized to the m drives).

    The torque limit bounds u(k..k+Nu−1) (nonlinear form: every pre-simulated input, n_torque = N);
    the increment limit bounds u(k+i) − u(k+i−1), i < Nu (delayed form: u(k+1+i) − u(k+i)): a box
    on v, which for the nonlinear form (whose pre-simulated inputs u_sim move by themselves) is
    shifted by u_sim(i) − u_sim(i−1), u_sim(−1) = u(k−1).

    Args:
        limits: sized to the drives. kind: the prediction's kind (``"absolute"``, ``"incremental"``
            or ``"simulative"``). Nu: control horizon. n_torque: the torque-limited steps.
        u_sim: (≥ Nu, m) pre-simulated inputs (simulative). u_prev: (m,) u(k−1) (N·m; simulative du).

    Raises:
        InvalidParameterError: an increment limit on the absolute form, or the nonlinear form's
            increment limit without u_prev.
    """
    tau, delta = limits.torque, limits.du
    torque = None if tau is None else np.broadcast_to(tau, (n_torque, len(tau)))
    if delta is None:
        return InputRows(torque, None, None)
    if kind == "absolute":
        raise InvalidParameterError("the du limit applies to the incremental forms (v = Δu); the absolute "
                                    "form has v = u")
    d = np.broadcast_to(delta, (Nu, len(delta)))
    if kind != "simulative":  # the increments add to u(k−1) (delayed: u(k)) itself: a box on v
        return InputRows(torque, -d, d)
    if u_prev is None:
        raise InvalidParameterError("the nonlinear form's du limit is measured from u(k−1): pass u_prev")
    # u(k+i) − u(k+i−1) = u_sim(i) − u_sim(i−1) + Δu(i)
    drift = np.diff(np.vstack([np.asarray(u_prev, dtype=float), np.asarray(u_sim, dtype=float)[:Nu]]), axis=0)
    return InputRows(torque, -d - drift, d - drift)


def build_problem(pred: Prediction, w: np.ndarray, weights: Weights, n_outputs: int, n_inputs: int,
                  limits: Limits | None = None, u_prev: np.ndarray | None = None) -> LeastSquaresProblem:
    """Stack the square-root system (15)–(16) and the limits (one-off; a controller keeps a
    :class:`Criterion` and calls :meth:`Criterion.problem` every step instead).

    Args:
        pred: the prediction ŷ = f + G v.
        w: reference outputs over the penalized rows, (n_rows, p) or (n_rows·p,) (m, rad).
        weights: square-root weights Qy, Qu.
        n_outputs, n_inputs: p and m.
        limits: input :class:`~parallel_gpc.limits.Limits` (a scalar value applies to every
            drive), or None. u_prev: (m,) u(k−1), as in :meth:`Criterion.problem`.

    Raises:
        ShapeError: w has the wrong shape, or per-drive limits not m long.
        InvalidParameterError: an increment limit on the absolute form.
    """
    sized = None if limits is None else as_limits(limits).for_drives(n_inputs)
    return Criterion(weights, pred.horizons, n_outputs, n_inputs).problem(pred, w, sized, u_prev)


def _is_cumulative_map(u_map: np.ndarray, Nu: int, m: int) -> bool:
    """True when the first Nu·m rows of u_map are kron(tri(Nu), I_m) (the prediction forms' map)."""

    if u_map.shape[1] != Nu * m or u_map.shape[0] < Nu * m:
        return False
    ref = cumulative_map(Nu, Nu, m)
    if u_map is ref:  # the cached map itself (the incremental form; the nonlinear one with Nu = N)
        return True
    top = u_map[:Nu * m]
    return (u_map.base is not None and u_map.base is ref.base) or bool(np.array_equal(top, ref))
