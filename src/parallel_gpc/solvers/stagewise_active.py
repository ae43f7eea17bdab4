"""Stage-wise primal-dual active-set method for linear-quadratic problems with input rows.

The reference (Python) twin of the compiled ``_native.stagewise_active``; it knows nothing about
GPC. The problem is a :class:`~parallel_gpc.solvers.stagewise_ipm.StageQP` whose every used row
is hard and acts on ONE input component (an *input row*: a torque or Δu limit of a controller),

    σ_r v_j(i) + Fz_r z(i) ≤ f_r,   σ_r = ±1,   i < n_decide        (row r of stage i, on component j)

(Fz_r = 0 for a box on v; a selector of the held input for the incremental forms' torque rows).
An active row fixes its component, v_j(i) = σ_r (f_r − Fz_r z(i)): affine in the state, so the
problem with a fixed active set is again an LQ problem — with state–input cross terms and
fewer free inputs — solved by ONE Riccati sweep (:func:`_sweep`: v = E_i z + e_i on the fixed
components, the free ones v_F = K_i z + k_i). The multipliers of the active rows follow from
the costates in one backward pass (:func:`~parallel_gpc.solvers.stagewise_ipm.costates` with the
set): λ_r = −σ_r ∂L/∂v_j(i).

A set that differs from the last full sweep's (the *base*) in at most :data:`SCHUR_MAX` components
is not swept again (:func:`_sweep_update`): the plan of the new set is the base plan plus a
combination of its *responses* (:func:`_response`, one per parameter: an offset θ of a component the
base fixes, v_j(i) = E z + e + θ, and a force θ (σ_r v_j(i) + Fz_r z(i)) in the cost for a component
the new set fixes by row r, each the base's Riccati recursion on vectors only: its gains and factors
kept), the parameters solved from the new set's equations on the changed components (their rows hold,
the freed ones are stationary: a Schur complement of SCHUR_MAX × 2 at most). Exact as the sweep (the
new set's optimum lies on that affine family); a response costs the vector passes of one recursion,
about a tenth of a sweep's matrix products, and is kept for the later sweeps of the solve against the
same base (planar_4rrr, incremental, N = 160: the warm steps of 3 sweeps take one full sweep and 2
updates; measured in ``benchmarks/README.md``, round 17). A singular system, or more changes, take a
full sweep, which becomes the base.

The active set is updated as a primal-dual active set (Hintermüller–Ito–Kunisch): a component
stays fixed while its multiplier is ≥ 0 and no other row on it is broken; a free component whose
rows are broken is fixed by its most broken row; a fixed one whose multiplier turned negative is
freed. The iterations stop when that update would keep the set — the KKT conditions (primal
feasibility, λ ≥ 0, stationarity of the free components, complementarity by construction) are
then verified, not trusted — or when a set comes back (a cycle) or the cap is reached: status
``"unconverged"``, for the caller to hand the problem to the interior point.

A component held by a box row (on v alone, Fz_r = 0: the absolute form's torque, a Δu) whose stages
before and after the same row holds stays fixed whatever its multiplier: a limited arc is left only
at its edges (:func:`_inside_box_arcs`) while an edge moves; once none does, the inner ones with a
negative multiplier are freed as without the rule (:func:`_next_set`).

The full update changes every component at once; with most inputs on a limit (planar_4rrr,
absolute, N = 160: 637 of 640) it swings without settling (the few free inputs pass far beyond
their bounds between sweeps: 3 changes, then 30, 61, 34, … on a warm start). A *cautious* update
then takes over for the rest of the solve: the components whose rows are broken are fixed, every
other one kept; only when no row is broken are components with negative multipliers freed, the
most negative first — one on the first such sweep, twice as many after frees that broke no row,
half as many after frees that did (a primal active set drops one row per iteration; freeing all
at once is the full update's swing). It takes over once the full update proposes a set seen
before or — from a start — no fewer changes than on the sweep before (N = 160 warm steps then
settle in 1–7 sweeps instead of none in 8). Not from a cold start: there the full update's
changes shrink unevenly on the way (N = 80, most inputs limited: 10–17 sweeps), the cautious one
would pay for each wrongly fixed row (over 30 sweeps). A set that still does not settle is
accepted when the last sweep's KKT residual is within :data:`AS_ACCEPT` (multipliers at 0
toggling), else reported unconverged.

Not every input-row problem has an optimal set of one row per component: torque and Δu rows of
the incremental forms binding together on one component pin the held input (a row on the state),
and the set then cycles: reported unconverged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from ..errors import SolverError
from .stagewise_ipm import StageQP, StageQPSolution, costates

__all__ = ["InputRowMap", "ActiveSetSolution", "input_rows_of", "shift_active_set", "active_set_of", "solve_active_set",
           "AS_MAX_ITER", "AS_WARM_MAX_ITER", "AS_TOL", "AS_ACCEPT"]

#: iteration cap (Riccati sweeps); a problem still changing its active set after it is unconverged. A cold
#: start takes 4–19 sweeps on the controller's torque-limited problems up to N = 80 (planar_4rrr); at
#: N = 160 with 637 of 640 inputs on their limits it does not settle in 400: the interior point solves
#: that first step and its active rows start the next. Measured there (planar_4rrr, Qu = 1e-5, every form,
#: the cold step and the warm one after the interior point's) and not settling either: block principal
#: pivoting with a backup count and then the k most violated changes (k halved or doubled), a projected
#: Newton step along the sweep's plan with the rows clipped, flipping a fixed component with λ < 0 to its
#: other bound, a start from every component on its nearer bound, a continuation over the rows of the
#: first 10/20/40/80 stages (settles up to 40–80, not beyond), a proximal term ρ‖v − v_k‖² (84–88 sweeps
#: at best) and the interior point's set after 4–10 of its iterations. With Qu = 1e-3 the cold absolute
#: and incremental steps settle (4 and 20 sweeps). The 30 sweeps cost 2.7 ms (absolute) and 10.7 ms
#: (incremental, nonlinear) of CPU beside the interior point's 9.8 and 21.7 ms there.
AS_MAX_ITER = 30
#: the cap from a start (the previous step's set shifted): a start settles in 1–12 sweeps (mean 1.5–3.7 up
#: to N = 80, ~4.5 at N = 160, planar_4rrr; 3–10 on the random problems of the tests); one that has not
#: by this many goes to the interior point without the full cap's cost.
AS_WARM_MAX_ITER = 12
#: the set's tolerance: a row broken by more than AS_TOL × the largest bound, or a multiplier below
#: −AS_TOL × the gradient's scale, changes the active set (the settled set meets both).
AS_TOL = 1e-10
#: the settled set's solution is accepted when its KKT residual (the largest of the rows' excess
#: over the largest bound, the multipliers' negative part and the free components' Lagrangian
#: gradient over the gradient's scale) is at most this, the interior point's acceptance: the sweep's
#: rounding leaves a free-component gradient of 2e-10–2e-8 of the scale (R v and Bᵀν cancel;
#: planar_4rrr, Qu = 1e-5, N = 10–20); the excess and the signs already hold to AS_TOL once the set settles.
AS_ACCEPT = 1e-6
#: a settled set is also accepted when its multipliers' negative part and its free components' gradient are within
#: AS_ROUNDING of the terms they sum (:func:`_terms_scale`): the rounding of a gradient whose terms cancel. Measured:
#: a five-bar with an (x, z) output in metres, incremental, N = 100, Qu = 1e-4 on a line (a point mass, a massless
#: link): q and Q z cancel in the costates to 5e-6 of their 0.86, R v and Bᵀν are 2e-10, the free gradient 3e-16:
#: 1.6e-6 of the gradient's scale (rejected: the step went to the condensed back end) and 8e-17 of its terms.
AS_ROUNDING = 1e-12
#: the shortest arc (consecutive stages one box row holds) kept while its edges move
#: (:func:`_inside_box_arcs`): a short arc may flip to the opposite bound whole (planar_4rrr, N = 12,
#: arcs of 5–7 stages: 4 sweeps freeing them at once, 12 and unsettled peeled stage by stage); 8–16
#: measure alike on the long horizons' arcs.
ARC_MIN_STAGES = 10


@dataclass(frozen=True)
class InputRowMap:
    """Which component each row of a :class:`StageQP` acts on.

    Attributes:
        comp: (N, k) int, the component j of v(i) the row acts on; −1 on an unused row.
        sign: (N, k) σ_r = ±1 (0 on an unused row).
    """

    comp: np.ndarray
    sign: np.ndarray


@dataclass
class ActiveSetSolution(StageQPSolution):
    """A :class:`StageQPSolution` (``lam`` ≥ 0 on the active rows, 0 elsewhere; ``s`` = 0) and its set.

    Attributes:
        fixed: (n_decide, m) int, the row fixing each component (−1: free): the next step's start,
            shifted by one stage.
    """

    fixed: np.ndarray | None = None


def input_rows_of(qp: StageQP) -> InputRowMap | None:
    """The :class:`InputRowMap` of ``qp``, or None when a used row is soft, on a stage without a
    decision, or not of the form σ v_j + Fz z ≤ f with σ = ±1 (the interior point's problems)."""
    used = np.isfinite(qp.f)
    N, k = qp.f.shape
    if not used.any():
        return InputRowMap(np.full((N, k), -1), np.zeros((N, k)))
    nd = qp.n_decide
    if (qp.soft & used).any() or used[nd:].any():
        return None
    Fv = qp.Fv[:nd]
    nonzero = Fv != 0.0
    one = nonzero.sum(axis=2) == 1
    sign = Fv.sum(axis=2)
    if not np.all(one[used[:nd]]) or not np.all(np.abs(sign[used[:nd]]) == 1.0):
        return None
    comp = np.full((N, k), -1)
    comp[:nd] = np.where(used[:nd], np.argmax(nonzero, axis=2), -1)
    sgn = np.zeros((N, k))
    sgn[:nd] = np.where(used[:nd], sign, 0.0)
    return InputRowMap(comp, sgn)


def _sweep(qp: StageQP, rows: InputRowMap, fixed: np.ndarray, keep: list | None = None):
    """The plan (z (N + 1, nz), v (n_decide, m)) of the LQ problem with the components ``fixed``
    (n_decide, m: the row fixing each, −1 free) held on their rows: one Riccati sweep.

    Raises:
        SolverError: the free inputs' Hessian is not positive definite (R not ≻ 0, non-finite data).
    """
    N, nd = qp.A.shape[0], qp.n_decide
    nz, m = qp.A.shape[1], qp.R.shape[0]
    gains = [None] * nd
    P, p = qp.Q[N], qp.q[N]
    Ps, ps, facs = [None] * (N + 1), [None] * (N + 1), [None] * nd
    Ps[N], ps[N] = P, p
    for i in range(N - 1, -1, -1):
        A, c = qp.A[i], qp.c[i]
        PA, w = P @ A, P @ c + p
        Pz, lin = qp.Q[i] + A.T @ PA, qp.q[i] + A.T @ w
        if i < nd:
            B = qp.B[i]
            PB = P @ B
            Hvv, gv = qp.R + B.T @ PB, B.T @ w
            Hvz = PB.T @ A if qp.S is None else PB.T @ A + qp.S
            E, e = np.zeros((m, nz)), np.zeros(m)
            fix = fixed[i] >= 0
            r = fixed[i][fix]
            E[fix] = -rows.sign[i, r][:, None] * qp.Fz[i, r]
            e[fix] = rows.sign[i, r] * qp.f[i, r]
            if fix.any():  # v = E z + e on the fixed components, substituted
                Hz, gv = Hvz + Hvv @ E, gv + Hvv @ e
                Pz = Pz + E.T @ Hvz + Hz.T @ E
                lin = lin + Hvz.T @ e + E.T @ gv
            else:
                Hz = Hvz
            free = ~fix
            K, k = np.zeros((0, nz)), np.zeros(0)
            if free.any():
                try:
                    fac = sla.cho_factor(Hvv[np.ix_(free, free)], check_finite=True)
                except (np.linalg.LinAlgError, ValueError) as exc:
                    raise SolverError(f"stage-wise active set: the free inputs' Hessian R + BᵀPB at stage {i} is "
                                      f"not positive definite (the input weight Qu must be nonsingular; {exc})") from None
                Hwz = Hz[free]
                K, k = -sla.cho_solve(fac, Hwz, check_finite=False), -sla.cho_solve(fac, gv[free], check_finite=False)
                Pz, lin = Pz + Hwz.T @ K, lin + Hwz.T @ k
                facs[i] = fac
            gains[i] = (free, K, k, E, e)
        P, p = 0.5 * (Pz + Pz.T), lin
        Ps[i], ps[i] = P, p
    z = np.empty((N + 1, nz))
    v = np.empty((nd, m))
    z[0] = qp.z0
    for i in range(N):
        z[i + 1] = qp.A[i] @ z[i] + qp.c[i]
        if i < nd:
            free, K, k, E, e = gains[i]
            v[i] = E @ z[i] + e
            v[i, free] = K @ z[i] + k
            z[i + 1] += qp.B[i] @ v[i]
    if keep is not None:
        keep[:] = [fixed.copy(), gains, Ps, ps, facs, z, v, {}]
    return z, v


#: the most components a set may differ in from the last full sweep's to be taken from it by
#: :func:`_sweep_update` (each a response of the vector passes of one recursion, ~15–20 µs compiled at
#: N = 160 against ~130 µs for the sweep: 12 and 24 measured no better on the N = 160 closed loops, 24
#: worse)
SCHUR_MAX = 6


def _response(qp: StageQP, rows: InputRowMap, base, i: int, j: int, r: int):
    """The change of the base set's plan (z (N + 1, nz), v) and of its p (N + 1, nz) per unit parameter at
    component j of v(i): r < 0 an offset, v_j(i) = E z + e + θ (j fixed in the base); r ≥ 0 a force on
    row r, θ (σ_r v_j(i) + Fz_r z_i) added to the cost (the row's multiplier)."""
    fixed, gains, Ps, ps, facs = base[:5]
    N, nd = qp.A.shape[0], qp.n_decide
    nz, m = qp.A.shape[1], qp.R.shape[0]
    pd = np.zeros((N + 1, nz))
    kd = {}
    ed = np.zeros(m)
    w = np.zeros(nz)
    for s in range(i, -1, -1):
        A, B = qp.A[s], qp.B[s]
        free, K, k, E, e = gains[s]
        lin, gv = A.T @ w, B.T @ w
        if s == i and r >= 0:
            gv[j] += rows.sign[i, r]
            lin = lin + qp.Fz[i, r]
        if s == i and r < 0:
            ed[j] = 1.0
            PB = Ps[s + 1] @ B
            Hvv = qp.R + B.T @ PB
            Hvz = PB.T @ A if qp.S is None else PB.T @ A + qp.S
            gv = gv + Hvv @ ed
            lin = lin + Hvz.T @ ed + E.T @ gv
        elif (~free).any():
            lin = lin + E.T @ gv
        if free.any():
            kd[s] = -sla.cho_solve(facs[s], gv[free], check_finite=False)
            lin = lin + K.T @ gv[free]
        pd[s] = lin
        w = lin
    z = np.zeros((N + 1, nz))
    v = np.zeros((nd, m))
    for s in range(N):
        z[s + 1] = qp.A[s] @ z[s]
        if s < nd:
            free, K, k, E, e = gains[s]
            v[s] = E @ z[s]
            if s == i:
                v[s] += ed
            v[s, free] = K @ z[s] + kd.get(s, 0.0)
            z[s + 1] += qp.B[s] @ v[s]
    return z, v, pd


def _sweep_update(qp: StageQP, rows: InputRowMap, base, fixed: np.ndarray):
    """The plan of the set ``fixed`` from the base set's factorization (its last full sweep) and its
    responses (:func:`_response`) to one parameter per changed component fixed in the base (an offset) and
    one per changed component fixed by a row now (a force on that row): the equations those rows and the
    freed components' stationarity impose, solved for the parameters (the Schur complement). None: too many
    changes, more than 2·SCHUR_MAX responses against this base, or a singular system (then a full sweep)."""
    bfixed, gains, Ps, ps, facs, z0, v0, cache = base
    changed = [(int(i), int(j)) for i, j in np.argwhere(fixed != bfixed)]
    if not changed or len(changed) > SCHUR_MAX:
        return None
    params = [(i, j, -1) for i, j in changed if bfixed[i, j] >= 0]
    params += [(i, j, int(fixed[i, j])) for i, j in changed if fixed[i, j] >= 0]
    if len(cache) + sum(key not in cache for key in params) > 2 * SCHUR_MAX:
        return None  # as many responses as about one sweep costs: a full sweep, a new base
    resp = []
    for key in params:
        if key not in cache:
            cache[key] = _response(qp, rows, base, *key)
        resp.append(cache[key])
    pb = np.asarray(ps)

    def stationarity(i, j, z, v, p):  # the v-gradient of component j at stage i
        g = qp.R[j] @ v[i] + qp.B[i][:, j] @ (Ps[i + 1] @ z[i + 1] + p[i + 1])
        return g + qp.S[j] @ z[i] if qp.S is not None else g

    def row(i, j, r, z, v):  # the value of row r
        return rows.sign[i, r] * v[i, j] + qp.Fz[i, r] @ z[i]

    n = len(params)
    G, c0 = np.zeros((n, n)), np.zeros(n)
    eq = 0
    for i, j in changed:
        if bfixed[i, j] >= 0:  # stationary in v_j(i) with the forces on its rows
            c0[eq] = stationarity(i, j, z0, v0, pb)
            for b, ((zd, vd, pd), (ib, jb, rb)) in enumerate(zip(resp, params)):
                G[eq, b] = stationarity(i, j, zd, vd, pd) + (rows.sign[i, rb] if (ib, jb) == (i, j) and rb >= 0 else 0.0)
            eq += 1
        if fixed[i, j] >= 0:
            r = int(fixed[i, j])
            c0[eq] = row(i, j, r, z0, v0) - qp.f[i, r]
            for b, (zd, vd, pd) in enumerate(resp):
                G[eq, b] = row(i, j, r, zd, vd)
            eq += 1
    try:
        theta = np.linalg.solve(G, -c0)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(theta)):
        return None
    z, v = z0.copy(), v0.copy()
    for t, (zd, vd, pd) in zip(theta, resp):
        z += t * zd
        v += t * vd
    return z, v


