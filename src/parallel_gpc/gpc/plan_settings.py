"""Settings of quadratically-optimal point-to-point planning, eq. (20)–(21): horizons, weights, modes."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass

import numpy as np

from ..errors import InvalidParameterError
from .criterion import Weights
from ..validation import positive

MODES = ("a", "b", "once")
#: Back end used when torque limits are given and no solver is named: the paper's QR while the
#: limits are inactive, the exact active-set QP (DAQP) when they bind.
DEFAULT_LIMITED_SOLVER = "qr-first:daqp-direct"
#: How :attr:`PlanResult.stopped` starts when Ctrl-C stopped the plan.
INTERRUPTED = "interrupted (Ctrl-C)"
#: What each mode is called in tables and plots.
MODE_LABELS = {"a": "(a) receding, no stopping information", "b": "(b) shrinking horizon, stops",
               "once": "once: open loop (linear systems only)"}


def _integer(name: str, value, low: int) -> int:
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
        Ts: sample time in s (default 10 ms).
        Qy: square-root output weight (scalar, (n_y,) or (n_y, n_y)).
        Qu: square-root input weight over the whole horizon (scalar, (n_u,) or (n_u, n_u)).
        torque_limit: symmetric drive torque limit |u| ≤ τ in N·m (scalar or (n_u,)), or None.
        solver: back-end name (:func:`parallel_gpc.solvers.make_solver`); default ``"qr"``
            without limits and ``"qr-first:daqp-direct"`` with limits.
        settle_steps: samples recorded after Nmax in modes (a) and (b) (default 400: mode (a)
            comes within 1 mm of B about 3.4·Nmax·Ts after the start on the default robot).
        reach_tolerance: (position m, orientation rad) band around B for the time to reach.
        plant_substeps: RK4 steps per sample of the default plant.
    """

    Nmax: int = 120
    Nmin: int = 10
    k: int = 2
    Ts: float = 0.01
    Qy: object = 1.0
    Qu: object = 1e-6
    torque_limit: object = None
    solver: str | None = None
    settle_steps: int = 400
    reach_tolerance: tuple[float, float] = (1e-4, 1e-3)
    plant_substeps: int = 5

    def __post_init__(self):
        k = _integer("order k", self.k, 1)
        Nmin = _integer("Nmin", self.Nmin, 1)
        Nmax = _integer("Nmax", self.Nmax, 1)
        if not k < Nmin <= Nmax:
            raise InvalidParameterError(f"horizons must satisfy k < Nmin ≤ Nmax; got k = {k}, Nmin = {Nmin}, "
                                        f"Nmax = {Nmax}")
        _integer("settle_steps", self.settle_steps, 0)
        _integer("plant_substeps", self.plant_substeps, 1)
        object.__setattr__(self, "Ts", positive("Ts", self.Ts, " s"))
        tol = tuple(self.reach_tolerance)
        if len(tol) != 2:
            raise InvalidParameterError(
                f"reach_tolerance = {self.reach_tolerance!r} must be (position m, orientation rad)")
        object.__setattr__(self, "reach_tolerance", (positive("reach tolerance (position)", tol[0], " m"),
                                                     positive("reach tolerance (orientation)", tol[1], " rad")))
        if self.torque_limit is not None:
            lim = np.asarray(self.torque_limit, dtype=float)
            if not np.all(np.isfinite(lim)) or np.any(lim <= 0):
                raise InvalidParameterError(f"torque_limit = {self.torque_limit!r} must be finite and > 0 (N·m)")
            if self.solver == "qr":
                raise InvalidParameterError(
                    "solver 'qr' cannot enforce torque limits; use a QP back end such as "
                    f"{DEFAULT_LIMITED_SOLVER!r}, 'osqp-direct' or 'qpsolvers:osqp'")

    @property
    def weights(self) -> Weights:
        return Weights(self.Qy, self.Qu)

    @property
    def solver_name(self) -> str:
        """The back end actually used."""
        if self.solver is not None:
            return self.solver
        return DEFAULT_LIMITED_SOLVER if self.torque_limit is not None else "qr"

    @property
    def duration(self) -> float:
        """Planned move time Nmax·Ts in s."""
        return self.Nmax * self.Ts

    def to_json(self) -> str:
        """The settings as JSON (arrays as lists)."""
        return json.dumps({k: (np.asarray(v).tolist() if isinstance(v, np.ndarray) else v)
                           for k, v in asdict(self).items()})


