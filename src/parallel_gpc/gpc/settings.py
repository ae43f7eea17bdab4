"""What a GPC controller is told (frozen, validated :class:`GPCSettings`) and what it remembers
between steps (a frozen :class:`ControllerState` snapshot)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InfeasibleLimitsError, InvalidParameterError
from ..validation import positive
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


def _limit(name: str, value) -> np.ndarray | None:
    """A symmetric limit as a read-only float array (scalar or 1-D), finite and > 0; None stays None."""
    if value is None:
        return None
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise InvalidParameterError(f"{name} = {value!r} is not a number or a vector of numbers") from None
    if arr.ndim > 1:
        raise InvalidParameterError(f"{name} has shape {arr.shape}; expected a scalar or (m,) (N·m)")
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise InfeasibleLimitsError(f"{name} = {arr.tolist()} must be finite and > 0 (symmetric limits ±value)")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class GPCSettings:
    """Validated, immutable settings of a :class:`~parallel_gpc.gpc.GPCController`.

    Attributes:
        Ts: sample time in s (> 0).
        horizons: N, No, Nu.
        weights: square-root weights Qy, Qu.
        form: ``"absolute"`` (7), ``"incremental"`` (8)–(9) with state [X; u(k−1)],
            ``"incremental-delayed"`` (8)–(9) as printed: state [X; u(k)], B̄ = [0; I], the
            increment realized one sample later (needs N ≥ 2), or ``"nonlinear"`` (10)–(12).
        solver: back-end name (:func:`parallel_gpc.solvers.make_solver`), or ``"riccati"``: the
            unconstrained problem by the Riccati recursion, no condensing (needs Qu nonsingular and
            no limits; :mod:`parallel_gpc.gpc.riccati`); None resolves to
            ``"qr"`` without limits; with limits ``"qr-first:bvls"`` (absolute form) or
            ``"qr-first:daqp-direct"`` (incremental forms).
        torque_limit: symmetric drive torque limit |u| ≤ τ (N·m), scalar or (m,), or None.
        du_limit: symmetric increment limit |Δu| ≤ δ (N·m per sample), incremental forms only.
        disturbance_gain: α ∈ [0, 1] of the state-disturbance estimate; None resolves to 0 for
            the absolute form and 0.5 for the incremental forms.
        max_condition: largest accepted condition number of the model's input gain (> 0).

    Raises:
        InvalidParameterError: bad Ts, form, horizons, weights type, solver/limits combination,
            gain or max_condition. InfeasibleLimitsError: limits that are not finite and > 0.
    """

    Ts: float
    horizons: Horizons
    weights: Weights = field(default_factory=Weights)
    form: str = "absolute"
    solver: str | None = None
    torque_limit: np.ndarray | None = None
    du_limit: np.ndarray | None = None
    disturbance_gain: float | None = None
    max_condition: float = 1e3

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
        put("torque_limit", _limit("torque_limit", self.torque_limit))
        put("du_limit", _limit("du_limit", self.du_limit))
        if self.form == "incremental-delayed" and self.horizons.N < 2:
            raise InvalidParameterError(
                f"form 'incremental-delayed' needs N ≥ 2 (its increment acts from k+2 on); got N = {self.horizons.N}")
        if self.du_limit is not None and self.form == "absolute":
            raise InvalidParameterError("du_limit applies to the incremental forms; form is 'absolute'")
        limited = self.torque_limit is not None or self.du_limit is not None
        if self.solver is None:
            put("solver", "qr" if not limited else DEFAULT_BOX_SOLVER if self.form == "absolute"
                else DEFAULT_LIMITED_SOLVER)
        if not isinstance(self.solver, str):
            raise InvalidParameterError(f"solver {self.solver!r} must be a back-end name such as 'qr'")
        if self.solver in ("qr", "cholesky") and limited:
            raise InvalidParameterError(
                f"solver {self.solver!r} cannot enforce torque/Δu limits; use a QP back end such as "
                f"{DEFAULT_LIMITED_SOLVER!r}, 'osqp-direct' or 'qpsolvers:osqp'"
            )
        if self.solver == "riccati" and limited:
            raise InvalidParameterError(
                "solver 'riccati' solves the unconstrained problem only; with torque/Δu limits use a QP back end "
                f"such as {DEFAULT_LIMITED_SOLVER!r} (or leave solver unset)")
        if self.solver.endswith("bvls") and self.form != "absolute" and self.torque_limit is not None:
            raise InvalidParameterError(
                f"solver {self.solver!r} handles box limits only; the {self.form} form's torque limit acts on "
                f"cumulative sums of Δu (linear limits): use {DEFAULT_LIMITED_SOLVER!r} or 'proxqp-direct'"
            )
        if self.disturbance_gain is None:
            put("disturbance_gain", 0.0 if self.form == "absolute" else 0.5)
        try:
            gain = float(self.disturbance_gain)
        except (TypeError, ValueError):
            gain = np.nan
        if not 0.0 <= gain <= 1.0:
            raise InvalidParameterError(f"disturbance_gain = {self.disturbance_gain!r} must lie in [0, 1]")
        put("disturbance_gain", gain)
        put("max_condition", positive("max_condition", self.max_condition))

    @property
    def has_limits(self) -> bool:
        """True when a torque or increment limit is set."""
        return self.torque_limit is not None or self.du_limit is not None


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
