"""Output predictions ``ŷ = f + G v`` (paper eq. (6)–(13)).

One LTV condenser, :func:`condense`, serves all three forms; they differ only in the per-step
matrices they feed it:

* :func:`absolute_prediction`, eq. (7): the discretized model at X(k), v = u;
* :func:`incremental_prediction`, eq. (8)–(9): state augmented with u(k−1), v = Δu; with
  ``delayed=True`` the paper's variant as printed: state [X(k); u(k)], B̄ = [0; I], the
  increment Δu(k) realized at k+1 (a one-sample computation delay);
* :func:`simulative_prediction`, eq. (10)–(12): deviation model along a pre-simulated nonlinear
  trajectory, augmented like the incremental form, v = Δu and u = u_sim + cumsum(Δu).

Horizons (eq. (5)): rows of the outputs j = 1..No are dropped; inputs are held after Nu
(absolute: columns beyond Nu fold into the last block; incremental: Δu = 0 beyond Nu).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..model import cached_identity, compiled_part
from ..errors import InvalidParameterError, ShapeError


@dataclass(frozen=True)
class Horizons:
    """Horizons of the criterion (5), in samples.

    Attributes:
        N: optimization (prediction) horizon, N ≥ 1.
        No: initial insensitivity horizon, 0 ≤ No < N (outputs k+1..k+No not penalized).
        Nu: control horizon, 1 ≤ Nu ≤ N (inputs held after it); default N.
    """

    N: int
    No: int = 0
    Nu: int | None = None

    def __post_init__(self):
        for name in ("N", "No"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise InvalidParameterError(f"horizon {name} = {value!r} must be an integer")
        if self.N < 1:
            raise InvalidParameterError(f"horizon N = {self.N} must be ≥ 1")
        if not 0 <= self.No < self.N:
            raise InvalidParameterError(f"horizon No = {self.No} must satisfy 0 ≤ No < N = {self.N}")
        if self.Nu is None:
            object.__setattr__(self, "Nu", int(self.N))
        if isinstance(self.Nu, bool) or not isinstance(self.Nu, (int, np.integer)) or not 1 <= self.Nu <= self.N:
            raise InvalidParameterError(f"control horizon Nu = {self.Nu!r} must be an integer with 1 ≤ Nu ≤ N = {self.N}")

    @property
    def n_rows(self) -> int:
        """Number of penalized output steps, N − No."""
        return self.N - self.No


#: the size of an input map (rows × columns) from which :meth:`Prediction.inputs` sums a cumulative map's
#: increments instead of taking the product (between 160² and 320², measured in its docstring)
CUMSUM_SIZE = 200 * 200


@dataclass
class Prediction:
    """Affine output prediction over the horizon and the map from v to applied inputs.

    Attributes:
        f: (n_rows·p,) free response (outputs k+No+1..k+N stacked; m and rad).
        G: (n_rows·p, Nu·m) dynamic matrix.
        u_base, u_map: the inputs over the first ``len(u_base)/m`` steps are
            ``u = u_base + u_map @ v`` (N·m); used for drive torque limits.
        horizons: the horizons used.
        kind: ``"absolute"``, ``"incremental"`` or ``"simulative"`` (what v means).
    """

    f: np.ndarray
    G: np.ndarray
    u_base: np.ndarray
    u_map: np.ndarray
    horizons: Horizons
    kind: str

    def outputs(self, v: np.ndarray) -> np.ndarray:
        """(n_rows·p,) predicted outputs ŷ = f + G v."""
        return self.f + self.G @ v

    def inputs(self, v: np.ndarray) -> np.ndarray:
        """(len(u_base),) inputs u = u_base + u_map v (N·m and V): a large cumulative map of the forms
        (:func:`cumulative_map`, the incremental and simulative predictions) as running sums of the
        increments, held after Nu, in O(N·m) instead of the dense (N·m)² product. Measured (planar_4rrr,
        m = 4, N = 20 / 40 / 80 / 160): the sums 4.3 / 5.0 / 5.1 / 6.5 µs, the product 1.5 / 3.5 / 14.6 /
        108 µs (a fifth of an incremental Riccati step at N = 160): the sums from CUMSUM_SIZE entries on."""
        rows, cols = self.u_map.shape
        Nu = self.horizons.Nu
        m = cols // Nu if Nu and cols % Nu == 0 else 0
        if rows * cols >= CUMSUM_SIZE and m and rows % m == 0 and self.u_map is cumulative_map(rows // m, Nu, m):
            sums = np.cumsum(np.reshape(v, (Nu, m)), axis=0)
            if rows // m > Nu:
                sums = np.vstack([sums, np.broadcast_to(sums[-1], (rows // m - Nu, m))])
            return self.u_base + sums[:rows // m].reshape(-1)
        return self.u_base + self.u_map.dot(v)  # (the product of @ without matmul's dispatch)


def _per_step(name: str, value, N: int, shape: tuple[int, ...]) -> np.ndarray:
    """Broadcast one matrix or a sequence of N matrices to an (N, *shape) array."""
    arr = np.asarray(value, dtype=float)
    if arr.shape == shape:
        return np.broadcast_to(arr, (N, *shape))
    if arr.shape == (N, *shape):
        return arr
    raise ShapeError(f"{name} has shape {arr.shape}; expected {shape} or {(N, *shape)}")


def condense(A, B, c, C, x0, horizons: Horizons, hold_inputs: bool) -> tuple[np.ndarray, np.ndarray]:
    """Condense the LTV model ``x(i+1) = A_i x(i) + B_i v(i) + c_i``, ``y = C x`` over the horizon.

    A time-invariant model (A and B given as single matrices) takes the block-Toeplitz route of
    eq. (7): the powers C·A^k by repeated squaring and G filled from the impulse response
    C·A^k·B; a time-varying one runs the recursion once over all columns at a time.

    Args:
        A: (n, n) or (N, n, n); B: (n, m) or (N, n, m); c: (n,), (N, n) or None.
        C: (p, n) output matrix; x0: (n,) initial state.
        horizons: N, No, Nu.
        hold_inputs: True holds v(Nu−1) for steps ≥ Nu (columns fold into the last block);
            False sets v = 0 there (columns dropped).

    Returns:
        f: (n_rows·p,) and G: (n_rows·p, Nu·m) with ŷ(k+No+1..k+N) = f + G v(0..Nu−1).
    """
    N = horizons.N
    C = np.asarray(C, dtype=float)
    n = C.shape[1]
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    m = B.shape[-1]
    x = np.asarray(x0, dtype=float)
    if x.shape != (n,):
        raise ShapeError(f"x0 has shape {x.shape}; expected ({n},)")
    if c is not None:
        c = np.asarray(c, dtype=float)
    if A.shape == (n, n) and B.shape == (n, m) and (c is None or c.shape == (n,)):
        return _condense_lti(A, B, c, C, x, horizons, hold_inputs)
    A = _per_step("A", A, N, (n, n))
    B = _per_step("B", B, N, (n, m))
    if c is not None:
        c = _per_step("c", c, N, (n,))
    return _condense_ltv(A, B, c, C, x, horizons, hold_inputs)


def _condense_ltv(A, B, c, C, x, horizons: Horizons, hold_inputs: bool):
    """Recursion S(i+1) = A_i S(i) + [B_i in column block i], with x carried as a first column.

    Causality: S(i) depends on the first min(i, Nu) input blocks only, so step i multiplies those
    columns (and x) alone — about half the work of the full recursion over N steps — and the new
    block is B_i itself (A_i times a zero block).
    """
    N, No, Nu = horizons.N, horizons.No, horizons.Nu
    n, m, p = A.shape[-1], B.shape[-1], C.shape[0]
    K = Nu * m
    S = np.zeros((N + 1, n, K + 1))  # S[i] = [x(i) at v = 0 | ∂x(i)/∂v]
    S[0, :, 0] = x
    for i in range(N):
        cols = 1 + min(i, Nu) * m  # the columns of S[i] that can be nonzero
        np.matmul(A[i], S[i, :, :cols], out=S[i + 1, :, :cols])
        if i < Nu:
            S[i + 1, :, cols:cols + m] = B[i]
        elif hold_inputs:
            S[i + 1, :, K + 1 - m:] += B[i]
        if c is not None:
            S[i + 1, :, 0] += c[i]
    Y = C @ S[No + 1:]  # (n_rows, p, K + 1)
    rows = horizons.n_rows * p
    return Y[:, :, 0].reshape(rows), Y[:, :, 1:].reshape(rows, K)


@lru_cache(maxsize=64)
def _toeplitz_index(N: int, No: int, Nu: int, hold: bool, p: int, m: int) -> np.ndarray:
    """(n_rows·p, Nu·m) flat indices into the stacked blocks [0, H_0 … H_{N−1}, ΣH_0 … ΣH_{N−1}]
    (each p × m) giving G element by element: G[i, j] = H_{i−j} for j ≤ i (block rows
    i = No..N−1); with ``hold`` the last block column collects H_0 + … + H_{i−Nu+1}."""
    i = np.arange(No, N)[:, None]
    j = np.arange(Nu)[None, :]
    idx = np.where(j <= i, 1 + i - j, 0)
    if hold and Nu < N:
        last = i[:, 0] - (Nu - 1)
        idx[:, Nu - 1] = np.where(last >= 0, 1 + N + last, 0)
    a = np.arange(p)[None, :, None, None]
    b = np.arange(m)[None, None, None, :]
    flat = (idx[:, None, :, None] * (p * m) + a * m + b).reshape((N - No) * p, Nu * m)
    flat.setflags(write=False)
    return flat


def _lti_responses(A, B, c, C, x, N: int):
    """Free response y(1..N) (N, p) and impulse response C A^k B, k = 0..N−1, (N, p, m) of the
    time-invariant model; the powers C·A^k by repeated squaring, stacked as one ((N+1)·p, n)
    matrix so that every product is a single BLAS call."""
    n, p = A.shape[0], C.shape[0]
    CP = np.empty(((N + 1) * p, n))  # rows k·p … (k+1)·p − 1: C A^k
    CP[:p] = C
    power, done = A, 1
    while done <= N:
        take = min(done, N + 1 - done)
        np.matmul(CP[:take * p], power, out=CP[done * p:(done + take) * p])
        done += take
        if done <= N:
            power = power @ power
    blocks = CP.reshape(N + 1, p, n)  # matrix-vector products block by block: one gemv over the
    f = blocks[1:] @ x  # stacked matrix sums in another order (u differs at 1e-12 on hexapod_8ups)
    if c is not None:
        f += np.cumsum(blocks[:N] @ c, axis=0)  # Σ_{k≤i} C A^k c
    return f, (CP[:N * p] @ B).reshape(N, p, B.shape[1])


def _toeplitz(H: np.ndarray, horizons: Horizons, hold: bool) -> np.ndarray:
    """Block-Toeplitz G of eq. (7) from the blocks H_k (N, p, m)."""
    N, No, Nu = horizons.N, horizons.No, horizons.Nu
    p, m = H.shape[1], H.shape[2]
    hold = hold and Nu < N
    blocks = np.empty((2 * N + 1 if hold else N + 1, p, m))
    blocks[0] = 0.0
    blocks[1:N + 1] = H
    if hold:
        np.cumsum(H, axis=0, out=blocks[N + 1:])
    return blocks.reshape(-1)[_toeplitz_index(N, No, Nu, hold, p, m)]


def _condense_lti(A, B, c, C, x, horizons: Horizons, hold_inputs: bool):
    """Block-Toeplitz condensation of eq. (7) for A_i = A, B_i = B, c_i = c."""
    f, H = _lti_responses(A, B, c, C, x, horizons.N)
    return f[horizons.No:].reshape(-1), _toeplitz(H, horizons, hold_inputs)


def _augment(A: np.ndarray, B: np.ndarray, c: np.ndarray | None, delayed: bool = False):
    """Augmented model (8)–(9), input Δu. Works on (…, n, n) stacks.

    Undelayed: state [x; u(k−1)], B̄ = [B; I] (the increment acts at once). Delayed (the paper's
    (8) as printed): state [x; u(k)], B̄ = [0; I] (the increment is realized one sample later).
    """
    n, m = B.shape[-2], B.shape[-1]
    lead = A.shape[:-2]
    Aa = np.zeros((*lead, n + m, n + m))
    Aa[..., :n, :n] = A
    Aa[..., :n, n:] = B
    Aa[..., n:, n:] = np.eye(m)
    Ba = np.zeros((*lead, n + m, m))
    if not delayed:
        Ba[..., :n, :] = B
    Ba[..., n:, :] = np.eye(m)
    ca = None
    if c is not None:
        ca = np.zeros((*np.shape(c)[:-1], n + m))
        ca[..., :n] = c
    return Aa, Ba, ca


@lru_cache(maxsize=64)
def cumulative_map(K: int, Nu: int, m: int) -> np.ndarray:
    """(K·m, Nu·m) map Δu(0..Nu−1) ↦ cumulative sums at steps 0..K−1 (Δu = 0 after Nu).

    Cached and read-only: the same object serves every step of a controller.
    """
    M = np.kron(np.tri(K, Nu), np.eye(m))
    M.setflags(write=False)
    return M


def absolute_prediction(Ad, Bd, cd, C, X, horizons: Horizons) -> Prediction:
    """Absolute prediction, eq. (7): v = [u(k) … u(k+Nu−1)] (N·m), held after Nu."""
    f, G = condense(Ad, Bd, cd, C, X, horizons, hold_inputs=True)
    m = np.asarray(Bd).shape[-1]
    size = horizons.Nu * m
    return Prediction(f, G, np.zeros(size), cached_identity(size), horizons, "absolute")  # u = v


def incremental_prediction(Ad, Bd, cd, C, X, u_prev, horizons: Horizons, delayed: bool = False) -> Prediction:
    """Incremental prediction, eq. (8)–(9): v = [Δu(k) … Δu(k+Nu−1)].

    Undelayed (default): u(k) = u(k−1) + Δu(k), ``u_prev`` = u(k−1), and the constrained inputs
    are u(k) … u(k+Nu−1). Delayed (``delayed=True``, the paper's (8) as printed): ``u_prev`` is
    u(k), already decided at k−1 and applied now; u(k+1) = u(k) + Δu(k), so ŷ(k+1) does not
    depend on v and the constrained inputs are u(k+1) … u(k+Nu).

    A time-invariant model is condensed through its step response S_j = Σ_{l≤j} C A^l B (the
    augmented model has exactly these Markov parameters, shifted by one sample when delayed):
    G[i, j] = S_{i−j} (delayed: S_{i−j−1}, S_{−1} = 0) and f = f_abs + S_i u_prev in both;
    a time-varying one through the augmented state of :func:`_augment`.

    Args:
        Ad: (n, n) or (N, n, n); Bd: (n, m) or (N, n, m); cd: (n,), (N, n) or None.
        C: (p, n); X: (n,) state; u_prev: (m,) u(k−1), or u(k) when delayed (N·m).
        horizons: N, No, Nu. delayed: the one-sample-delay variant.
    """
    Ad, Bd = np.asarray(Ad, dtype=float), np.asarray(Bd, dtype=float)
    C = np.asarray(C, dtype=float)
    X = np.asarray(X, dtype=float)
    u_prev = np.asarray(u_prev, dtype=float)
    m = Bd.shape[-1]
    Nu = horizons.Nu
    n = C.shape[1]
    cd = None if cd is None else np.asarray(cd, dtype=float)
    u_base, u_map = np.broadcast_to(u_prev, (Nu, m)).reshape(-1), cumulative_map(Nu, Nu, m)  # tile, faster
    if Ad.shape == (n, n) and Bd.shape == (n, m) and (cd is None or cd.shape == (n,)) and X.shape == (n,):
        f, H = _lti_responses(Ad, Bd, cd, C, X, horizons.N)
        S = np.cumsum(H, axis=0)  # step response
        f += S @ u_prev
        if delayed:  # B̄ = [0; I]: every Markov parameter of Δu one sample later
            S = np.concatenate([np.zeros_like(S[:1]), S[:-1]])
        G = _toeplitz(S, horizons, hold=False)
        return Prediction(f[horizons.No:].reshape(-1), G, u_base, u_map, horizons, "incremental")
    Aa, Ba, ca = _augment(Ad, Bd, cd, delayed)
    Ca = np.hstack([C, np.zeros((C.shape[0], m))])
    x0 = np.concatenate([X, u_prev])
    f, G = condense(Aa, Ba, ca, Ca, x0, horizons, hold_inputs=False)
    return Prediction(f, G, u_base, u_map, horizons, "incremental")


def deviation_gain(A_seq, B_seq, C, horizons: Horizons) -> np.ndarray:
    """G of the deviation model along a trajectory, eq. (10)–(12): δX(i+1) = A_i δX(i) + B_i δu(i),
    δX(0) = 0, δu(i) = Σ_{l ≤ min(i, Nu−1)} Δu(l), ŷ − ŷ_sim = G [Δu(0) … Δu(Nu−1)] on the
    penalized outputs C δX(j), j = No+1..N.

    The compiled core condenses it in one call (``_native.condense_deviation``, the recursion on
    the deviation state alone); the augmented state of :func:`_augment` through :func:`condense`
    is its reference (``PARALLEL_GPC_NATIVE=0``).

    Args:
        A_seq: (N, n, n), B_seq: (N, n, m): the stage models (one matrix each: the same at every stage).
        C: (p, n) output matrix. horizons: N, No, Nu.

    Returns:
        ((N − No)·p, Nu·m) G.
    """
    A_seq, B_seq = np.asarray(A_seq, dtype=float), np.asarray(B_seq, dtype=float)
    N = horizons.N
    n, m = B_seq.shape[-2], B_seq.shape[-1]
    A_seq, B_seq = _per_step("A_seq", A_seq, N, (n, n)), _per_step("B_seq", B_seq, N, (n, m))
    C = np.asarray(C, dtype=float)
    compiled = compiled_part(None, "condense_deviation", "the compiled deviation gain")
    if compiled is not None and C.ndim == 2 and C.shape[1] == n:
        return compiled(np.ascontiguousarray(A_seq), np.ascontiguousarray(B_seq), np.ascontiguousarray(C),
                        horizons.No, horizons.Nu)
    Aa, Ba, _ = _augment(A_seq, B_seq, None)
    Ca = np.hstack([C, np.zeros((C.shape[0], m))])
    return condense(Aa, Ba, None, Ca, np.zeros(n + m), horizons, hold_inputs=False)[1]


def deviation_response(A_seq, B_seq, C, horizons: Horizons, v) -> np.ndarray:
    """G v of :func:`deviation_gain`'s G without forming G: the deviation model run once from
    δX(0) = 0 with the inputs of v (work linear in N; the Gauss–Newton iterations' steps that the
    Riccati recursion solves need no more of G).

    Args:
        A_seq: (N, n, n), B_seq: (N, n, m): the stage models. C: (p, n) output matrix.
        horizons: N, No, Nu. v: (Nu·m,) increments [Δu(0) … Δu(Nu−1)] (N·m).

    Returns:
        ((N − No)·p,) G v on the penalized outputs (m, rad); ``deviation_gain(...) @ v`` is its
        reference (``PARALLEL_GPC_NATIVE=0``).
    """
    compiled = compiled_part(None, "deviation_response", "the compiled deviation response")
    if compiled is not None:
        return compiled(np.ascontiguousarray(A_seq, dtype=float), np.ascontiguousarray(B_seq, dtype=float),
                        np.ascontiguousarray(C, dtype=float), np.ascontiguousarray(v, dtype=float),
                        horizons.No, horizons.Nu)
    return deviation_gain(A_seq, B_seq, C, horizons) @ v


def simulative_prediction(A_seq, B_seq, C, y_sim, u_sim, horizons: Horizons) -> Prediction:
    """Incremental prediction with nonlinear simulative substitution, eq. (10)–(12).

    Args:
        A_seq: (N, n, n), B_seq: (N, n, m): discrete models along the pre-simulated trajectory
            (at X_sim(k+i), i = 0..N−1).
        C: (p, n) output matrix.
        y_sim: (N, p) pre-simulated outputs ŷ_sim(k+1..k+N).
        u_sim: (N, m) the input sequence of the pre-simulation (N·m).
        horizons: N, No, Nu.

    Returns:
        ŷ = ŷ_sim + G Δu with u(k+i) = u_sim(k+i) + Σ_{j≤i} Δu(k+j), G of :func:`deviation_gain`.
    """
    N, p = horizons.N, np.shape(C)[0]
    G = deviation_gain(A_seq, B_seq, C, horizons)
    y_sim = np.asarray(y_sim, dtype=float)
    if y_sim.shape != (N, p):
        raise ShapeError(f"y_sim has shape {y_sim.shape}; expected {(N, p)}")
    u_sim = np.asarray(u_sim, dtype=float)
    f = y_sim[horizons.No:].reshape(-1)
    m = G.shape[1] // horizons.Nu
    return Prediction(f, G, u_sim.reshape(-1), cumulative_map(N, horizons.Nu, m), horizons, "simulative")