def _update(rows: InputRowMap, fixed: np.ndarray, lam, broken, tol_lam: float, frees: int | None = None,
            inner: np.ndarray | None = None) -> np.ndarray:
    """The next active set (n_decide, m): per component, its most broken row if one is broken,
    else the row fixing it while its multiplier is ≥ −tol_lam or it lies inside an arc of a box
    (``inner``, :func:`_inside_box_arcs`), else free. ``broken``: (n_decide, k),
    how far each row is broken beyond the tolerance (≤ 0: held). ``frees`` (the cautious update):
    the components with a broken row fixed by it, every other one as it is; only when no row is
    broken, at most ``frees`` of the components whose multiplier is below −tol_lam freed (the most
    negative ones)."""
    nd, m = fixed.shape
    comp = rows.comp[:nd]
    on = comp[:, None, :] == np.arange(m)[None, :, None]  # (nd, m, k): row r acts on component j
    viol = np.where(on, broken[:, None, :], -np.inf)
    worst = np.argmax(viol, axis=2)
    is_broken = np.take_along_axis(viol, worst[..., None], axis=2)[..., 0] > 0.0
    held = fixed >= 0
    lam_fixed = np.where(held, np.take_along_axis(lam[:nd], np.maximum(fixed, 0), axis=1), 0.0)
    keep = held & (lam_fixed >= -tol_lam)
    if inner is not None:
        keep |= inner
    if frees is None:
        return np.where(is_broken, worst, np.where(keep, fixed, -1))
    if is_broken.any():
        return np.where(is_broken, worst, fixed)
    new = fixed.copy()
    negative = np.flatnonzero(held & ~keep)
    new.flat[negative[np.argsort(lam_fixed.flat[negative], kind="stable")[:frees]]] = -1
    return new


