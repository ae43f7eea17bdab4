"""Limits of a controlled robot: one frozen, validated type, :class:`Limits`.

Every place that limits the inputs takes a :class:`Limits` whole — the controller's settings
(:class:`~parallel_gpc.gpc.GPCSettings`), the planner's (:class:`~parallel_gpc.gpc.PlanSettings`),
the tracking study's (:class:`~parallel_gpc.studies.TrackingSettings`), the plant's drive saturation
(:class:`~parallel_gpc.model.ConstrainedPlant`) — and reads its named fields; nothing re-checks
it. A limit is validated once, when the :class:`Limits` is built (finite, > 0, a scalar or one
value per drive), and sized to the drive count once, by :meth:`Limits.for_drives`, where the
drive count is first known.

Input kinds (symmetric, per drive, always hard):

* ``torque``: |u(k+i)| ≤ τ over the control horizon (N·m for revolute drives, N for prismatic ones);
* ``du``: |u(k+i) − u(k+i−1)| ≤ δ per sample, u(k−1) the input applied last (same unit per sample;
  incremental forms).

State kinds (stage-wise over the predicted steps k+No+1..k+N, linearized along the prediction;
soft by default, see :data:`SOFT_DEFAULT`):

* ``drive_position``: q_lo ≤ q_a(ŷ(k+i)) ≤ q_hi, (n_u, 2) lower and upper bounds (m or rad: a
  leg's stroke, a crank's angle range), linearized through the drive Jacobian ∂q_a/∂y;
* ``drive_rate``: |q̇_a| ≤ r per drive (m/s or rad/s), q̇_a ≈ ∂q_a/∂y (ŷ(k+i) − ŷ(k+i−1)) / Ts;
* ``output_box``: y_lo ≤ ŷ(k+i) ≤ y_hi, (n_y, 2) bounds (m, rad; ±inf: that side free) — the
  workspace;
* ``output_velocity``: |ẏ| ≤ v per output (m/s, rad/s), ẏ ≈ (ŷ(k+i) − ŷ(k+i−1)) / Ts;
* ``joint_position``: q_lo ≤ q_j(ŷ(k+i)) ≤ q_hi per named passive one-DOF joint (revolute: rad,
  prismatic: m; a universal joint is two such joints, two ranges), ``{joint_name: (lo, hi)}``,
  linearized through the joint's row of the velocity map ∂q_j/∂y. The names are checked against
  the robot where the robot is known (the controller, the planner, the robot file).

A soft kind is relaxed by slack variables s ≥ 0 (one per bound and step) at the exact L1 cost
``penalty``·s plus a small quadratic ``penalty``·:data:`SOFT_QUADRATIC`·s²: the problem is
always feasible and the constraint holds exactly whenever it can (the penalty above the
constraint's Lagrange multiplier). A field that is None is no limit of that kind.

This module sits beside :mod:`parallel_gpc.validation` (it imports only NumPy and the errors) so
that the plants (``model``) and the controller (``gpc``) take the same type.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from .errors import InfeasibleLimitsError, InvalidParameterError, ShapeError

__all__ = ["Limits", "Kind", "KIND_TABLE", "KINDS", "INPUT_KINDS", "STATE_KINDS", "KINEMATIC_KINDS", "SOFT_DEFAULT",
           "DEFAULT_PENALTY", "SOFT_QUADRATIC", "as_limits", "symmetric_limit", "bound_pairs", "joint_ranges"]


@dataclass(frozen=True)
class Kind:
    """What one limit kind is: the one place that says so (the special cases read it).

    Attributes:
        meaning: the limit and its unit, for messages and help.
        on: ``"input"`` (the drive efforts u: hard, checked on every applied input) or ``"state"``
            (the predicted motion: stage-wise, linearized along the prediction, soft or hard).
        form: ``"symmetric"`` (±value, () or (n,)), ``"bounds"`` ((lower, upper) pairs, (1, 2) or
            (n, 2)) or ``"named"`` (``{joint_name: (lo, hi)}``).
        per: what one entry is for: ``"drive"`` (sized n_u), ``"output"`` (n_y) or ``"joint"`` (by name).
        kinematic: computed through the robot's kinematics (drive or joint positions and their
            Jacobians), not from the outputs or inputs alone.
    """

    meaning: str
    on: str
    form: str
    per: str
    kinematic: bool = False


#: every limit kind a :class:`Limits` holds, by field name, in field order.
KIND_TABLE = {
    "torque": Kind("drive torque limit |u| ≤ τ (N·m, or N for prismatic drives)", "input", "symmetric", "drive"),
    "du": Kind("drive increment limit |u(k) − u(k−1)| ≤ δ (N·m or N per sample)", "input", "symmetric",
               "drive"),
    "drive_position": Kind("drive position range q_lo ≤ q_a ≤ q_hi (m or rad; a stroke)", "state", "bounds",
                           "drive", kinematic=True),
    "drive_rate": Kind("drive rate limit |q̇_a| ≤ r (m/s or rad/s)", "state", "symmetric", "drive", kinematic=True),
    "output_box": Kind("workspace box y_lo ≤ y ≤ y_hi (m, rad)", "state", "bounds", "output"),
    "output_velocity": Kind("output velocity limit |ẏ| ≤ v (m/s, rad/s)", "state", "symmetric", "output"),
    "joint_position": Kind("passive joint ranges q_lo ≤ q_j ≤ q_hi by joint name (m or rad)", "state", "named",
                           "joint", kinematic=True),
}
#: the limit kinds, by field name, with their meaning and unit.
KINDS = {kind: k.meaning for kind, k in KIND_TABLE.items()}
#: kinds on the inputs (hard: the QP enforces them exactly, every applied input is checked).
INPUT_KINDS = tuple(kind for kind, k in KIND_TABLE.items() if k.on == "input")
#: kinds on the predicted motion (stage-wise, linearized along the prediction).
STATE_KINDS = tuple(kind for kind, k in KIND_TABLE.items() if k.on == "state")
#: kinds given as (lower, upper) pairs; the others are symmetric ±value or named ranges.
BOUND_KINDS = tuple(kind for kind, k in KIND_TABLE.items() if k.form == "bounds")
#: kinds sized by the outputs (n_y).
OUTPUT_KINDS = tuple(kind for kind, k in KIND_TABLE.items() if k.per == "output")
#: the state kinds computed through the robot's kinematics (positions and Jacobians of drives and joints):
#: linearized along the condensed prediction, not stage-wise.
KINEMATIC_KINDS = tuple(kind for kind, k in KIND_TABLE.items() if k.kinematic)
#: the kinds that are soft when ``soft`` is not given.
SOFT_DEFAULT = frozenset(STATE_KINDS)
#: default exact-penalty weight ρ of a soft kind: criterion units per unit of violation (m, rad, m/s, …).
DEFAULT_PENALTY = 1e3
#: the quadratic slack weight, relative to ρ (per unit²): keeps the QP strictly convex, small beside ρ·s.
SOFT_QUADRATIC = 1e-2


def symmetric_limit(name: str, value, size: int | None = None, per: str = "drive") -> np.ndarray | None:
    """A symmetric limit ±value as a read-only float array; None stays None.

    Args:
        name: what the value is, for the message (``"torque"``, ``"plant torque_limit"``).
        value: a number (every drive) or a 1-D sequence (one per drive), finite and > 0.
        size: the drive count, when known: a number is broadcast to (size,), a sequence must
            have that length.
        per: what one value is for, in messages (``"drive"``, ``"output"``).

    Returns:
        () or (n,) read-only array; (size,) when ``size`` is given.

    Raises:
        InvalidParameterError: not a number or a sequence of numbers (a string, a bool).
        ShapeError: 2-D or more, empty, or not ``size`` long.
        InfeasibleLimitsError: an entry ≤ 0, NaN or infinite (it admits no input, or none of use).
    """
    if value is None:
        return None
    entries = np.asarray(value, dtype=object).reshape(-1) if not isinstance(value, (str, bytes)) else [value]
    try:
        if any(isinstance(x, (str, bytes, bool, np.bool_)) for x in entries):
            raise TypeError
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise InvalidParameterError(f"{name} limit = {value!r} is not a number or a vector of numbers") from None
    if arr.ndim > 1 or (arr.ndim == 1 and arr.size == 0):
        raise ShapeError(f"{name} limit has shape {arr.shape}; expected a scalar or one value per {per}")
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise InfeasibleLimitsError(f"{name} limit = {arr.tolist()} must be finite and > 0 (symmetric limits "
                                    "±value)")
    if size is not None:
        if arr.ndim == 0:
            arr = np.full(size, float(arr))
        elif arr.shape != (size,):
            raise ShapeError(f"{name} limit {arr.tolist()} has shape {arr.shape}; expected a scalar or one value "
                             f"per {per} ({size},)")
    arr.setflags(write=False)
    return arr


def bound_pairs(name: str, value, size: int | None = None) -> np.ndarray | None:
    """(lower, upper) bounds as a read-only (k, 2) float array; None stays None.

    Args:
        name: the kind, for the message (``"drive_position"``).
        value: one pair ``[lo, hi]`` (every drive or output) or one pair per entry ``[[lo, hi], …]``;
            lo < hi, either may be ±inf (that side free) but not both NaN.
        size: the entry count, when known: one pair is broadcast to (size, 2).

    Raises:
        InvalidParameterError: not numbers. ShapeError: not (2,) or (k, 2), or not ``size`` long.
        InfeasibleLimitsError: a lower bound not below its upper bound, or NaN.
    """
    if value is None:
        return None
    try:
        if isinstance(value, (str, bytes)) or any(isinstance(x, (str, bytes, bool, np.bool_))
                                                  for x in np.asarray(value, dtype=object).reshape(-1)):
            raise TypeError
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise InvalidParameterError(f"{name} = {value!r} is not a pair [lower, upper] or a list of pairs") from None
    if arr.shape == (2,):
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] == 0:
        raise ShapeError(f"{name} has shape {arr.shape}; expected one pair [lower, upper] (2,) or one per entry (k, 2)")
    bad = np.flatnonzero(~(arr[:, 0] < arr[:, 1]))
    if bad.size:
        i = int(bad[0])
        raise InfeasibleLimitsError(f"{name}[{i}] = [{arr[i, 0]:g}, {arr[i, 1]:g}]: the lower bound must be below the "
                                    "upper bound (and neither NaN)")
    if size is not None:
        if arr.shape[0] == 1 and size != 1:
            arr = np.repeat(arr, size, axis=0)
        elif arr.shape[0] != size:
            raise ShapeError(f"{name} has {arr.shape[0]} pairs; expected one pair or {size} (one per entry)")
    arr.setflags(write=False)
    return arr


def joint_ranges(value) -> MappingProxyType | None:
    """Ranges of named joints as a read-only ``{name: (lo, hi)}`` mapping, sorted by name; None stays None.

    Args:
        value: a mapping ``{joint_name: [lo, hi]}`` (rad for a revolute joint, m for a prismatic
            one; lo < hi, either may be ±inf), or its items as pairs ``[(name, [lo, hi]), …]``.

    Raises:
        InvalidParameterError: not a mapping of names, empty. ShapeError: a range that is not a pair.
        InfeasibleLimitsError: a lower bound not below its upper bound.
    """
    if value is None:
        return None
    try:
        items = dict(value)
    except (TypeError, ValueError):
        items = None
    if not items or not all(isinstance(k, str) and k for k in items):
        raise InvalidParameterError(f"joint_position = {value!r} must be a non-empty mapping "
                                    "{joint_name: [lower, upper]} (rad or m)")
    out = {}
    for name in sorted(items):
        pair = bound_pairs(f"joint_position[{name!r}]", items[name])
        if pair.shape != (1, 2):
            raise ShapeError(f"joint_position[{name!r}] = {items[name]!r}: expected one pair [lower, upper]")
        out[name] = (float(pair[0, 0]), float(pair[0, 1]))
    return MappingProxyType(out)


def _check_value(kind: str, value, size: int | None = None):
    """A kind's value validated (and sized when ``size`` is given; named ranges are by name)."""
    form = KIND_TABLE[kind].form
    if form == "named":
        return joint_ranges(value)
    if form == "bounds":
        return bound_pairs(kind, value, size)
    return symmetric_limit(kind, value, size, KIND_TABLE[kind].per)


