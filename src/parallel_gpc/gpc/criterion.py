"""The GPC criterion (5): square-root weights and the stacked least-squares problem (15)–(16)."""

from __future__ import annotations

import numpy as np
from dataclasses import dataclass

from ..errors import InfeasibleLimitsError, InvalidParameterError, ShapeError
from ..solvers import LeastSquaresProblem
from .prediction import Prediction, _cumulative_map


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

    if u_map.shape[1] != Nu * m or u_map.shape[0] < Nu * m:
        return False
    ref = _cumulative_map(Nu, Nu, m)
    top = u_map[:Nu * m]
    return top is ref or (u_map.base is not None and u_map.base is ref.base) or bool(np.array_equal(top, ref))