def _next_set(rows: InputRowMap, fixed: np.ndarray, lam, broken, tol_lam: float, frees: int | None,
              inner: np.ndarray) -> np.ndarray:
    """:func:`_update` with the arcs' inner components ``inner`` kept, or without that rule when it
    would keep the set as it is (the arcs' edges hold, their inside does not: freed as before)."""
    new = _update(rows, fixed, lam, broken, tol_lam, frees, inner)
    if inner.any() and np.array_equal(new, fixed):
        new = _update(rows, fixed, lam, broken, tol_lam, frees)
    return new


def _inside_box_arcs(fixed: np.ndarray, box: np.ndarray) -> np.ndarray:
    """(n_decide, m) the components held by a box row (``box`` (n_decide, k): the row's Fz = 0) whose
    stages before and after are held by the same row, in an arc of at least :data:`ARC_MIN_STAGES`
    stages: inside a limited arc, which only its edges leave.

    An arc on a box of v (the absolute form's torque, a Δu) shrinks from its edges: after a change at
    one end, the multipliers of the whole arc beyond it can turn negative together (they carry the
    costate along the arc), and freeing them all swings the plan past the opposite bounds (planar_4rrr,
    absolute, N = 160: 30, then 90–108 changes proposed on warm steps that end 2 components from their
    start). Kept, the arc's edges free one stage per sweep at each end, and the inner multipliers
    still negative once the edges hold are freed then (:func:`_next_set`): warm steps there take 1–5
    sweeps instead of 1–7 and none goes to the interior point (1 of 12 did). Not rows on the state
    (the incremental forms' torque on the held input: the arcs there are not those of v, and keeping
    them costs sweeps)."""
    nd = fixed.shape[0]
    held = (fixed >= 0) & np.take_along_axis(box[:nd], np.maximum(fixed, 0), axis=1)
    same = np.zeros_like(held)
    same[1:-1] = (fixed[:-2] == fixed[1:-1]) & (fixed[2:] == fixed[1:-1])
    start = np.ones(fixed.shape, bool)
    start[1:] = fixed[1:] != fixed[:-1]
    length = np.empty(fixed.shape, int)
    for j in range(fixed.shape[1]):
        run = np.cumsum(start[:, j])
        length[:, j] = np.bincount(run)[run]
    return held & same & (length >= ARC_MIN_STAGES)


