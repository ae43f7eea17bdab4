"""What a GPC controller is told (frozen, validated :class:`GPCSettings`) and what it remembers
between steps (a frozen :class:`ControllerState` snapshot)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InvalidParameterError
from ..limits import Limits, as_limits
from ..validation import number, positive
from .criterion import Weights
from .prediction import Horizons

FORMS = ("absolute", "incremental", "incremental-delayed", "nonlinear")
#: the paper's three algorithms (the delayed variant of the incremental form left out).
PAPER_FORMS = ("absolute", "incremental", "nonlinear")
#: forms whose decision variable is the increment Δu (the incremental forms).
INCREMENTAL_FORMS = ("incremental", "incremental-delayed", "nonlinear")
#: back end used with limits and no solver named, incremental forms (the torque limit acts on
#: cumulative sums of Δu: linear limits).
DEFAULT_LIMITED_SOLVER = "qr-first:daqp-direct"
#: back end used with limits and no solver named, absolute form (the torque limit is a box on
#: v = u): QR, then bounded-variable least squares when a limit binds — an exact active set on
#: the square-root form (KKT residual ≤ 4e-15 relative on the benchmark problems of every robot,
#: DAQP's regularized QP ≤ 2e-10) and no dense QP setup.
DEFAULT_BOX_SOLVER = "qr-first:bvls"
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
        solver: back-end name (:func:`parallel_gpc.solvers.make_solver`), or ``"riccati"``: the
            problem solved stage-wise, no condensing (needs Qu nonsingular; the Riccati recursion
            without limits, :mod:`parallel_gpc.gpc.riccati`; with torque, du, output_box and
            output_velocity limits a stage-wise interior point, :mod:`parallel_gpc.gpc.stagewise`;
            not with drive limits); None resolves to ``"qr"`` without limits;
            with input limits only :data:`DEFAULT_BOX_SOLVER` (absolute form) or
            :data:`DEFAULT_LIMITED_SOLVER` (incremental forms, and any form with state limits).
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
        check_terminal(self)
        put("solver", resolve_solver(self.solver, self.form, self.limits, self.terminal))
        if self.solver == "riccati" and self.weights.Qf is not None and np.any(np.asarray(self.weights.Qf) != 1.0):
            raise InvalidParameterError(f"solver 'riccati' takes the paper's criterion; the terminal weight "
                                        f"Qf = {self.weights.Qf!r} needs a dense back end such as 'qr'")
        if self.disturbance_gain is None:
            put("disturbance_gain", 0.0 if self.form == "absolute" else 0.5)
        put("disturbance_gain", unit_interval("disturbance_gain", self.disturbance_gain))
        put("max_condition", positive("max_condition", self.max_condition))
        check_iterations(self)
        put("tolerance", positive("tolerance", self.tolerance))
        if self.time_budget is not None:
            put("time_budget", positive("time_budget", self.time_budget, " s"))


def check_iterations(settings: "GPCSettings") -> None:
    """Refuse iterations that are not an integer ≥ 1, or > 1 outside the nonlinear form's dense solve."""
    n = settings.iterations
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise InvalidParameterError(f"iterations = {n!r} must be an integer ≥ 1 (1: the paper's single step)")
    if n > 1 and settings.form != "nonlinear":
        raise InvalidParameterError(f"iterations = {n} iterates the nonlinear form's prediction; form is "
                                    f"{settings.form!r} (use form='nonlinear' or iterations=1)")
    if n > 1 and settings.solver == "riccati":
        raise InvalidParameterError(f"iterations = {n} needs a dense back end (e.g. 'qr'); solver 'riccati' "
                                    "solves the paper's single step only")


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


def resolve_solver(solver: str | None, form: str, limits: Limits, terminal: str | None = None) -> str:
    """The back end of a form with these limits (and terminal equality): None resolves to the
    default; a back end that cannot enforce them is refused.

    Raises:
        InvalidParameterError: not a name, or a name that cannot enforce ``limits`` (qr, cholesky,
            riccati with a drive or joint limit, a terminal equality or Qf ≠ 1; bvls with the incremental
            forms' torque limit, state limits or a terminal equality).
    """
    limited = limits.needs_qp or terminal is not None
    if terminal is not None and solver is not None and isinstance(solver, str) and (
            solver in ("qr", "cholesky", "riccati") or solver.endswith("bvls")):
        raise InvalidParameterError(f"solver {solver!r} cannot enforce the terminal equality {terminal!r} (general "
                                    f"equality rows); use {DEFAULT_LIMITED_SOLVER!r} (or leave solver unset)")
    if solver is None:
        box_only = form == "absolute" and not limits.has_state_limits and terminal is None
        return "qr" if not limited else DEFAULT_BOX_SOLVER if box_only else DEFAULT_LIMITED_SOLVER
    if not isinstance(solver, str):
        raise InvalidParameterError(f"solver {solver!r} must be a back-end name such as 'qr'")
    if solver in ("qr", "cholesky") and limited:
        raise InvalidParameterError(
            f"solver {solver!r} cannot enforce the limits {limits!r}; use a QP back end such as "
            f"{DEFAULT_LIMITED_SOLVER!r}, 'osqp-direct' or 'qpsolvers:osqp'")
    if solver == "riccati" and any(getattr(limits, kind) is not None
                                   for kind in ("drive_position", "drive_rate", "joint_position")):
        raise InvalidParameterError(
            f"solver 'riccati' enforces torque, du, output_box and output_velocity limits stage-wise; the drive limits "
            f"or joint ranges in {limits.describe()} are linearized along the condensed prediction: use a QP back end "
            f"such as {DEFAULT_LIMITED_SOLVER!r} (or leave solver unset)")
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


def _frozen(value):
    if value is None:
        return None
    arr = np.array(value, dtype=float, copy=True)
    arr.setflags(write=False)
    return arr


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
            object.__setattr__(self, name, _frozen(getattr(self, name)))
