"""The controller's constrained problems solved stage-wise (``solver="riccati"`` with limits).

The same stage models as the unconstrained Riccati path (:func:`~parallel_gpc.gpc.stages.stage_models`:
z(i+1) = Ā_i z(i) + B̄_i v(i) + c̄_i, ŷ(i) = C̄ z(i) [+ ŷ_sim(i), nonlinear]) and the same criterion
(5), Φ = J + const: Q_i = 2 C̄ᵀ Qyᵀ Qy C̄ on the penalized steps i = No+1..N, R = 2 Quᵀ Qu. The
limits become rows F_i [z(i); v(i)] ≤ f_i of the stage they act on (work linear in N). A problem
whose rows are all input rows (torque and Δu: each acts on one component of v(i)) is solved by
the active set of :mod:`parallel_gpc.solvers.stagewise_active` (one Riccati sweep per change of
the set), any other — and one whose active set does not settle, visibly (the result's message)
— by the interior point of :mod:`parallel_gpc.solvers.stagewise_ipm` (on input rows from a cold start
until its iterate names the active set, :data:`~parallel_gpc.solvers.CROSSOVER`, which the active set
then verifies):

The rows are the ones the condensed layout uses, defined once per kind
(:func:`~parallel_gpc.gpc.criterion.input_rows`, :func:`~parallel_gpc.gpc.constraints.output_rows`);
this module only places them on the stages:

* torque, on u(i): absolute, v(i) = u(i); incremental forms, u(i) = z(i)[n:] + v(i) (the input
  memory plus the increment; the delayed form's stage i bounds u(k+1+i), its memory holding u(k+i):
  u(k), decided at k − 1, is in z(0) and no row); nonlinear, u(i) = u_sim(i) + z(i)[n:] + v(i)
  (v = 0 after Nu);
* du, the box on v(i), i < Nu;
* the output kinds, ŷ(i) = C̄ (Ā z + B̄ v + c̄)(i−1) [+ ŷ_sim(i)] and ŷ(i−1) = C̄ z(i−1)
  [+ ŷ_sim(i−1)] (the measured y(k) on stage 0): a row of stage i − 1; soft kinds get a slack
  s ≥ 0 costing ρ s + SOFT_QUADRATIC·ρ s² (the condensed path's penalty; one slack per side
  instead of one per pair: the same optimum, the two sides never both bind).

From the controller's second step on, the solve starts from the previous solution shifted by one
stage (the active set's rows, :func:`~parallel_gpc.solvers.shift_active_set`; for the incremental
forms and the nonlinear one, :data:`EDGE_FORMS`, with the edges of the limited arcs that moved from step to step moved
again while that brought the last step nearer its set; the interior point's plan, multipliers and
slacks, :class:`~parallel_gpc.solvers.StageStart`, on rows other than input rows).
The nonlinear form's torque rows after Nu (the held deviation plus the pre-simulated input: rows
on the state alone) bound v(Nu−1) through the held input: stage Nu − 1 keeps the tightest of each
side (:func:`input_bounds`), and the active set takes them too.

Not covered (refused by :func:`~parallel_gpc.gpc.settings.resolve_solver`): the drive limits
(drive_position, drive_rate), linearized through the robot's drive Jacobian along the previous
plan — the condensed back ends take them.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ..errors import InvalidParameterError, SolverError
from ..limits import OUTPUT_KINDS, SOFT_QUADRATIC, Limits
from ..model import compiled_part
from ..solvers import (AS_MAX_ITER, AS_WARM_MAX_ITER, CROSSOVER, ActiveSetSolution, InputRowMap, SolveResult, StageQP,
                       StageQPSolution, StageStart, active_set_of, input_rows_of, shift_active_set, solve_active_set,
                       solve_stage_qp, stopped_short)
from .constraints import ACTIVE_TOL, STATE_TOL, ConstraintReport, output_rows
from .criterion import input_rows
from .prediction import Horizons
from .stages import FORM_CODES, stage_models

__all__ = ["StagewiseSolver", "stage_problem", "input_bounds", "step_bounds", "tracking_gradient", "STAGEWISE_KINDS"]

#: the limit kinds the stage-wise path enforces.
STAGEWISE_KINDS = ("torque", "du", "output_box", "output_velocity")
#: the forms whose next active set moves the last step's moving arc edges again
#: (:func:`~parallel_gpc.solvers.shift_active_set` with the set before): their torque rows act on the
#: held input (the nonlinear form's, after Nu, on the held deviation), whose limited arcs grow or shrink
#: smoothly from step to step (planar_4rrr, incremental, N = 160: 3 sweeps a step → 1; nonlinear, N = 80:
#: 3.9 → 1.2–1.7, the pre-simulated inputs' arcs moving by 1–4 stages a step). A moved start that does
#: not settle is followed by the plain shift before the interior point (:meth:`StagewiseSolver._plain_after`).
#: Not the absolute form: its limited inputs switch between the bounds, and a move repeated there costs
#: more sweeps (N = 160: 3–7 → up to 12).
#: At every horizon: the compiled step predicts and checks the move itself (``RiccatiActive.keep``, a few µs;
#: it was kept to Nu ≥ 80 while the rule cost ~30 µs of Python a step). planar_4rrr, Qu = 1e-5, τ = half the
#: free loop's largest |u|: on the replayed states of ``bench_riccati.py --limited`` (incremental, N = 40) the
#: sweeps of 28 warm steps 60 → 50, limited/unconstrained 1.30–1.32 → 1.20–1.22; in each form's own closed loop
#: (N = 10–40, 60 steps) neutral, 1.1–1.3 sweeps a warm step with the rule or without.
EDGE_FORMS = ("incremental", "incremental-delayed", "nonlinear")


def _pair(kind: str, Fz, Fv, const, lo, hi, soft: bool) -> tuple:
    """The two-sided rows lo ≤ Fz z + Fv v + const ≤ hi ((N, k, ·) each, ±inf: unused) as one-sided
    rows [Fz; −Fz] z + [Fv; −Fv] v ≤ [hi − const; const − lo]: (kind, Fz, Fv, f, soft), (N, 2k, ·)."""
    return (kind, np.concatenate([Fz, -Fz], axis=1), np.concatenate([Fv, -Fv], axis=1),
            np.concatenate([hi - const, const - lo], axis=1), soft)


def tracking_gradient(CQ, r, N: int, No: int) -> np.ndarray:
    """The criterion's linear stage terms q (N + 1, nz): −2 C̄ᵀ Qy r(i) on the penalized steps
    i = No+1..N, 0 before. CQ: (nz, p) C̄ᵀ Qy. r: (N − No, p) targets."""
    q = np.zeros((N + 1, CQ.shape[0]))
    q[No + 1:] = -2.0 * np.asarray(r, float) @ CQ.T
    return q


def input_bounds(form: str, limits: Limits, horizons: Horizons, m: int, u_sim=None, u_prev=None) -> list[tuple]:
    """The bounds of the input rows lo ≤ v(i) [+ z(i)[n:]] ≤ hi on the stages: (kind, lo (N, m), hi (N, m))
    per input kind (``"torque"``, ``"du"``) the limits have, ±inf on the unused rows (stages i ≥ Nu).

    The values of :func:`~parallel_gpc.gpc.criterion.input_rows` (the condensed layout's), less what u(i)
    holds besides v and the held input: the nonlinear form's pre-simulated u_sim(i) (its Δu bounds come
    shifted by the drift already). The nonlinear form's torque rows after Nu bound the held deviation,
    u(i) − u_sim(i) = z(i)[n:] = z(Nu−1)[n:] + v(Nu−1) for i ≥ Nu: every row of the stages i ≥ Nu − 1
    acts on v(Nu−1) alike, and stage Nu − 1 keeps the tightest of each side (the same feasible set, and
    rows on a decision: the active set's).

    Args:
        form: the controller's form. limits: sized to the m drives, input kinds tightened by the margin.
        horizons: N, Nu. u_sim: (N, m) pre-simulated inputs (nonlinear form, N·m). u_prev: (m,) u(k−1)
            (nonlinear Δu, N·m).
    """
    N, Nu = horizons.N, horizons.Nu
    nonlinear = form == "nonlinear"
    rows = input_rows(limits, "absolute" if form == "absolute" else "simulative" if nonlinear else "incremental",
                      Nu, N if nonlinear else Nu, u_sim, u_prev)
    bounds = []
    if rows.torque is not None:
        hi = np.full((N, m), np.inf)
        hi[:Nu] = rows.torque[:Nu]
        lo = -hi
        if nonlinear:
            u_sim = np.asarray(u_sim, float)
            hi[:Nu] -= u_sim[:Nu]
            lo[:Nu] -= u_sim[:Nu]
            hi[Nu - 1] = np.min(rows.torque[Nu - 1:] - u_sim[Nu - 1:], axis=0)
            lo[Nu - 1] = np.max(-rows.torque[Nu - 1:] - u_sim[Nu - 1:], axis=0)
        bounds.append(("torque", lo, hi))
    if rows.du_lo is not None:  # a box on v(i), i < Nu
        lo, hi = np.full((N, m), -np.inf), np.full((N, m), np.inf)
        lo[:Nu], hi[:Nu] = rows.du_lo, rows.du_hi
        bounds.append(("du", lo, hi))
    return bounds


def step_bounds(limits: Limits, horizons: Horizons, u_sim, u_prev=None) -> np.ndarray:
    """The nonlinear form's input-row bounds f (N, k) of one step in the stage layout: per input kind
    the limits have (torque, then du), the columns [hi, −lo] of :func:`input_bounds` (the rows
    [v; −v] [+ z[n:]] ≤ f of :func:`stage_problem`), inf on the unused rows (stages i ≥ Nu).

    :func:`input_bounds` is the reference; this is the same numbers written straight into one array
    (the compiled limited step passes them every step: they move with the pre-simulated inputs). The
    tightest torque rows after Nu on stage Nu − 1: min_i (τ − u_sim(i)) = τ − max_i u_sim(i) (rounding
    is monotone: the same float). The entries of the stages i < Nu are finite (the limits are).

    Args:
        limits: sized to the m drives, input kinds tightened by the margin. horizons: N, Nu.
        u_sim: (N, m) pre-simulated inputs (N·m). u_prev: (m,) u(k−1) (N·m), needed with a du limit.
    """
    N, Nu = horizons.N, horizons.Nu
    tau, delta = limits.torque, limits.du
    u_sim = np.asarray(u_sim, float)
    m = u_sim.shape[1]
    f = np.full((N, 2 * m * ((tau is not None) + (delta is not None))), np.inf)
    u = u_sim[:Nu]
    col = 0
    if tau is not None:
        np.subtract(tau, u, out=f[:Nu, :m])
        np.add(tau, u, out=f[:Nu, m:2 * m])
        tail = u_sim[Nu - 1:]
        np.subtract(tau, tail.max(axis=0), out=f[Nu - 1, :m])
        np.add(tau, tail.min(axis=0), out=f[Nu - 1, m:2 * m])
        col = 2 * m
    if delta is not None:
        if u_prev is None:
            raise InvalidParameterError("the nonlinear form's du limit is measured from u(k−1): pass u_prev")
        drift = np.empty_like(u)  # u_sim(i) − u_sim(i−1), u_sim(−1) = u(k−1)
        np.subtract(u[0], u_prev, out=drift[0])
        np.subtract(u[1:], u[:-1], out=drift[1:])
        np.subtract(delta, drift, out=f[:Nu, col:col + m])
        np.add(delta, drift, out=f[:Nu, col + m:col + 2 * m])
    return f


def stage_problem(form: str, Ab, Bb, cb, Cz, z0, r, Wy, Wu, horizons: Horizons, limits: Limits, Ts: float,
                  y_now, y_sim=None, u_sim=None, u_prev=None, out_rows=None) -> tuple[StageQP, np.ndarray]:
    """The :class:`~parallel_gpc.solvers.StageQP` of one step (see the module docstring): the rows of
    :func:`~parallel_gpc.gpc.criterion.input_rows` and :func:`~parallel_gpc.gpc.constraints.output_rows`
    (the definitions the condensed layout uses) placed on the stages they act on.

    Args:
        form: the controller's form. Ab, Bb, cb, Cz, z0: :func:`~parallel_gpc.gpc.stages.stage_models`.
        r: (N − No, p) targets (nonlinear: w − ŷ_sim). Wy (p, p), Wu (m, m): square-root weights.
        horizons: N, No, Nu. limits: sized to the drives and outputs, input kinds tightened by the
            controller's margin. Ts: sample time (s). y_now: (p,) measured output y(k) (m, rad).
        y_sim: (N, p) pre-simulated outputs ŷ_sim(k+1..k+N) (nonlinear form), else None.
        u_sim: (N, m) pre-simulated inputs (nonlinear form). u_prev: (m,) u(k−1) (nonlinear du).
        out_rows: ``output_rows(limits, horizons, Ts, p)`` when the caller keeps it (they depend on neither
            the state nor the step), else None.

    Returns:
        (the problem, kinds (k,) object array: the limit kind of each row column, the same on every stage).
    """
    H = horizons
    N, No, Nu = H.N, H.No, H.Nu
    nz, m, p = Ab.shape[1], Bb.shape[2], Cz.shape[0]
    CQ = Cz.T @ (Wy.T @ Wy)
    Q = np.zeros((N + 1, nz, nz))
    Q[No + 1:] = 2.0 * CQ @ Cz
    q = tracking_gradient(CQ, r, N, No)
    decided = (np.arange(N) < Nu)[:, None, None]  # v(i) exists on the stages i < Nu
    blocks = []
    for kind, lo, hi in input_bounds(form, limits, H, m, u_sim, u_prev):
        Fz, Fv = np.zeros((N, m, nz)), np.zeros((N, m, m))
        Fv[:Nu] = np.eye(m)
        if kind == "torque" and form != "absolute":  # u(i) = z(i)[n:] + v(i) [+ u_sim(i), in the bounds]
            Fz[:Nu, :, nz - m:] = np.eye(m)
        blocks.append(_pair(kind, Fz, Fv, np.zeros((N, m)), lo, hi, False))
    out_rows = output_rows(limits, H, Ts, p) if out_rows is None else out_rows
    if out_rows:
        # ŷ(i) = C̄ Ā z(i−1) + C̄ B̄ v(i−1) + C̄ c̄(i−1) [+ ŷ_sim(i)], a row of stage i − 1, whose own
        # ŷ(i−1) = C̄ z(i−1) [+ ŷ_sim(i−1)] (stage 0: the measured y(k))
        CA, CB = Cz @ Ab, (Cz @ Bb) * decided
        y_next = cb @ Cz.T + (0.0 if y_sim is None else y_sim)
        P = np.empty((N, p, nz))
        P[:] = Cz
        P[0] = 0.0
        y_cur = np.zeros((N, p))
        y_cur[0] = y_now
        if y_sim is not None:
            y_cur[1:] = y_sim[:N - 1]
        for b in out_rows:
            st = slice(b.first - 1, N)  # the stages of the row blocks
            k = b.cur.shape[1]
            Fz, Fv, const = np.zeros((N, k, nz)), np.zeros((N, k, m)), np.zeros((N, k))
            lo, hi = np.full((N, k), -np.inf), np.full((N, k), np.inf)
            Fz[st] = b.cur @ CA[st]
            Fv[st] = b.cur @ CB[st]
            const[st] = (b.cur @ y_next[st, :, None])[..., 0] + b.offset
            if b.prev is not None:
                Fz[st] += b.prev @ P[st]
                const[st] += (b.prev @ y_cur[st, :, None])[..., 0]
            lo[st], hi[st] = b.lo, b.hi
            blocks.append(_pair(b.kind, Fz, Fv, const, lo, hi, b.soft))
    if blocks:
        kinds = np.concatenate([np.full(b[1].shape[1], b[0], dtype=object) for b in blocks])
        Fz = np.concatenate([b[1] for b in blocks], axis=1)
        Fv = np.concatenate([b[2] for b in blocks], axis=1)
        f = np.concatenate([b[3] for b in blocks], axis=1)
        soft = np.concatenate([np.full(b[1].shape[1], b[4]) for b in blocks])
    else:
        kinds, Fz, Fv, f, soft = np.empty(0, dtype=object), np.zeros((N, 0, nz)), np.zeros((N, 0, m)), \
            np.zeros((N, 0)), np.zeros(0, bool)
    rho = limits.penalty
    soft_rows = np.empty(f.shape, bool)
    soft_rows[:] = soft
    qp = StageQP(Ab, Bb, cb, z0, Q, q, 2.0 * Wu.T @ Wu, Nu, Fz, Fv, f, soft_rows, rho, 2.0 * SOFT_QUADRATIC * rho)
    return qp, kinds


def _bound_scale(f: np.ndarray) -> float:
    """The largest |bound| of the used (finite) rows f (N, k), at least 1e-12: the scale of the active
    set's row excess in its KKT residual."""
    return max(float(np.max(np.abs(f[np.isfinite(f)]), initial=0.0)), 1e-12)


class StagewiseSolver:
    """Stage-wise solve of one controller's constrained problem (active set or interior point).

    Args:
        Wy: (p, p) and Wu: (m, m) square-root weights (Wu nonsingular). C: (p, n) the model's output
            matrix. horizons: N, No, Nu. form: the controller's form. limits: sized to the drives
            and outputs (input kinds tightened by the controller's margin). Ts: sample time (s).
        native: None = the compiled ``_native.stagewise_active``, ``_native.RiccatiActive`` and
            ``_native.stagewise_ipm`` when available, False = the Python references
            :func:`~parallel_gpc.solvers.solve_active_set` and :func:`~parallel_gpc.solvers.solve_stage_qp`,
            True = compiled or raise.

    A problem of input rows alone (torque, Δu; every form) is solved in ONE compiled call per step
    (``_native.RiccatiActive``: the stage models, the criterion's linear terms, the active set and J
    built and solved without a :class:`~parallel_gpc.solvers.StageQP`; the nonlinear form's bounds,
    which move with the pre-simulated inputs, passed each step: :func:`step_bounds`); the problem is
    formed in Python only when the interior point takes over.

    Attributes:
        method: what solved the last problem: ``"active-set"``, ``"interior-point"`` (rows other
            than input rows) or ``"interior-point after active set"`` (the set did not settle).
        iterations: the last solve's (active-set sweeps, interior-point iterations), 0 when unused.
        excess: how far the last solution's rows may exceed their bounds, in the rows' units (N·m for
            torque and Δu rows), as the active set's own KKT verification bounds it (residual × the
            largest bound: the residual is at least the largest excess over the largest bound);
            inf when it did not verify it (the interior point, a failed solve): the caller checks.
    """

    name = "riccati"

    def __init__(self, Wy, Wu, C, horizons: Horizons, form: str, limits: Limits, Ts: float,
                 native: bool | None = None):
        self.Wy, self.Wu = np.asarray(Wy, float), np.asarray(Wu, float)
        self.C = np.ascontiguousarray(C, dtype=float)
        self.horizons, self.form, self.limits, self.Ts = horizons, form, limits, Ts
        self._compiled = compiled_part(native, "stagewise_ipm", "the compiled stage-wise interior point")
        self._compiled_active = compiled_part(native, "stagewise_active", "the compiled stage-wise active set")
        self._compiled_step = compiled_part(native, "RiccatiActive", "the compiled limited step")
        self.native = self._compiled is not None and self._compiled_active is not None
        self._step = None  # the compiled RiccatiActive of a problem of input rows (built on the first step)
        self._out_shape: tuple = ()  # ((Nu, m), k): the shapes of its plan and set, the columns of its λ
        self._last: StageQPSolution | None = None  # the last solution (the next step's warm start)
        self._fixed: np.ndarray | None = None  # the last active set (the next step's, shifted)
        self._before: np.ndarray | None = None  # the set of the step before the last (EDGE_FORMS), or None
        # the last step's starts (the plain shift, the one with the edges moved or None) and whether the moved
        # edges start this step: they do while the last step's solution was nearer the moved start than the plain one
        self._starts: tuple | None = None
        self._edges = False
        self._moves_edges = form in EDGE_FORMS  # the edges' start is tried
        # the first step's problem when only its models, targets (and the nonlinear form's bounds) change from
        # step to step (input rows alone: Q, the rows and their bounds are the limits' and the weights'), its kinds
        self._template: tuple | None = None
        self._rows: tuple | None = None  # (the used rows (N, k), their InputRowMap or None): the same every step
        self.method, self.iterations, self.excess = "", (0, 0), np.inf
        self._unsettled: tuple | None = None  # (message, iterations) of a compiled step whose set did not settle
        self._output_rows = output_rows(limits, horizons, Ts, self.Wy.shape[0])  # the same every step

    def _start(self, qp: StageQP, last: StageQPSolution | None) -> StageStart | None:
        """The last solution shifted by one stage (the interior point's warm start), or None: v(i) ←
        v(i+1) (absolute: the last held; the increments of the incremental forms: 0 at the end; the
        nonlinear form's deviation from a new pre-simulation: the unconstrained plan), λ and s likewise."""
        if last is None or last.lam.shape != qp.f.shape or last.v.shape[0] != qp.n_decide:
            return None
        v = None
        if self.form != "nonlinear":
            v = np.concatenate([last.v[1:], last.v[-1:] if self.form == "absolute" else np.zeros_like(last.v[-1:])])

        def shifted(a):
            return np.concatenate([a[1:], a[-1:]])

        return StageStart(v, shifted(last.lam), np.zeros_like(last.lam) if last.s is None else shifted(last.s))

    def _next_start(self) -> np.ndarray | None:
        """The active set's start from the last step's set: shifted, or (:data:`EDGE_FORMS`, while that
        paid on the last step) with its moving edges moved again
        (the Python path's; the compiled step's own start is this rule compiled, :meth:`_keep_set`)."""
        plain, moved = shift_active_set(self._fixed), None
        if self._moves_edges and self._before is not None:
            moved = shift_active_set(self._fixed, self._before)
        self._starts = (plain, moved)
        return moved if self._edges and moved is not None else plain

    def _plain_after(self, start: np.ndarray | None) -> np.ndarray | None:
        """The plain shift of this step's starts (:meth:`_next_start`) when ``start`` was the moved
        edges' one and differs from it, else None: the start to try next when the moved one did not
        settle, before the interior point (a mispredicted move: planar_4rrr, nonlinear, N = 160, a
        step of 12 sweeps and 27 interior-point iterations that the plain shift settles in 3)."""
        if self._starts is None or start is None:
            return None
        plain, moved = self._starts
        return plain if moved is not None and start is moved and not np.array_equal(plain, moved) else None

    def _keep_set(self, fixed: np.ndarray | None, warm: bool) -> None:
        """Keep ``fixed`` (the step's active set, or None) as the next step's, the last one as the set
        before (warm: a step after the last; else None), and whether the next step starts from the
        moved edges: when this step's set is at most half as far (components differing) from its moved
        start as from the plain shift (an edge moving steadily; not one that turns back or moves every
        other step, nor sets changing all along the horizon: planar_4rrr, nonlinear, N = 160, moved
        4 and 8 components off where the plain shift was 7, a moved start that then failed to settle).

        With the compiled step (``_native.RiccatiActive``) the compiled step keeps the set and decides
        the next start (``keep``, this rule compiled: its warm solves start from there and fall back to
        the plain shift, :meth:`_plain_after`'s; the ~20 µs of Python per step that these rules cost
        here, half of the glue of a limited step: planar_4rrr, incremental, N = 80)."""
        if self._step is not None:
            self._step.keep(None if fixed is None else np.ascontiguousarray(fixed, np.int64), warm)
            self._before, self._fixed, self._starts, self._edges = (self._fixed if warm else None), fixed, None, False
            return
        plain, moved = self._starts if warm and self._starts is not None else (None, None)
        if fixed is not None and moved is not None:
            off_moved, off_plain = np.count_nonzero(moved != fixed), np.count_nonzero(plain != fixed)
            self._edges = off_plain > 0 and 2 * off_moved <= off_plain
        else:
            self._edges = False
        self._before, self._fixed, self._starts = (self._fixed if warm else None), fixed, None

    def _input_rows(self, qp: StageQP) -> InputRowMap | None:
        """:func:`~parallel_gpc.solvers.input_rows_of` ``qp``, formed again only when the used rows
        change (the rows' Fz, Fv and softness are the limits', the same every step)."""
        used = np.isfinite(qp.f)
        if self._rows is None or not np.array_equal(used, self._rows[0]):
            self._rows = (used, input_rows_of(qp) if qp.S is None else None)
        return self._rows[1]

    def _active(self, qp: StageQP, rows: InputRowMap, start: np.ndarray | None):
        """The active-set solve (compiled, or the Python reference)."""
        if self._compiled_active is None:
            return solve_active_set(qp, rows, start)
        c = np.ascontiguousarray
        try:
            v, z, lam, fixed, iterations, ok, residual, message = self._compiled_active(
                c(qp.A, float), c(qp.B, float), c(qp.c, float), c(qp.z0, float), c(qp.Q, float), c(qp.q, float),
                c(qp.R, float), qp.n_decide, c(qp.Fz, float), c(qp.f, float), c(rows.comp, np.int64),
                c(rows.sign, float), None if start is None else c(start, np.int64),
                AS_MAX_ITER if start is None else AS_WARM_MAX_ITER)
        except RuntimeError as exc:
            raise SolverError(str(exc)) from None
        return ActiveSetSolution(v, z, np.zeros(qp.f.shape), lam, None, iterations,
                                 "optimal" if ok else "unconverged", residual, message, fixed)

    def _solve(self, qp: StageQP, start: StageStart | None, crossover: float = 0.0) -> StageQPSolution:
        """The compiled interior point, or the Python reference (``crossover``: see :func:`solve_stage_qp`)."""
        if self._compiled is None:
            return solve_stage_qp(qp, start=start, crossover=crossover)
        try:
            c = np.ascontiguousarray
            v, z, s, lam, iterations, ok, merit = self._compiled(
                c(qp.A, float), c(qp.B, float), c(qp.c, float), c(qp.z0, float), c(qp.Q, float), c(qp.q, float),
                c(qp.R, float), qp.n_decide, c(qp.Fz, float), c(qp.Fv, float), c(qp.f, float), c(qp.soft, bool),
                qp.rho, qp.kappa, np.zeros(0) if qp.S is None else c(qp.S, float),
                *((None, None, None) if start is None else
                  (None if start.v is None else c(start.v, float), c(start.lam, float), c(start.s, float))),
                crossover)
        except RuntimeError as exc:
            raise SolverError(str(exc)) from None
        status, message = ("crossover", "") if merit <= crossover else ("optimal", "") if ok else \
            stopped_short(qp, z, v, iterations, merit)
        return StageQPSolution(v, z, s, lam, None, iterations, status, merit, message)

    def _interior(self, qp: StageQP, rows: InputRowMap | None, last: StageQPSolution | None):
        """The interior point where the active set did not settle (or alone: rows other than input
        rows, warm-started from ``last``): (its solution, its iterations, the active set's sweeps after it).

        On input rows it starts cold and stops at :data:`~parallel_gpc.solvers.CROSSOVER`; the active
        set then starts from the set the iterate's multipliers name and verifies it (its KKT
        conditions; 1–5 sweeps measured). A set that does not settle there: the interior point goes on
        from its iterate to its own tolerance (its solution; the sweeps counted)."""
        if rows is None:
            sol = self._solve(qp, self._start(qp, last))
            return sol, sol.iterations, 0
        cross = self._solve(qp, None, CROSSOVER)
        if cross.status != "crossover":
            return cross, cross.iterations, 0
        sol = self._active(qp, rows, active_set_of(qp, rows, cross.lam))
        if sol.status == "optimal":
            return sol, cross.iterations, sol.iterations
        rest = self._solve(qp, StageStart(cross.v, cross.lam, cross.s))
        return rest, cross.iterations + rest.iterations, sol.iterations

    def _failed(self, t0: float, message: str) -> SolveResult:
        """A failed solve's result: a NaN plan (Nu·m,), J = inf, the reason; t0: its start (perf_counter)."""
        n_v = self.horizons.Nu * self.Wu.shape[0]
        return SolveResult(np.full(n_v, np.nan), np.inf, "failed", self.name, None, time.perf_counter() - t0, False,
                           message)

    def _step_bounds(self, u_sim, u_prev) -> np.ndarray | None:
        """The input rows' bounds f (N, k) of this step where they change from step to step (the
        nonlinear form's: they move with the pre-simulated inputs), else None (the limits' own)."""
        return None if self.form != "nonlinear" else step_bounds(self.limits, self.horizons, u_sim, u_prev)

    def _solve_step(self, step: tuple, r, warm: bool, t0: float, f: np.ndarray | None,
                    start: np.ndarray | None = None) -> SolveResult | None:
        """The compiled limited step of input rows (``_native.RiccatiActive``), f: the step's bounds of
        :meth:`_step_bounds` or None, start: a set to start from as it is (:meth:`solve`) or None: its
        SolveResult, or None when the active set did not settle (the caller hands the problem to the
        interior point; the last solution, kept for its warm start, is left in place).

        The step's arrays go to the compiled call as they are (it reads any C-contiguous float64 array
        of the right size in place; others are converted on the way in), a warm start is chosen there
        from the set it keeps (:meth:`_next_start` and :meth:`_plain_after`, compiled), and it writes the
        plan, multipliers and set into arrays made here (cheaper than the ones it would hand over):
        nothing else is built here but the result."""
        A, B, c, x0, u0 = step
        # from a set of this control step (its last Gauss–Newton step's) as it is, cold, or warm: the compiled
        # step's start from the set it keeps (:meth:`_keep_set`; :meth:`_next_start` and :meth:`_plain_after`)
        from_kept = start is None and warm and self._fixed is not None
        cap = AS_MAX_ITER if start is None and not from_kept else AS_WARM_MAX_ITER
        self.excess = np.inf
        (Nu, m), k = self._out_shape
        v, lam, fixed = np.empty((Nu, m)), np.empty((self.horizons.N, k)), np.empty((Nu, m), np.int64)
        try:
            _, J, _, _, iterations, ok, residual, message = self._step.solve(A, B, c, x0, u0, r, start, cap, f,
                                                                             from_kept, v, lam, fixed)
        except RuntimeError as exc:
            self._last = None
            self._keep_set(None, False)
            return self._failed(t0, str(exc))
        self.iterations = (iterations, 0)
        if not ok:
            self._unsettled = (message, self.iterations)
            return None
        self.method = "active-set"
        self._keep_set(fixed, warm)
        compiled = self._step
        self.excess = residual * compiled.f_scale  # the largest bound of the used rows (this step's)
        self._last = StageQPSolution(v, None, None, lam, None, iterations, "optimal", residual)  # s: no slacks
        return SolveResult(v.reshape(-1), J, "optimal", self.name, iterations, time.perf_counter() - t0,
                           compiled.active, "")

    @property
    def active_set(self) -> np.ndarray | None:
        """The active set the last solve ended on ((Nu, m) ints: the row each input component is held on,
        −1 where free; the interior point's active rows when it solved), or None (no solve yet, a failed
        one, rows other than input rows): a ``start`` of :meth:`solve`."""
        return self._fixed

    def solve(self, step: tuple, r, y_now, y_sim=None, u_sim=None, u_prev=None, warm: bool = False,
              start: np.ndarray | None = None, bounds: np.ndarray | None = None
              ) -> tuple[SolveResult, ConstraintReport | None]:
        """(the plan v (Nu·m,) as a SolveResult, what the state limits did or None without them).

        Args:
            step: (A, B, c, x0, u0) of :meth:`~parallel_gpc.gpc.riccati.RiccatiSolver.solve` (the
                arguments of :func:`~parallel_gpc.gpc.stages.stage_models`).
            r, y_now, y_sim, u_sim, u_prev: as in :func:`stage_problem`.
            warm: start from the last solution shifted by one stage (a controller's next step),
                else from the unconstrained plan.
            start: an active set to start from as it is, in place of ``warm``'s (:attr:`active_set`
                of a solve of the same rows: the last Gauss–Newton step of the same control step), or None.
            bounds: the nonlinear form's input-row bounds (N, k) of this step, :func:`step_bounds` of
                u_sim and u_prev, when the caller keeps them (the same in every Gauss–Newton step of a
                control step), else None: computed here.

        Returns:
            status ``optimal`` (``active_limits`` when a row binds), ``infeasible`` (hard limits
            that cannot all hold: the message names the row) or ``failed``.
        """
        t0 = time.perf_counter()
        H = self.horizons
        self.excess = np.inf
        f = bounds if bounds is not None or self._template is None else self._step_bounds(u_sim, u_prev)
        if self._step is not None:
            result = self._solve_step(step, r, warm, t0, f, start)
            if result is not None:
                return result, None
        models = stage_models(self.form, *step[:3], self.C, *step[3:], H)
        Ab, Bb, cb, Cz, z0 = models
        if self._template is not None:
            template, kinds, CQ = self._template
            qp = replace(template, A=Ab, B=Bb, c=cb, z0=z0, q=tracking_gradient(CQ, r, H.N, H.No),
                         f=template.f if f is None else f)
        else:
            qp, kinds = stage_problem(self.form, Ab, Bb, cb, Cz, z0, r, self.Wy, self.Wu, H, self.limits, self.Ts,
                                      y_now, y_sim, u_sim, u_prev, self._output_rows)
            if not self._output_rows:  # input rows alone: only the models, targets (and nonlinear bounds) change
                self._template = (qp, kinds, Cz.T @ (self.Wy.T @ self.Wy))
                rows = self._input_rows(qp)
                if rows is not None and self._compiled_step is not None and self._compiled_active is not None:
                    self._step = self._compiled_step(
                        self.C, self.Wy, self.Wu, H.N, H.No, H.Nu, FORM_CODES[self.form], qp.Fz, qp.f,
                        np.ascontiguousarray(rows.comp, np.int64), rows.sign, self._moves_edges)
                    self._out_shape = ((H.Nu, self.Wu.shape[0]), qp.f.shape[1])  # v and the set, λ's columns
                    result = self._solve_step(step, r, warm, t0, None if self.form != "nonlinear" else qp.f, start)
                    if result is not None:
                        return result, None
        rows = self._input_rows(qp)
        last, self._last = self._last if warm else None, None
        kept = None  # the next step's set
        try:
            sol, self.method, self.iterations = None, "interior-point", (0, 0)
            if self._unsettled is not None:  # the compiled step's set did not settle: straight to the interior point
                self.method, fell_back, self.iterations = "interior-point after active set", *self._unsettled
                self._unsettled = None
            elif rows is not None:
                fixed_start = start if start is not None else self._next_start() if warm else None
                sol = self._active(qp, rows, fixed_start)
                plain = None if sol.status == "optimal" else self._plain_after(fixed_start)
                if plain is not None:  # the moved edges' start did not settle: the plain shift's next
                    swept, sol = sol.iterations, self._active(qp, rows, plain)
                    sol.iterations += swept
                self.iterations = (sol.iterations, 0)
                if sol.status == "optimal":
                    self.method, kept = "active-set", sol.fixed
                else:
                    self.method, fell_back = "interior-point after active set", sol.message
            if sol is None or sol.status != "optimal":
                sol, ipm, swept = self._interior(qp, rows, last)
                self.iterations = (self.iterations[0] + swept, ipm)
                if rows is not None and sol.status == "optimal":  # its active rows start the next step's set
                    kept = sol.fixed if isinstance(sol, ActiveSetSolution) else active_set_of(qp, rows, sol.lam)
        except SolverError as exc:
            self._keep_set(None, False)
            return self._failed(t0, str(exc)), None
        self._keep_set(kept, warm)
        if sol.status == "optimal":
            self._last = sol
        v = sol.v.reshape(-1)
        e = (np.asarray(r, float) - sol.z[H.No + 1:] @ Cz.T) @ self.Wy.T
        J = float(np.sum(e * e) + np.sum((sol.v @ self.Wu.T) ** 2))
        if self.method == "active-set":  # input rows only (no state report), their KKT conditions verified
            self.excess = sol.residual * _bound_scale(qp.f)
            return SolveResult(v, J, "optimal", self.name, sol.iterations, time.perf_counter() - t0,
                               bool((sol.fixed >= 0).any()), ""), None
        used = np.isfinite(qp.f)
        F_x = np.einsum("ikn,in->ik", qp.Fz, sol.z[:-1])
        F_x[:H.Nu] += np.einsum("ikm,im->ik", qp.Fv[:H.Nu], sol.v)
        f = np.where(used, qp.f, 0.0)
        gap = np.where(used, f + sol.s - F_x, np.inf)
        active = used & (gap <= ACTIVE_TOL * (1.0 + np.abs(f)))
        state = used & np.isin(kinds, OUTPUT_KINDS)
        report = None
        if state.any():
            slack = {str(kd): float(np.max(sol.s[state & (kinds == kd) & qp.soft], initial=0.0))
                     for kd in OUTPUT_KINDS if (state & (kinds == kd) & qp.soft).any()}
            binding = np.broadcast_to(kinds, used.shape)[active & state]
            report = ConstraintReport(tuple(sorted({str(kd) for kd in binding})), slack)
        status = {"optimal": "optimal", "unconverged": "failed"}.get(sol.status, "infeasible")
        message = "" if status == "optimal" else sol.message
        if self.method == "interior-point after active set":
            message = f"{fell_back}: solved by the interior point" + (f"; {message}" if message else "")
        hard_excess = float(np.max(np.where(used & ~qp.soft, F_x - f, 0.0), initial=0.0))
        if status == "optimal" and hard_excess > STATE_TOL * (1.0 + float(np.max(np.abs(f), initial=0.0))):
            status, message = "infeasible", f"a hard limit is exceeded by {hard_excess:.3g} (infeasible)"
        return SolveResult(v, J, status, self.name, sum(self.iterations), time.perf_counter() - t0,
                           bool(active.any()), message), report