def shift_active_set(fixed: np.ndarray | None, before: np.ndarray | None = None) -> np.ndarray | None:
    """A previous step's set (n_decide, m) shifted by one stage (the last stage repeated), or None.

    With ``before``, the set (n_decide, m) of the step before that one, the edges of the limited
    arcs that moved from step to step (``fixed`` against ``before`` shifted) are moved again by as
    many stages (:func:`_extrapolate_edges`): an arc that grows or shrinks by a few stages per step
    (the held input of the incremental forms reaching its torque limit earlier and earlier) costs
    the plain shift one sweep per stage of the move, every step (planar_4rrr, incremental, N = 160:
    3 sweeps a step, 1 with the edges moved).
    """
    if fixed is None or fixed.shape[0] == 0:
        return None
    shifted = np.concatenate([fixed[1:], fixed[-1:]])
    if before is None or before.shape != fixed.shape:
        return shifted
    return _extrapolate_edges(fixed, np.concatenate([before[1:], before[-1:]]), shifted)


def _extrapolate_edges(fixed: np.ndarray, was: np.ndarray, shifted: np.ndarray) -> np.ndarray:
    """``shifted`` (``fixed`` shifted by one stage) with every moved edge moved again.

    A *moved edge*: a run of consecutive stages of one component where ``fixed`` differs from
    ``was`` (the set it was solved from, or the step before's shifted), all with one value r (a
    row, or −1: free), next on one side only to a stage that held r in both — the arc (or the
    free stretch) r grew into the run. Its next move, of the run's length in the same direction,
    is predicted: those stages (in the shifted frame) set to r while they hold what lay beyond the
    run. A wrong prediction costs sweeps, not accuracy (the active set corrects the set and
    verifies its KKT conditions)."""
    nd = fixed.shape[0]
    out = shifted.copy()
    # the changed entries (few: a step's set moves by a stage or two) as (component, stage), in that order
    changed = [divmod(c, nd) for c in np.flatnonzero((fixed != was).T).tolist()]
    a = 0
    while a < len(changed):
        j, s = changed[a]
        r, e = fixed.item(s, j), s
        a += 1
        while a < len(changed) and changed[a] == (j, e + 1) and fixed.item(e + 1, j) == r:
            e, a = e + 1, a + 1
        length = e - s + 1
        grew_later = s > 0 and fixed.item(s - 1, j) == r and was.item(s - 1, j) == r
        grew_earlier = e + 1 < nd and fixed.item(e + 1, j) == r and was.item(e + 1, j) == r
        if grew_later == grew_earlier:  # no side or both: not an edge
            continue
        if grew_later:  # the next stages after the run (at s − 1 … e − 1 once shifted)
            if e + 1 >= nd:
                continue
            beyond, targets = fixed.item(e + 1, j), range(e, min(e + length, nd))
        else:
            if s == 0:
                continue
            beyond, targets = fixed.item(s - 1, j), range(s - 2, max(s - 2 - length, -1), -1)
        for t in targets:
            if out.item(t, j) != beyond:
                break
            out[t, j] = r
    return out


