"""The controller's unconstrained problems solved by the Riccati recursion (``solver="riccati"``,
the default where it gives QR's minimizer: :func:`~parallel_gpc.gpc.settings.default_solver`).

The criterion (5) of every form is a linear-quadratic tracking problem of a state-space model
over the horizon; instead of condensing it into ŷ = f + G v (eq. (7)–(12)) and solving the
square-root system (15)–(19) by QR, the Riccati recursion of
:func:`parallel_gpc.solvers.riccati.lq_tracking` solves it stage by stage (work linear in N).
Stage models z(i+1) = Ā_i z(i) + B̄_i v(i) + c̄_i, output ŷ = C̄ z, C̄ = [C 0]:

* absolute (7), v = u: z = x and (Ā, B̄, c̄) = (A_d, B_d, c_d) when Nu = N; with Nu < N the
  input is held in the state, z = [x; u_h]: Ā = [[A_d, 0], [0, 0]], B̄ = [B_d; I] while
  deciding (i < Nu), then Ā = [[A_d, B_d], [0, I]] with no decision (u held);
* incremental (8)–(9), v = Δu: z = [x; u(k−1)] (the base without its null(B_d) part),
  Ā = [[A_d, B_d], [0, I]], B̄ = [B_d; I], Δu = 0 after Nu;
* incremental-delayed: z = [x; u(k)], B̄ = [0; I];
* nonlinear (10)–(12): the deviation model along the pre-simulation, z = [δx; δu] from 0,
  Ā_i = [[A_i, B_i], [0, I]], B̄_i = [B_i; I], no affine term, targets w − ŷ_sim.

Compiled, the nonlinear form's unconstrained step is one call: the model update's pre-simulation,
the deviation stages and the recursion (``_native.riccati_presimulated``,
:meth:`RiccatiSolver.presimulated`); the model's ``simulate_factorized`` followed by
:meth:`RiccatiSolver.solve` (compiled or :func:`~parallel_gpc.solvers.riccati.lq_tracking`) is its reference.
Its limited step takes the pre-simulation and null(B_d(X)) in one compiled call too
(``_native.presimulated_stages``: ``simulate_factorized``'s arrays, contiguous), then the compiled active set.

The minimizer equals the QR back end's whenever it is unique: Qu nonsingular (R = QuᵀQu ≻ 0).
With limits (torque, Δu, output box and velocity) the same stage models feed the stage-wise
active set (input limits) or interior point of :mod:`parallel_gpc.gpc.stagewise`. Not covered (a clear
:class:`~parallel_gpc.errors.InvalidParameterError` when requested): Qu singular (redundant
drives need the minimum-norm QR answer) and the drive limits (drive_position, drive_rate).
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import InvalidParameterError, SolverError
from ..limits import Limits
from ..model import compiled_part, cached_identity
from ..solvers import SolveResult, lq_tracking
from ..validation import read_only
from .prediction import Horizons, Prediction, cumulative_map
from .redundancy import NULL_RTOL
from .stages import FORM_CODES, stage_models
from .stagewise import StagewiseSolver

__all__ = ["RiccatiPath", "RiccatiSolver", "stage_models", "FORM_CODES"]

class RiccatiSolver:
    """Riccati solve of one controller's unconstrained problem (compiled when available).

    Args:
        Wy: (p, p) and Wu: (m, m) square-root weights (Wu nonsingular).
        C: (p, n) output matrix.
        horizons: N, No, Nu. form: the controller's form.
        native: None = the compiled ``_native.Riccati`` when it is available, False = the Python
            reference :func:`~parallel_gpc.solvers.riccati.lq_tracking`, True = compiled or raise.

    Raises:
        InvalidParameterError: Qu singular (the minimizer is not unique: use ``solver="qr"``),
            or native=True without the compiled core.
    """

    name = "riccati"

    def __init__(self, Wy, Wu, C, horizons: Horizons, form: str, native: bool | None = None):
        Wu = np.asarray(Wu, float)
        sv = np.linalg.svd(Wu, compute_uv=False)
        if not sv.size or not sv.min() > 1e-12 * max(1.0, sv.max()):
            raise InvalidParameterError(
                f"solver 'riccati' needs a nonsingular input weight Qu (R = QuᵀQu ≻ 0); Qu has singular values "
                f"{np.round(sv, 12).tolist()}: use solver 'qr' (its minimum-norm answer avoids drive fighting)")
        if form not in FORM_CODES:
            raise InvalidParameterError(f"form {form!r} is not one of {tuple(FORM_CODES)}")
        self.Wy, self.Wu, self.C = np.asarray(Wy, float), Wu, np.ascontiguousarray(C, dtype=float)
        self.horizons, self.form = horizons, form
        Riccati = compiled_part(native, "Riccati", "the compiled Riccati solve")
        self._compiled = None
        if Riccati is not None:
            H = horizons
            self._compiled = Riccati(self.C, self.Wy, Wu, H.N, H.No, H.Nu, FORM_CODES[form])
        self.native = self._compiled is not None
        # the nonlinear form's pre-simulation and recursion in one call (a core without it: two calls)
        self._presimulated = None if self._compiled is None or form != "nonlinear" else compiled_part(
            None, "riccati_presimulated", "the compiled nonlinear step")
        m = Wu.shape[0]
        self._zero_c, self._zero_u = read_only(np.zeros(self.C.shape[1])), read_only(np.zeros(m))  # per controller

    def solve(self, A, B, c, x0, u0, r) -> SolveResult:
        """The plan v (Nu·m,) of the form's problem.

        Args:
            A: (n, n) or (N, n, n) (N·n rows when compiled); B: (n, m) or (N, n, m);
                c: (n,), (N, n) or None: the model (absolute and incremental: A_d, B_d, c_d at X;
                nonlinear: A_i, B_i along the pre-simulation).
            x0: (n,) state. u0: (m,) the input held in the state (incremental forms), else ignored.
            r: (N − No, p) targets (w; nonlinear: w − ŷ_sim).

        Returns:
            SolveResult with status ``unconstrained`` and J of the criterion (5), or ``failed``
            (the message says why) when R + BᵀPB is not positive definite or v is not finite.
        """
        t0 = time.perf_counter()
        n, m = self.C.shape[1], self.Wu.shape[0]
        try:
            if self._compiled is not None:
                cc = self._zero_c if c is None else np.asarray(c, float)
                v, J = self._compiled.solve(np.asarray(A, float).reshape(-1, n), np.asarray(B, float).reshape(-1, m),
                                            cc.reshape(-1), x0, self._zero_u if u0 is None else u0, r)
            else:
                Ab, Bb, cb, Cz, z0 = stage_models(self.form, A, B, c, self.C, x0, u0, self.horizons)
                v, J = lq_tracking(Ab, Bb, cb, Cz, z0, r, self.Wy, self.Wu, self.horizons.No, self.horizons.Nu)
        except (SolverError, RuntimeError) as exc:
            n_v = self.horizons.Nu * m
            return SolveResult(np.full(n_v, np.nan), np.inf, "failed", self.name, None, time.perf_counter() - t0,
                               False, str(exc))
        return SolveResult(v, J, "unconstrained", self.name, None, time.perf_counter() - t0, False, "")

    @property
    def fuses_presimulation(self) -> bool:
        """True when :meth:`presimulated` is available (the nonlinear form, compiled)."""
        return self._presimulated is not None

    def presimulated(self, update, X0, u_seq, Ts: float, offset, w) -> tuple:
        """The nonlinear form's pre-simulation (10) and the plan along it in one compiled call
        (``_native.riccati_presimulated``): the model's ``simulate_factorized``, then :meth:`solve`
        with r = w − ŷ_sim, which stay the reference.

        Args:
            update: the model's compiled model update (``ReducedModel.compiled_update``).
            X0: (n,) state; u_seq: (N, m) inputs of the pre-simulation (N·m); Ts: sample time (s);
                offset: (n,) added to every step (the disturbance estimate) or None.
            w: (N − No, p) reference rows (m and rad).

        Returns:
            (sim, result, inputs, null): sim = (A_seq (N, n, n), B_seq (N, n, m), c_seq (N, n),
            X_seq (N + 1, n)) as ``simulate_factorized``; the :meth:`solve` SolveResult of the
            deviation model; inputs (N, m) = u_seq + the cumulative Δu of the plan (N·m); null the
            :func:`~parallel_gpc.gpc.redundancy.null_basis` of B_seq[0] (None at full column rank,
            False when not computed: B_seq[0] not finite).
        """
        t0 = time.perf_counter()
        E, X_seq, v, J, message, inputs, null = self._presimulated(self._compiled, update, X0, u_seq, Ts, offset, w,
                                                                   NULL_RTOL)
        n, m = self.C.shape[1], self.Wu.shape[0]
        sim = (E[:, :, :n], E[:, :, n:n + m], E[:, :, -1], X_seq)
        status = "failed" if message else "unconstrained"
        return sim, SolveResult(v, J, status, self.name, None, time.perf_counter() - t0, False, message), inputs, \
            _null_result(null)


def _null_result(null):
    """The null(B_d(X)) rows a compiled pre-simulation returned as :meth:`GPCController.presimulate`
    takes them: the rows, None at full column rank, False (not computed) when B_d was not finite (None)."""
    return False if null is None else null if null.shape[0] else None


class RiccatiPath:
    """A controller's ``solver="riccati"``: the step's stage data without condensing, the solve,
    and the input map u = u_base + u_map v the controller's bookkeeping uses.

    Args:
        criterion: the controller's :class:`~parallel_gpc.gpc.criterion.Criterion`.
        C: (p, n) output matrix of the model. form: the controller's form.
        native: as in :class:`RiccatiSolver`.
        limits: the controller's limits sized to its drives and outputs, input kinds tightened
            by its margin (None or no limit: the unconstrained recursion). Ts: sample time (s),
            needed with limits.

    Attributes:
        report: what the state limits did in the last constrained solve (None without them).

    Raises:
        InvalidParameterError: Qu singular (see :class:`RiccatiSolver`).
    """

    def __init__(self, criterion, C, form: str, native: bool | None = None, limits: Limits | None = None,
                 Ts: float | None = None):
        Wy, Wu = criterion.weights.blocks(criterion.n_outputs, criterion.n_inputs)
        self.solver = RiccatiSolver(Wy, Wu, C, criterion.horizons, form, native)
        self.form, self.horizons, self.m = form, criterion.horizons, criterion.n_inputs
        self.constrained = None if limits is None or not limits.needs_qp else StagewiseSolver(
            Wy, Wu, C, criterion.horizons, form, limits, Ts, native)
        self.report = None
        self._u_sim = None
        self._extra = {}
        H, m = self.horizons, self.m  # the input map's parts that do not change from step to step
        self._empty = (read_only(np.empty(0)), read_only(np.empty((0, H.Nu * m))))
        self._u_map = cached_identity(H.Nu * m) if form == "absolute" else cumulative_map(
            H.N if form == "nonlinear" else H.Nu, H.Nu, m)
        self._zero_base = read_only(np.zeros(H.Nu * m))
        self._planned = None  # (A_seq, SolveResult, inputs) of the last fused nonlinear step, taken by solve()
        # the limited nonlinear step's pre-simulation with null(B_d) in one call (compiled; else the model's)
        self._stages_call = None if form != "nonlinear" or self.constrained is None or not self.constrained.native \
            else compiled_part(None, "presimulated_stages", "the compiled pre-simulation")
        self._solved = (None, None)  # (SolveResult, inputs) that solve() returned from it

    def stages(self, ctl, X: np.ndarray, w: np.ndarray) -> tuple:
        """(A, B, c, x0, u0, r) of the step at X with the reference rows w ((N − No, p), m and rad);
        keeps the controller's one-step model (and, nonlinear, the pre-simulated inputs)."""
        if self.form == "nonlinear":
            fused = self.constrained is None and self.solver.fuses_presimulation
            update = getattr(ctl.model, "compiled_update", None) if fused or self._stages_call is not None else None
            simulate = None if update is None else self._fused(update, w) if fused else self._limited(update)
            A_seq, B_seq, C, y_sim, self._u_sim = ctl.presimulate(X, simulate)
            if self.constrained is not None:
                self._extra = {"y_now": C @ X, "y_sim": y_sim, "u_sim": self._u_sim, "u_prev": ctl.u_prev}
            return A_seq, B_seq, None, X, None, w - y_sim[self.horizons.No:]
        Ad, Bd, cd, base = ctl.linear_stages(X)
        if self.constrained is not None:
            self._extra = {"y_now": ctl.model.C @ X}
        return Ad, Bd, cd, X, base, w

    def _fused(self, update, w):
        """A pre-simulation for :meth:`GPCController.presimulate` that also plans along it
        (:meth:`RiccatiSolver.presimulated`); the plan waits for :meth:`solve` of these stages."""
        def simulate(X0, u_seq, Ts, offset):
            sim, result, inputs, null = self.solver.presimulated(update, X0, u_seq, Ts, offset, w)
            self._planned = (sim[0], result, inputs)
            return (*sim, null)
        return simulate

    def _limited(self, update):
        """The limited step's pre-simulation for :meth:`GPCController.presimulate`: the model's
        ``simulate_factorized`` and null(B_d(X)) in one compiled call (``_native.presimulated_stages``)."""
        def simulate(X0, u_seq, Ts, offset):
            A, B, c, X, null = self._stages_call(update, X0, u_seq, Ts, offset, NULL_RTOL)
            return A, B, c, X, _null_result(null)
        return simulate

    def solve(self, A, B, c, x0, u0, r, warm: bool = False, bounds: np.ndarray | None = None) -> SolveResult:
        """:meth:`RiccatiSolver.solve`, or with limits the stage-wise active set or interior point
        (:class:`~parallel_gpc.gpc.stagewise.StagewiseSolver`; :attr:`report` set), warm-started
        from its last solution when ``warm`` (the controller's next step); the stages of a fused
        nonlinear step (:meth:`stages`) were solved in its call already (:meth:`planned_inputs`).
        ``bounds``: the nonlinear form's input-row bounds of this step when the caller keeps them
        (:func:`~parallel_gpc.gpc.stagewise.step_bounds` of its pre-simulated inputs and u(k−1)), else None."""
        planned, self._planned, self._solved = self._planned, None, (None, None)
        if planned is not None and planned[0] is A:  # the fused step planned these stages already
            self._solved = planned[1:]
            return planned[1]
        if self.constrained is None:
            return self.solver.solve(A, B, c, x0, u0, r)
        result, self.report = self.constrained.solve((A, B, c, x0, u0), r, warm=warm, bounds=bounds, **self._extra)
        return result

    def planned_inputs(self, result: SolveResult) -> np.ndarray | None:
        """(N, m) inputs u = u_base + u_map v of ``result`` (N·m) when it is the fused nonlinear
        step's (:meth:`solve`, which computed them in its call), else None."""
        solved, inputs = self._solved
        return inputs if result is solved else None

    @property
    def excess(self) -> float:
        """How far the last constrained solution's limit rows may exceed the bounds it was given, as
        its solver verified (:attr:`~parallel_gpc.gpc.stagewise.StagewiseSolver.excess`, N·m); inf
        when unverified or without limits."""
        return np.inf if self.constrained is None else self.constrained.excess

    def input_map(self, ctl, stages: tuple) -> Prediction:
        """A :class:`~parallel_gpc.gpc.prediction.Prediction` carrying only the input map of the
        form (f and G are empty: nothing was condensed)."""
        H, m = self.horizons, self.m
        none, empty = self._empty
        if self.form == "absolute":
            return Prediction(none, empty, self._zero_base, self._u_map, H, "absolute")
        if self.form == "nonlinear":
            return Prediction(none, empty, self._u_sim.reshape(-1), self._u_map, H, "simulative")
        base = stages[4]
        u_base = np.broadcast_to(base, (H.Nu, m)).reshape(-1)  # np.tile, without its overhead
        return Prediction(none, empty, u_base, self._u_map, H, "incremental")
