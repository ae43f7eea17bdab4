"""What a GPC controller is told (frozen, validated :class:`GPCSettings`) and what it remembers
between steps (a frozen :class:`ControllerState` snapshot)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import InvalidParameterError
from ..limits import KINEMATIC_KINDS, Limits, as_limits
from ..model.native import compiled_part
from ..validation import number, positive, read_only
from .criterion import Weights
from .prediction import Horizons

FORMS = ("absolute", "incremental", "incremental-delayed", "nonlinear")
#: the paper's three algorithms (the delayed variant of the incremental form left out).
PAPER_FORMS = ("absolute", "incremental", "nonlinear")
#: forms whose decision variable is the increment Δu (the incremental forms).
INCREMENTAL_FORMS = ("incremental", "incremental-delayed", "nonlinear")
#: condensed back end used with limits and no solver named, incremental forms (the torque limit
#: acts on cumulative sums of Δu: linear limits).
DEFAULT_LIMITED_SOLVER = "qr-first:daqp-direct"
#: condensed back end used with limits and no solver named, absolute form (the torque limit is a
#: box on v = u): QR, then bounded-variable least squares when a limit binds — an exact active set
#: on the square-root form (KKT residual ≤ 4e-15 relative on the benchmark problems of every
#: robot, DAQP's regularized QP ≤ 2e-10) and no dense QP setup.
DEFAULT_BOX_SOLVER = "qr-first:bvls"
#: the stage-wise path is the default only when σ_min(Qu) ≥ RICCATI_QU_MARGIN · σ_max(Qy) · Ts²
#: (Qy·Ts² is the scale of the outputs' weight on an input: G ~ Ts² M⁻¹B; the Riccati recursion
#: works with R + BᵀPB, the square of the conditioning QR sees, so its plan drifts from QR's as Qu
#: shrinks on redundant drives). Measured, plan ‖v − v_qr‖/‖v_qr‖ over one step of the absolute,
#: incremental and nonlinear forms (planar_4rrr, delta_3rus, hexapod_6ups, hexapod_8ups,
#: docs/your-robot/fivebar.urdf; Ts = 1, 2, 10 ms, Qu = 1e-2 … 1e-10): ≤ 4.1e-11 at
#: σ_min(Qu)/(σ_max(Qy)·Ts²) ≥ 1e-2, 3e-10 to 4.4e-10 at 1e-3 to 2.5e-3, up to 1.7e-4 at 1e-6 (the
#: redundant robots; the others stay ≤ 4e-11 at every Qu measured).
RICCATI_QU_MARGIN = 1e-2
#: with torque/Δu limits, the stage-wise path (an active set of Riccati sweeps, the interior point
#: when the set does not settle) is the default from this horizon on (N ≥): measured faster than the
#: condensed default at every N measured, 10 … 160 (1.4–3.5× at N ≤ 20, 8–36× at N ≥ 80; absolute
#: N = 160 1.55×, most of its steps by the interior point), torque limits, planar_4rrr, plans within
#: 1e-8 of DAQP's (benchmarks/README.md, "Round 5: the active set on the input rows"). Shorter
#: horizons were not measured: the condensed default there. Every form: the nonlinear form's torque
#: rows after Nu sit on the held deviation and join the active set through stage Nu − 1
#: (:func:`~parallel_gpc.gpc.stagewise.input_bounds`; its step 1.4–1.6× the unconstrained one over
#: N = 20…160, planar_4rrr); the delayed form's rows are the incremental form's on [x; u(k)] (its plan
#: u(k+1…) equals DAQP's to 1e-8, tests/test_stagewise_delayed.py), its step 1.1–1.6× the unconstrained
#: one over N = 20…160 in closed loop (planar_4rrr, benchmarks/README.md, "Round 9").
STAGEWISE_LIMITED_MIN_N = 10
#: terminal equalities of the tracking forms: ``"pose"``: ŷ(k+N) = w(k+N); ``"stop"``: that and
#: ŷ(k+N) = ŷ(k+N−1) (zero mean velocity over the last predicted sample).
TERMINALS = ("pose", "stop")


@dataclass(frozen=True, eq=False)
class GPCSettings:
    """Validated, immutable settings of a :class:`~parallel_gpc.gpc.GPCController`.

    The one place these fields are defined: ``GPCController(model, settings)`` takes them whole,
    ``GPCController.build(model, Ts, horizons, ..., u0=...)`` builds them from keywords.

    Attributes:
        Ts: sample time in s (> 0); a model with its own Ts (a
            :class:`~parallel_gpc.gpc.DiscreteLinearModel`) must agree (checked once, when the
            controller is built).
        horizons: N, No, Nu.
        weights: square-root weights Qy, Qu.
        form: ``"absolute"`` (7), ``"incremental"`` (8)–(9) with state [X; u(k−1)],
            ``"incremental-delayed"`` (8)–(9) as printed: state [X; u(k)], B̄ = [0; I], the
            increment realized one sample later (needs N ≥ 2), or ``"nonlinear"`` (10)–(12).
        solver: back-end name (:func:`parallel_gpc.solvers.make_solver`: ``"qr"``, the paper's
            square-root reference, and the condensed back ends), or ``"riccati"``: the problem
            solved stage-wise, no condensing (needs Qu nonsingular; the Riccati recursion without
            limits, :mod:`parallel_gpc.gpc.riccati`; with torque, du, output_box and
            output_velocity limits a stage-wise interior point, :mod:`parallel_gpc.gpc.stagewise`;
            not with drive limits, a terminal equality or weight, or iterations > 1); None: the
            default of :func:`default_solver` (``"riccati"`` where it gives QR's minimizer and
            is faster, otherwise ``"qr"`` or a condensed QP back end). After validation the
            name the controller uses; :attr:`solver_is_default` says whether it was chosen.
        limits: the :class:`~parallel_gpc.limits.Limits` (torque |u| ≤ τ; increment
            |u(k) − u(k−1)| ≤ δ, incremental forms only; the state kinds drive_position,
            drive_rate, output_box, output_velocity, joint_position, hard or soft,
            :mod:`parallel_gpc.gpc.constraints`);
            None = ``Limits()``, no limit.
        disturbance_gain: α ∈ [0, 1] of the state-disturbance estimate
            d ← (1 − α) d + α (X(k) − X̂(k|k−1)) added to the model's affine term over the horizon
            (unbiased prediction under model mismatch with a steady load, which the incremental
            forms need to reach zero steady-state error); None resolves to 0 for the absolute
            form and 0.5 for the incremental forms.
        max_condition: largest accepted condition number (> 0) of the model's input gain
            g = M_r⁻¹ B_r (discretized) at the measured state; beyond it a step raises
            :class:`~parallel_gpc.errors.SingularPoseError` instead of commanding the unbounded
            torques a (near-)singular pose calls for. Default 1e3: cond(g) is 10–20 along the
            paper's S-curve and A→B on both embedded robots, 1e3 is about 1 cm from a planar_3rrr
            direct singularity. Which gain is checked for other models:
            :class:`~parallel_gpc.gpc.ControlModel`.
        iterations: largest number of Gauss–Newton iterations per step of the nonlinear form
            (integer ≥ 1): 1 is the paper's single linearization; more continue to the optimum of
            the discrete nonlinear MPC problem (:mod:`parallel_gpc.gpc.nmpc`). Only with form
            ``"nonlinear"`` and a dense back end (not ``"riccati"``) when > 1.
        tolerance: the iterations stop when the Gauss–Newton step ‖v⁺ − v‖∞ ≤ tolerance·(1 + ‖v‖∞)
            (> 0, relative; default 1e-8).
        time_budget: s per control step (> 0) for the iterations (real-time mode): no iteration
            starts that would end past it (the step record says so), or None (no budget).
        terminal: an optional terminal equality, hard rows of the QP (:data:`TERMINALS`):
            ``"pose"``: ŷ(k+N) = w(k+N); ``"stop"``: also ŷ(k+N) = ŷ(k+N−1) (the mean velocity over
            the last predicted sample is zero: stop at the target; needs N − No ≥ 2); None
            (default): none. The terminal weight is the weights' ``Qf``.
        solver_is_default: True when ``solver`` was left unset and :func:`default_solver` chose
            it (not a constructor argument; a changed copy, :meth:`changed`, chooses again).
        step_solver: what solves the control steps (not a constructor argument): ``"riccati"``
            when the nonlinear form's Gauss–Newton iterations take the Riccati recursion
            (:func:`iterations_by_riccati`; ``solver`` then names the condensed back end a step
            whose minimizer breaks an input limit goes to), otherwise ``solver``. The controller
            reports it as its ``solver``.

    Raises:
        InvalidParameterError: bad Ts, form, horizons, weights or limits type, solver/limits
            combination, gain or max_condition.
    """

    Ts: float
    horizons: Horizons
    weights: Weights = field(default_factory=Weights)
    form: str = "absolute"
    solver: str | None = None
    limits: Limits = field(default_factory=Limits)
    disturbance_gain: float | None = None
    max_condition: float = 1e3
    iterations: int = 1
    tolerance: float = 1e-8
    time_budget: float | None = None
    terminal: str | None = None
    solver_is_default: bool = field(default=False, init=False)
    step_solver: str = field(default="", init=False)

    def __post_init__(self):
        def put(name, value):
            object.__setattr__(self, name, value)

        put("Ts", positive("Ts", self.Ts, " s"))
        if self.form not in FORMS:
            raise InvalidParameterError(f"form {self.form!r} is not one of {FORMS}")
        if not isinstance(self.horizons, Horizons):
            raise InvalidParameterError(f"horizons must be a Horizons(N, No, Nu), got {self.horizons!r}")
        if not isinstance(self.weights, Weights):
            raise InvalidParameterError(f"weights must be a Weights(Qy, Qu), got {self.weights!r}")
        put("limits", as_limits(self.limits))
        if self.form == "incremental-delayed" and self.horizons.N < 2:
            raise InvalidParameterError(
                f"form 'incremental-delayed' needs N ≥ 2 (its increment acts from k+2 on); got N = {self.horizons.N}")
        check_form_limits(self.form, self.limits)
        put("iterations", check_iterations(self.iterations, self.form))
        check_terminal(self)
        put("solver_is_default", self.solver is None)
        put("solver", default_solver(self) if self.solver is None else resolve_solver(
            self.solver, self.form, self.limits, self.terminal, stagewise_obstacle(self)))
        if self.disturbance_gain is None:
            put("disturbance_gain", 0.0 if self.form == "absolute" else 0.5)
        put("disturbance_gain", unit_interval("disturbance_gain", self.disturbance_gain))
        put("max_condition", positive("max_condition", self.max_condition))
        put("tolerance", positive("tolerance", self.tolerance))
        if self.time_budget is not None:
            put("time_budget", positive("time_budget", self.time_budget, " s"))
        put("step_solver", "riccati" if iterations_by_riccati(self) else self.solver)

    def changed(self, **changes) -> "GPCSettings":
        """A validated copy with ``changes`` (fields by name); a solver that was chosen by default
        (:attr:`solver_is_default`) is chosen again for the new settings unless ``changes`` names one,
        an explicit one is kept (``dataclasses.replace`` alone would keep the chosen name as if given)."""
        again = {"solver": None} if self.solver_is_default and "solver" not in changes else {}
        return replace(self, **changes, **again)


def iterations_by_riccati(settings: "GPCSettings") -> bool:
    """True when every Gauss–Newton step of the nonlinear form's iterations (iterations > 1), the
    paper's included, is solved by the Riccati recursion on its stage models
    (:func:`~parallel_gpc.gpc.nmpc.riccati_steps`): the recursion gives the condensed subproblem's
    minimizer whenever the paper's single step of these settings would take the stage-wise path
    (:func:`stagewise_obstacle` of ``iterations=1`` empty: no terminal equality or weight, no drive
    limit; Qu nonsingular with :data:`RICCATI_QU_MARGIN`), no state limit is set (their rows move
    with every linearization), the back end is the default (an explicit back end solves every
    step) and the compiled recursion is there (:func:`stagewise_compiled`: the pure-Python one is
    slower than the condensed QR). The one owner of that rule."""
    return (settings.iterations > 1 and settings.solver_is_default and not settings.limits.has_state_limits
            and stagewise_exact(replace(settings, iterations=1)) and stagewise_compiled(False))


def check_iterations(n, form: str = "nonlinear") -> int:
    """The Gauss–Newton iterations ``n`` of ``form``; refused unless an integer ≥ 1, and > 1 outside the
    nonlinear form (:class:`GPCSettings`; :class:`~parallel_gpc.studies.TrackingSettings` for its nonlinear runs)."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise InvalidParameterError(f"iterations = {n!r} must be an integer ≥ 1 (1: the paper's single step)")
    if n > 1 and form != "nonlinear":
        raise InvalidParameterError(f"iterations = {n} iterates the nonlinear form's prediction; form is "
                                    f"{form!r} (use form='nonlinear' or iterations=1)")
    return int(n)


def check_terminal(settings: "GPCSettings") -> None:
    """Refuse a terminal equality that is not one of :data:`TERMINALS`, a ``"stop"`` with fewer than
    two predicted rows, or one with the iterated nonlinear form."""
    t = settings.terminal
    if t is None:
        return
    if t not in TERMINALS:
        raise InvalidParameterError(f"terminal = {t!r} is not one of {list(TERMINALS)} (or None: no terminal "
                                    "equality)")
    H = settings.horizons
    if t == "stop" and H.n_rows < 2:
        raise InvalidParameterError(f"terminal 'stop' sets ŷ(k+N) = ŷ(k+N−1): it needs N − No ≥ 2 predicted rows; "
                                    f"got N = {H.N}, No = {H.No}")
    if settings.iterations > 1:
        raise InvalidParameterError(f"terminal = {t!r} enters the paper's single step only so far: use iterations=1")


def check_form_limits(form: str, limits: Limits) -> None:
    """Refuse an increment limit on the absolute form (v = u has no increments)."""
    if limits.du is not None and form == "absolute":
        raise InvalidParameterError(f"the du limit {limits.du.tolist()} applies to the incremental forms (v = Δu); "
                                    "form is 'absolute'")


def stagewise_obstacle(settings: "GPCSettings") -> str:
    """Why the stage-wise path (``solver="riccati"``) cannot solve these settings' problem, or ""
    when it can: the one owner of that rule (the default and an explicit ``"riccati"`` both ask).
    Qu's singularity is checked where the weights meet the drive count
    (:class:`~parallel_gpc.gpc.riccati.RiccatiSolver`)."""
    limits, qf = settings.limits, np.asarray(settings.weights.Qf, dtype=float)
    if settings.terminal is not None:
        return f"it cannot enforce the terminal equality {settings.terminal!r} (general equality rows)"
    if np.any(qf != 1.0):
        return (f"it takes the paper's criterion; the terminal weight Qf = {settings.weights.Qf!r} needs a "
                "dense back end")
    if settings.iterations > 1:
        return f"iterations = {settings.iterations} needs a dense back end; it solves the paper's single step only"
    kinematic = [kind for kind in KINEMATIC_KINDS if getattr(limits, kind) is not None]
    if kinematic:
        return (f"it enforces torque, du, output_box and output_velocity limits stage-wise; the drive limits or "
                f"joint ranges ({', '.join(kinematic)}) in {limits.describe()} are linearized along the condensed "
                "prediction")
    return ""


def stagewise_exact(settings: "GPCSettings") -> bool:
    """True when the Riccati path gives these settings' condensed minimizer to rounding: no
    :func:`stagewise_obstacle` and :func:`weight_margin` ≥ :data:`RICCATI_QU_MARGIN` (Qu
    nonsingular with margin). Asked by :func:`default_solver` and :func:`iterations_by_riccati`."""
    return not stagewise_obstacle(settings) and weight_margin(settings.weights, settings.Ts) >= RICCATI_QU_MARGIN


def weight_margin(weights: Weights, Ts: float) -> float:
    """σ_min(Qu) / (σ_max(Qy)·Ts²) (1/s², compared with :data:`RICCATI_QU_MARGIN`); inf when Qy = 0."""
    def singular_values(w):
        w = np.asarray(w, dtype=float)
        return np.abs(w).ravel() if w.ndim < 2 else np.linalg.svd(w, compute_uv=False)
    qy = singular_values(weights.Qy).max()
    return np.inf if qy == 0.0 else singular_values(weights.Qu).min() / (qy * Ts * Ts)


def condensed_default(form: str, limits: Limits, terminal: str | None = None) -> str:
    """The condensed back end of a form with these limits (and terminal equality): ``"qr"``
    without limits, :data:`DEFAULT_BOX_SOLVER` for box limits on the absolute form, otherwise
    :data:`DEFAULT_LIMITED_SOLVER` (also the replacement of a failed stage-wise solve)."""
    if not limits.needs_qp and terminal is None:
        return "qr"
    box_only = form == "absolute" and not limits.has_state_limits and terminal is None
    return DEFAULT_BOX_SOLVER if box_only else DEFAULT_LIMITED_SOLVER


def default_solver(settings: "GPCSettings") -> str:
    """The back end ``solver=None`` resolves to: the one place of the default policy.

    ======================================================  =========================================
    the settings                                            default
    ======================================================  =========================================
    stage-wise exact (below), no limits, compiled core      ``"riccati"`` (the Riccati recursion)
    stage-wise exact, torque/du limits only, N ≥            ``"riccati"`` (the stage-wise active set;
    :data:`STAGEWISE_LIMITED_MIN_N`, every form             the interior point when it does not settle)
    otherwise                                               :func:`condensed_default`: ``"qr"``
                                                            without limits (Qu singular: QR's
                                                            minimum-norm answer, no drive fighting),
                                                            :data:`DEFAULT_BOX_SOLVER`,
                                                            :data:`DEFAULT_LIMITED_SOLVER`
    ======================================================  =========================================

    Stage-wise exact: the Riccati path gives the condensed problem's minimizer to rounding — no
    :func:`stagewise_obstacle` (terminal equality or weight, iterations > 1, drive or joint
    limits) and :func:`weight_margin` ≥ :data:`RICCATI_QU_MARGIN` (Qu nonsingular with margin).
    Both ``"riccati"`` rows also need the compiled core (:func:`stagewise_compiled`): without it
    (not built, or ``PARALLEL_GPC_NATIVE=0``) the default is :func:`condensed_default`, whose QR
    is faster than the pure-Python recursion.
    """
    limits, H = settings.limits, settings.horizons
    inputs_only = not limits.has_state_limits
    if (not limits.needs_qp or (inputs_only and H.N >= STAGEWISE_LIMITED_MIN_N)) \
            and stagewise_exact(settings) and stagewise_compiled(limits.needs_qp):
        return "riccati"
    return condensed_default(settings.form, limits, settings.terminal)


def stagewise_compiled(limited: bool) -> bool:
    """True when the compiled core has the stage-wise solve the default would use (the Riccati
    recursion; with limits also the stage-wise active set and interior point): not built or
    ``PARALLEL_GPC_NATIVE=0`` gives False, and the default is the condensed one. The pure-Python
    stage-wise reference was measured slower than QR on every form (planar_4rrr, Ts = 2 ms, CPU
    medians of a controller step: N = 20 absolute 2.8 vs 0.91 ms, incremental 3.0 vs 1.1 ms,
    nonlinear 8.4 vs 6.5 ms; torque-limited absolute 22 vs 2.5 ms (bvls); N = 80 still 1.1–4×)."""
    parts = ("Riccati", "stagewise_active", "stagewise_ipm") if limited else ("Riccati",)
    return all(compiled_part(None, part, "the compiled stage-wise solve") is not None for part in parts)


def resolve_solver(solver: str | None, form: str, limits: Limits, terminal: str | None = None,
                   stagewise: str | None = None) -> str:
    """A back-end name checked against a form with these limits (and terminal equality); None
    resolves to :func:`condensed_default` (the planner's condensed problems; a controller's
    default is :func:`default_solver`).

    Args:
        stagewise: :func:`stagewise_obstacle` of a controller's settings ("" none): ``"riccati"``
            is refused with it; None: no stage-wise path (a condensed problem).

    Raises:
        InvalidParameterError: not a name, or a name that cannot enforce ``limits`` or the
            terminal equality (qr, cholesky; riccati where :func:`stagewise_obstacle` says why;
            bvls with the incremental forms' torque limit, state limits or a terminal equality).
    """
    if solver is None:
        return condensed_default(form, limits, terminal)
    if not isinstance(solver, str):
        raise InvalidParameterError(f"solver {solver!r} must be a back-end name such as 'qr'")
    if solver == "riccati" and stagewise:
        raise InvalidParameterError(f"solver 'riccati' cannot solve this problem: {stagewise}; use a back end such "
                                    f"as {condensed_default(form, limits, terminal)!r} (or leave solver unset)")
    if terminal is not None and (solver in ("qr", "cholesky") or solver.endswith("bvls")):
        raise InvalidParameterError(f"solver {solver!r} cannot enforce the terminal equality {terminal!r} (general "
                                    f"equality rows); use {DEFAULT_LIMITED_SOLVER!r} (or leave solver unset)")
    if solver in ("qr", "cholesky") and limits.needs_qp:
        raise InvalidParameterError(
            f"solver {solver!r} cannot enforce the limits {limits.describe()}; use a QP back end such as "
            f"{condensed_default(form, limits)!r}, 'osqp-direct' or 'qpsolvers:osqp', or drop the limits "
            f"(Limits(); a robot file's limits: track --limits none)")
    if solver.endswith("bvls") and limits.has_state_limits:
        raise InvalidParameterError(
            f"solver {solver!r} handles box limits only; the state limits {limits.describe()} are linear rows in the "
            f"decision variables: use {DEFAULT_LIMITED_SOLVER!r} or 'proxqp-direct'")
    if solver.endswith("bvls") and form != "absolute" and limits.torque is not None:
        raise InvalidParameterError(
            f"solver {solver!r} handles box limits only; the {form} form's torque limit acts on cumulative sums "
            f"of Δu (linear limits): use {DEFAULT_LIMITED_SOLVER!r} or 'proxqp-direct'")
    return solver


def unit_interval(name: str, value) -> float:
    """``value`` as a float in [0, 1].

    Raises:
        InvalidParameterError: not a number in [0, 1].
    """
    try:
        x = number(name, value)
    except InvalidParameterError:
        x = np.nan
    if not 0.0 <= x <= 1.0:
        raise InvalidParameterError(f"{name} = {value!r} must lie in [0, 1]")
    return x




@dataclass(frozen=True, eq=False)
class ControllerState:
    """Everything a controller carries from one step to the next (read-only copies).

    ``controller.restore(controller.state)`` puts a controller back where it was: the next step
    gives the same inputs (to rounding: caches kept by the model, such as a robot's assembly
    warm start, and a QP back end's internal working set are not controller state).

    Attributes:
        u_prev: (m,) last applied input u(k−1) (N·m).
        plan: (N, m) last optimal input sequence (N·m); the nonlinear form pre-simulates it.
        disturbance: (n_x,) state-disturbance estimate d added to the model's affine term.
        x_next: (n_x,) one-step prediction X̂(k+1|k) of the last step, or None before the first.
        warm_start: last solution v (what the QP back ends are warm-started from, shifted by one
            sample), or None before the first step.
    """

    u_prev: np.ndarray
    plan: np.ndarray
    disturbance: np.ndarray
    x_next: np.ndarray | None = None
    warm_start: np.ndarray | None = None

    def __post_init__(self):
        for name in ("u_prev", "plan", "disturbance", "x_next", "warm_start"):
            object.__setattr__(self, name, read_only(getattr(self, name)))