def active_set_of(qp: StageQP, rows: InputRowMap, lam: np.ndarray) -> np.ndarray:
    """The active set (n_decide, m) that another solver's multipliers λ (N, k) indicate (the interior
    point's, to start the next step): per component the row with the largest λ, where that λ is above
    1e-6 of the largest one; the others free."""
    nd, m = qp.n_decide, qp.R.shape[0]
    on = rows.comp[:nd, None, :] == np.arange(m)[None, :, None]  # (nd, m, k)
    weight = np.where(on, lam[:nd, None, :], -np.inf)
    best = np.argmax(weight, axis=2)
    top = np.take_along_axis(weight, best[..., None], axis=2)[..., 0]
    return np.where(top > 1e-6 * max(float(np.max(lam, initial=0.0)), 1e-300), best, -1)


def _valid(fixed: np.ndarray, rows: InputRowMap) -> np.ndarray:
    """``fixed`` with the entries that name no used row on their component freed (−1)."""
    nd, m = fixed.shape
    k = rows.comp.shape[1]
    r = np.clip(fixed, 0, k - 1)
    named = np.take_along_axis(rows.comp[:nd], r, axis=1) == np.arange(m)
    return np.where((fixed >= 0) & (fixed < k) & named, fixed, -1)


def solve_active_set(qp: StageQP, rows: InputRowMap, start: np.ndarray | None = None,
                     max_iter: int | None = None, tol: float = AS_TOL) -> ActiveSetSolution:
    """Solve a :class:`StageQP` of input rows (:func:`input_rows_of`) by the primal-dual active set.

    Args:
        qp: the problem. rows: its :func:`input_rows_of`. start: (n_decide, m) a guess of the active
            set, the row fixing each component or −1 (:func:`shift_active_set` of the previous step's;
            an entry naming no used row on its component is freed), or None: the unconstrained
            plan's broken rows. max_iter: Riccati sweeps at most (None: :data:`AS_MAX_ITER` cold,
            :data:`AS_WARM_MAX_ITER` from a start). tol: :data:`AS_TOL`.

    Returns:
        status ``"optimal"`` (the KKT conditions verified: residual ≤ :data:`AS_ACCEPT`) or ``"unconverged"``
        (a cycle or the cap; the message says which): then hand ``qp`` to the interior point.

    Raises:
        SolverError: a free inputs' Hessian that is not positive definite.
    """
    N, nd = qp.A.shape[0], qp.n_decide
    m = qp.R.shape[0]
    used = np.isfinite(qp.f)
    f = np.where(used, qp.f, 0.0)
    f_scale = max(float(np.max(np.abs(f[used]), initial=0.0)), 1e-12)
    fixed = np.full((nd, m), -1) if start is None else _valid(np.asarray(start, dtype=int), rows)
    if max_iter is None:
        max_iter = AS_MAX_ITER if start is None else AS_WARM_MAX_ITER
    seen = set()
    box = np.all(qp.Fz == 0.0, axis=2)  # (N, k): the rows of v alone
    fewest, frees, freed = nd * m + 1, None, False  # frees: None while the full update runs
    base = []
    for it in range(1, max_iter + 1):
        upd = _sweep_update(qp, rows, base, fixed) if base else None
        if upd is None:
            z, v = _sweep(qp, rows, fixed, base)
        else:
            z, v = upd
        lam = np.zeros(qp.f.shape)
        nu, grad = costates(qp, z, v, lam, active=(rows.comp, rows.sign, fixed))
        # the gradient's scale: the largest entry of R v and Bᵀ ν(i+1) (they cancel at the optimum)
        scale = max(float(np.max(np.abs(v @ qp.R.T), initial=0.0)),
                    float(np.max(np.abs(np.einsum("imk,im->ik", qp.B[:nd], nu[1:nd + 1])), initial=0.0)), 1e-300)
        Fx = np.einsum("ikn,in->ik", qp.Fz, z[:N])
        Fx[:nd] += np.einsum("ikm,im->ik", qp.Fv[:nd], v)
        gap = np.where(used, Fx - f, -np.inf)
        inner = _inside_box_arcs(fixed, box)
        new = _next_set(rows, fixed, lam, gap[:nd] - tol * f_scale, tol * scale, None, inner)
        def kkt_residual(gradient_scale: float) -> float:  # the rows' excess, λ's negative part, the free gradient
            return max(float(np.max(gap, initial=0.0)) / f_scale, float(np.max(-lam, initial=0.0)) / gradient_scale,
                       float(np.max(np.abs(grad), initial=0.0)) / gradient_scale)

        residual = kkt_residual(scale)
        if np.array_equal(new, fixed):
            if residual > AS_ACCEPT:  # or rounding: the gradient's scale at least AS_ROUNDING / AS_ACCEPT of its terms'
                residual = kkt_residual(max(scale, AS_ROUNDING / AS_ACCEPT * _terms_scale(qp, z, v, lam)))
            status = "optimal" if residual <= AS_ACCEPT else "unconverged"
            message = "" if status == "optimal" else (
                f"stage-wise active set: the set settled with a KKT residual {residual:.3g} above {AS_ACCEPT:g}")
            return ActiveSetSolution(v, z, np.zeros(qp.f.shape), lam, nu, it, status, residual, message, fixed)
        # the full update while it proposes no set seen before and (from a start) fewer changes each sweep,
        # then the cautious one: one component freed per sweep, twice as many after frees that broke no
        # row, half as many after frees that did
        n_changed = int(np.count_nonzero(new != fixed))
        if frees is None and ((start is not None and n_changed >= fewest) or new.tobytes() in seen):
            frees = 1
        fewest = min(fewest, n_changed)
        if frees is not None:
            broken = gap[:nd] - tol * f_scale
            any_broken = bool(np.any(broken > 0.0))
            if freed:
                frees = max(1, frees // 2) if any_broken else 2 * frees
            new, freed = _next_set(rows, fixed, lam, broken, tol * scale, frees, inner), not any_broken
            if new.tobytes() in seen:
                return _unsettled(v, z, lam, nu, it, residual, fixed,
                                  f"stage-wise active set: the active set cycles after {it} sweeps")
        seen.add(fixed.tobytes())
        swept, fixed = fixed, new
    return _unsettled(v, z, lam, nu, max_iter, residual, swept,
                      f"stage-wise active set: not converged in {max_iter} sweeps (KKT residual {residual:.3g})")


def _terms_scale(qp: StageQP, z, v, lam) -> float:
    """The largest term the v-gradient R v(i) + Bᵢᵀ ν(i+1) sums, in absolute values: |R||v| and |Bᵢ|ᵀ ν̄(i+1), ν̄ the
    costates' recursion on absolute values (ν̄_N = |Q_N||z_N| + |q_N|, ν̄_i = |Q_i||z_i| + |q_i| + |A_i|ᵀ ν̄_{i+1} +
    |Fz_i|ᵀ|λ_i|): what the gradient's rounding is relative to when its terms cancel."""
    N, nd = qp.A.shape[0], qp.n_decide
    nb = np.abs(qp.Q[N]) @ np.abs(z[N]) + np.abs(qp.q[N])
    scale = float(np.max(np.abs(v) @ np.abs(qp.R).T, initial=0.0))
    for i in range(N - 1, -1, -1):
        if i < nd:
            scale = max(scale, float(np.max(np.abs(qp.B[i]).T @ nb, initial=0.0)))
        nb = np.abs(qp.Q[i]) @ np.abs(z[i]) + np.abs(qp.q[i]) + np.abs(qp.A[i]).T @ nb + np.abs(qp.Fz[i]).T @ np.abs(lam[i])
        if qp.S is not None and i < nd:
            nb = nb + np.abs(qp.S).T @ np.abs(v[i])
    return scale


def _unsettled(v, z, lam, nu, iterations: int, residual: float, fixed, message: str) -> ActiveSetSolution:
    """The last sweep's solution (of the set ``fixed``) when the set did not settle: accepted all the
    same when its KKT residual is at most :data:`AS_ACCEPT` (rows whose multipliers hover at 0 toggling
    in and out), else ``"unconverged"`` with ``message``."""
    ok = residual <= AS_ACCEPT
    return ActiveSetSolution(v, z, np.zeros(lam.shape), lam, nu, iterations, "optimal" if ok else "unconverged",
                             residual, "" if ok else message, fixed)
