"""Settings of quadratically-optimal point-to-point planning, eq. (20)–(21): horizons, weights, modes."""

from __future__ import annotations

import json
from dataclasses import dataclass, field, fields

import numpy as np

from ..errors import InvalidParameterError
from ..limits import Limits, as_limits
from ..validation import positive
from .criterion import Weights
from .settings import DEFAULT_LIMITED_SOLVER, resolve_solver

MODES = ("a", "b", "once")
#: How :attr:`PlanResult.stopped` starts when Ctrl-C stopped the plan.
INTERRUPTED = "interrupted (Ctrl-C)"
#: What each mode is called in tables and plots.
MODE_LABELS = {"a": "(a) receding, no stopping information", "b": "(b) shrinking horizon, stops",
               "once": "once: open loop (linear systems only)"}


def integer(name: str, value, low: int) -> int:
    """``value`` as an int ≥ ``low`` (a bool or a float is refused).

    Raises:
        InvalidParameterError: naming the value and the bound.
    """
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise InvalidParameterError(f"{name} = {value!r} must be an integer ≥ {low}")
    return int(value)


@dataclass(frozen=True)
class PlanSettings:
    """What to plan with (validated at construction).

    Attributes:
        Nmax: horizon of the first solve, samples; the move lasts Nmax·Ts.
        Nmin: smallest horizon of mode (b), k < Nmin ≤ Nmax (the paper: ≤ about 20, larger
            values do not improve the result).
        k: order of the system in samples: the last k outputs are penalized (2 for X = [y, ẏ]).
        Ts: sample time in s (default 10 ms); the plant the plan runs on must have the same.
        weights: square-root weights: Qy on the output, Qu on the input over the whole horizon
            (default ``Weights(1.0, 1e-6)``).
        limits: input :class:`~parallel_gpc.limits.Limits`: a torque limit |u| ≤ τ (the plan is
            in absolute inputs: no increment limit); default none.
        solver: back-end name (:func:`parallel_gpc.solvers.make_solver`); None resolves to
            ``"qr"`` without limits and :data:`~parallel_gpc.gpc.settings.DEFAULT_LIMITED_SOLVER`
            with limits.
        settle_steps: samples recorded after Nmax in modes (a) and (b) (default 400: mode (a)
            comes within 1 mm of B about 3.4·Nmax·Ts after the start on the default robot).
        reach_tolerance: (position m, orientation rad) band around B for the time to reach.
        plant_substeps: RK4 steps per sample of the default plant.

    Raises:
        InvalidParameterError: a horizon, Ts, weights, limits, solver or tolerance out of range.
    """

    Nmax: int = 120
    Nmin: int = 10
    k: int = 2
    Ts: float = 0.01
    weights: Weights = field(default_factory=lambda: Weights(1.0, 1e-6))
    limits: Limits = field(default_factory=Limits)
    solver: str | None = None
    settle_steps: int = 400
    reach_tolerance: tuple[float, float] = (1e-4, 1e-3)
    plant_substeps: int = 5

    def __post_init__(self):
        k = integer("order k", self.k, 1)
        Nmin = integer("Nmin", self.Nmin, 1)
        Nmax = integer("Nmax", self.Nmax, 1)
        if not k < Nmin <= Nmax:
            raise InvalidParameterError(f"horizons must satisfy k < Nmin ≤ Nmax; got k = {k}, Nmin = {Nmin}, "
                                        f"Nmax = {Nmax}")
        integer("settle_steps", self.settle_steps, 0)
        integer("plant_substeps", self.plant_substeps, 1)
        object.__setattr__(self, "Ts", positive("Ts", self.Ts, " s"))
        tol = tuple(self.reach_tolerance)
        if len(tol) != 2:
            raise InvalidParameterError(
                f"reach_tolerance = {self.reach_tolerance!r} must be (position m, orientation rad)")
        object.__setattr__(self, "reach_tolerance", (positive("reach tolerance (position)", tol[0], " m"),
                                                     positive("reach tolerance (orientation)", tol[1], " rad")))
        if not isinstance(self.weights, Weights):
            raise InvalidParameterError(f"weights must be a Weights(Qy, Qu), got {self.weights!r}")
        limits = as_limits(self.limits)
        if limits.du is not None:
            raise InvalidParameterError(f"the plan is in absolute inputs: its limits {limits!r} may not hold a du "
                                        "limit (give the torque limit only)")
        object.__setattr__(self, "limits", limits)
        solver = DEFAULT_LIMITED_SOLVER if self.solver is None and limits.needs_qp else self.solver
        object.__setattr__(self, "solver", resolve_solver(solver, "absolute", limits))

    @property
    def duration(self) -> float:
        """Planned move time Nmax·Ts in s."""
        return self.Nmax * self.Ts

    def to_json(self) -> str:
        """The settings as JSON (weights and limits as plain lists)."""
        data = {f.name: getattr(self, f.name) for f in fields(self)}
        data["weights"] = {"Qy": np.asarray(self.weights.Qy).tolist(), "Qu": np.asarray(self.weights.Qu).tolist()}
        data["limits"] = self.limits.to_dict()
        return json.dumps(data)