def _entries(kind: str, value) -> int | None:
    """The count of per-entry values a kind's validated value fixes (one per drive or output), None
    for one value for all (or named ranges, which are not sized)."""
    form = KIND_TABLE[kind].form
    if form == "bounds":
        return value.shape[0] if value.shape[0] > 1 else None
    if form == "symmetric":
        return value.shape[0] if value.ndim == 1 else None
    return None


@dataclass(frozen=True, eq=False, repr=False)
class Limits:
    """Input limits, validated when built (see the module docstring for the kinds).

    ``Limits()`` (or :meth:`none`) is no limit at all. A scalar applies to every drive; one value
    per drive is an (n_u,) sequence. :meth:`for_drives` gives the same limits as (n_u,) arrays
    for a robot with n_u drives.

    Attributes:
        torque: symmetric drive torque limit τ > 0, () or (n_u,) read-only array (N·m; N for
            prismatic drives), or None.
        du: symmetric increment limit δ > 0 on u(k) − u(k−1), () or (n_u,) read-only array
            (N·m or N per sample), or None. Incremental forms only.
        drive_position: (1, 2) or (n_u, 2) drive position bounds [lo, hi] (m or rad), or None.
        drive_rate: symmetric drive rate limit, () or (n_u,) (m/s or rad/s), or None.
        output_box: (1, 2) or (n_y, 2) output bounds [lo, hi] (m, rad; ±inf: free), or None.
        output_velocity: symmetric output velocity limit, () or (n_y,) (m/s, rad/s), or None.
        joint_position: read-only ``{joint_name: (lo, hi)}`` ranges of passive one-DOF joints
            (rad or m), sorted by name, or None.
        soft: the state kinds relaxed by slack variables (frozenset of names of
            :data:`STATE_KINDS`); default :data:`SOFT_DEFAULT` (every state kind), ``()``: all hard.
        penalty: exact L1 penalty weight ρ > 0 of the soft kinds (criterion units per unit of
            violation; default :data:`DEFAULT_PENALTY`).

    Raises:
        InvalidParameterError: a value that is not a number or a vector of numbers, a soft kind
            that is not a state kind, a penalty that is not finite and > 0.
        ShapeError: a 2-D symmetric value, or per-drive (per-output) values of different lengths.
        InfeasibleLimitsError: a value ≤ 0, NaN or infinite; a lower bound not below its upper one.
    """

    torque: np.ndarray | None = None
    du: np.ndarray | None = None
    drive_position: np.ndarray | None = None
    drive_rate: np.ndarray | None = None
    output_box: np.ndarray | None = None
    output_velocity: np.ndarray | None = None
    joint_position: MappingProxyType | None = None
    soft: frozenset = SOFT_DEFAULT
    penalty: float = DEFAULT_PENALTY

    def __post_init__(self):
        sizes = {"drive": set(), "output": set()}
        for kind in KINDS:
            arr = _check_value(kind, getattr(self, kind))
            object.__setattr__(self, kind, arr)
            if arr is not None and _entries(kind, arr) is not None:
                sizes[KIND_TABLE[kind].per].add(_entries(kind, arr))
        for what, found in sizes.items():
            if len(found) > 1:
                raise ShapeError(f"per-{what} limits of different lengths: {self!r}; give one value per "
                                 f"{what} for each (or one for all)")
        soft = self.soft
        if isinstance(soft, str) or not hasattr(soft, "__iter__"):
            raise InvalidParameterError(f"soft = {soft!r} must be a collection of kind names out of {list(STATE_KINDS)}")
        soft = frozenset(soft)
        wrong = sorted(str(k) for k in soft if k not in STATE_KINDS)
        if wrong:
            raise InvalidParameterError(f"soft = {sorted(map(str, soft))}: {wrong} cannot be soft; soft kinds are "
                                        f"{list(STATE_KINDS)} (torque and du limits are always hard)")
        object.__setattr__(self, "soft", soft)
        rho = self.penalty
        if isinstance(rho, (bool, np.bool_)) or not isinstance(rho, (int, float, np.integer, np.floating)) or \
                not np.isfinite(rho) or rho <= 0:
            raise InvalidParameterError(f"penalty = {rho!r} must be a finite number > 0 (criterion units per unit "
                                        "of violation)")
        object.__setattr__(self, "penalty", float(rho))

    @classmethod
    def none(cls) -> "Limits":
        """No limit of any kind."""
        return cls()

    def values(self) -> dict[str, np.ndarray]:
        """The limits that are set, by kind (``{"torque": τ, …}``)."""
        return {kind: getattr(self, kind) for kind in KINDS if getattr(self, kind) is not None}

    @property
    def is_empty(self) -> bool:
        """True when no limit of any kind is set."""
        return not self.values()

    def is_soft(self, kind: str) -> bool:
        """True when ``kind`` (a state kind that is set) is relaxed by slack variables."""
        return kind in self.soft

    @property
    def has_state_limits(self) -> bool:
        """True when a limit of a state kind (positions, rates, workspace) is set."""
        return any(getattr(self, kind) is not None for kind in STATE_KINDS)

    @property
    def has_kinematic_limits(self) -> bool:
        """True when a limit of a kind computed through the robot's kinematics (:data:`KINEMATIC_KINDS`) is set."""
        return any(getattr(self, kind) is not None for kind in KINEMATIC_KINDS)

    @property
    def needs_qp(self) -> bool:
        """True when the problem has limits a QP back end must enforce (input or state kinds)."""
        return self.has_input_limits or self.has_state_limits

    @property
    def has_input_limits(self) -> bool:
        """True when a torque or increment limit is set (what a QP back end must enforce)."""
        return self.torque is not None or self.du is not None

    @property
    def n_drives(self) -> int | None:
        """The drive count the per-drive values fix, or None (one value for all, or no limit)."""
        return next((_entries(kind, arr) for kind, arr in self.values().items()
                     if KIND_TABLE[kind].per == "drive" and _entries(kind, arr) is not None), None)

    def _options(self) -> dict:
        return {"soft": self.soft, "penalty": self.penalty}

    def for_drives(self, n_u: int, n_y: int | None = None) -> "Limits":
        """The same limits with every per-drive value (n_u,) or (n_u, 2) (one value broadcast),
        and, when ``n_y`` is given, every per-output value (n_y,) or (n_y, 2); ``self`` when
        already so.

        Raises:
            ShapeError: per-drive (per-output) values that are not n_u (n_y) long.
        """
        count = {"drive": n_u, "output": n_y, "joint": None}  # named ranges are not sized
        sizes = {kind: count[KIND_TABLE[kind].per] for kind in self.values()}
        sized = {kind: arr if sizes[kind] is None else _check_value(kind, arr, sizes[kind])
                 for kind, arr in self.values().items()}
        if all(sized[k] is self.values()[k] or sized[k].shape == self.values()[k].shape for k in sized):
            return self
        return Limits(**sized, **self._options())

    def scaled(self, factor: float) -> "Limits":
        """The input limits (torque, du) multiplied by ``factor`` > 0 (e.g. tightened by 1 − margin for
        a QP); the state kinds as they are."""
        values = {kind: arr * factor if kind in INPUT_KINDS else arr for kind, arr in self.values().items()}
        return Limits(**values, **self._options())

    def only(self, *kinds: str) -> "Limits":
        """The same limits with only ``kinds`` set (e.g. ``only("torque")`` for a plant's saturation)."""
        return Limits(**{k: v for k, v in self.values().items() if k in kinds}, **self._options())

    def check_pose(self, y, labels=None) -> None:
        """Raise when the output pose ``y`` (n_y,) lies outside the output box (a box that excludes
        the start pose admits no motion from it).

        Raises:
            InfeasibleLimitsError: naming the output, its value and the box.
        """
        box = self.output_box
        if box is None:
            return
        y = np.asarray(y, dtype=float).reshape(-1)
        box = bound_pairs("output_box", box, y.size)
        out = np.flatnonzero((y < box[:, 0]) | (y > box[:, 1]))
        if out.size:
            i = int(out[0])
            name = labels[i] if labels is not None else f"y[{i}]"
            raise InfeasibleLimitsError(f"the output box excludes the pose: {name} = {y[i]:.6g} is outside "
                                        f"[{box[i, 0]:g}, {box[i, 1]:g}]; the box must contain the start pose")

    def to_dict(self) -> dict:
        """Plain-Python values by kind (the input kinds always, None when unset; a state kind when
        set, with the soft kinds and the penalty): JSON and result-file metadata."""
        out = {kind: None if getattr(self, kind) is None else _plain(getattr(self, kind)) for kind in KINDS
               if kind in INPUT_KINDS or getattr(self, kind) is not None}
        if self.has_state_limits:
            out["soft"] = sorted(k for k in self.soft if getattr(self, k) is not None)
            out["penalty"] = self.penalty
        return out

    def describe(self) -> str:
        """One line naming every limit that is set (``"torque ±1000; drive_position [0.45, 1.3] (soft)"``),
        or ``"none"``."""
        parts = []
        for kind, arr in self.values().items():
            form = KIND_TABLE[kind].form
            if form == "named":
                text = "; ".join(f"{name} [{lo:g}, {hi:g}]" for name, (lo, hi) in arr.items()) if len(arr) <= 4 \
                    else f"{len(arr)} joints"
            elif form == "bounds":
                rows = np.unique(arr, axis=0)
                shown = rows if len(rows) == 1 else arr  # one range for all, else each in output order
                text = "; ".join(f"[{lo:g}, {hi:g}]" for lo, hi in shown) if len(shown) <= 6 else f"{len(arr)} ranges"
            else:
                flat = np.unique(arr)  # one value for all, else each in drive / output order
                shown = flat if flat.size == 1 else arr.ravel()
                text = "±" + ("/".join(f"{x:g}" for x in shown) if shown.size <= 6 else f"{arr.size} values")
            hardness = "" if kind in INPUT_KINDS else (" (soft)" if kind in self.soft else " (hard)")
            parts.append(f"{kind} {text}{hardness}")
        return ", ".join(parts) if parts else "none"

    def __eq__(self, other) -> bool:
        if not isinstance(other, Limits):
            return NotImplemented
        return self._options() == other._options() and all(
            (a is None and b is None) or (a is not None and b is not None and (
                dict(a) == dict(b) if KIND_TABLE[k].form == "named"
                else a.shape == b.shape and bool(np.array_equal(a, b))))
            for k, a, b in ((k, getattr(self, k), getattr(other, k)) for k in KINDS))

    def __hash__(self) -> int:
        return hash((tuple(sorted(self.soft)), self.penalty) + tuple(
            (k, None if v is None else tuple(v.items()) if KIND_TABLE[k].form == "named" else (v.shape, v.tobytes()))
            for k, v in ((k, getattr(self, k)) for k in KINDS)))

    def __repr__(self) -> str:
        return "Limits(" + ", ".join(f"{k}={v!r}" for k, v in self.to_dict().items()
                                     if v is not None and k in KINDS) + ")"


def _plain(value):
    """A kind's value as plain Python (lists; joint ranges as ``{name: [lo, hi]}``)."""
    if isinstance(value, MappingProxyType):
        return {name: list(pair) for name, pair in value.items()}
    return value.tolist()


def as_limits(value) -> Limits:
    """``value`` if it is a :class:`Limits`, ``Limits()`` for None.

    Raises:
        InvalidParameterError: anything else (a bare number: which kind would it limit?).
    """
    if value is None:
        return Limits()
    if not isinstance(value, Limits):
        raise InvalidParameterError(f"limits = {value!r} must be a Limits(torque=..., du=...) (or None: no limit)")
    return value
