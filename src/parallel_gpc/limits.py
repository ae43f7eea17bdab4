"""Limits of a controlled robot: one frozen, validated type, :class:`Limits`.

Every place that limits the inputs takes a :class:`Limits` whole — the controller's settings
(:class:`~parallel_gpc.gpc.GPCSettings`), the planner's (:class:`~parallel_gpc.gpc.PlanSettings`),
the tracking study's (:class:`~parallel_gpc.studies.TrackingSettings`), the plant's drive saturation
(:class:`~parallel_gpc.model.ConstrainedPlant`) — and reads its named fields; nothing re-checks
it. A limit is validated once, when the :class:`Limits` is built (finite, > 0, a scalar or one
value per drive), and sized to the drive count once, by :meth:`Limits.for_drives`, where the
drive count is first known.

Kinds now (symmetric, per drive, hard):

* ``torque``: |u(k+i)| ≤ τ over the control horizon (N·m for revolute drives, N for prismatic ones);
* ``du``: |u(k+i) − u(k+i−1)| ≤ δ per sample, u(k−1) the input applied last (same unit per sample;
  incremental forms).

Kinds to come (drive positions, passive joint positions, an output box, output and drive
velocities, hard or soft) are further optional named fields of the same frozen type, listed in
:data:`KINDS`, validated in :meth:`Limits.__post_init__` and sized in :meth:`Limits.for_drives`
like these two; a field that is None is no limit of that kind.

This module sits beside :mod:`parallel_gpc.validation` (it imports only NumPy and the errors) so
that the plants (``model``) and the controller (``gpc``) take the same type.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InfeasibleLimitsError, InvalidParameterError, ShapeError

__all__ = ["Limits", "KINDS", "as_limits", "symmetric_limit"]

#: the limit kinds a :class:`Limits` holds, by field name, with their meaning and unit.
KINDS = {"torque": "drive torque limit |u| ≤ τ (N·m, or N for prismatic drives)",
         "du": "drive increment limit |u(k) − u(k−1)| ≤ δ (N·m or N per sample)"}


def symmetric_limit(name: str, value, size: int | None = None) -> np.ndarray | None:
    """A symmetric limit ±value as a read-only float array; None stays None.

    Args:
        name: what the value is, for the message (``"torque"``, ``"plant torque_limit"``).
        value: a number (every drive) or a 1-D sequence (one per drive), finite and > 0.
        size: the drive count, when known: a number is broadcast to (size,), a sequence must
            have that length.

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
        raise ShapeError(f"{name} limit has shape {arr.shape}; expected a scalar or one value per drive (n_u,)")
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise InfeasibleLimitsError(f"{name} limit = {arr.tolist()} must be finite and > 0 (symmetric limits "
                                    "±value)")
    if size is not None:
        if arr.ndim == 0:
            arr = np.full(size, float(arr))
        elif arr.shape != (size,):
            raise ShapeError(f"{name} limit {arr.tolist()} has shape {arr.shape}; expected a scalar or one value "
                             f"per drive ({size},)")
    arr.setflags(write=False)
    return arr


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

    Raises:
        InvalidParameterError: a value that is not a number or a vector of numbers.
        ShapeError: a 2-D value, or per-drive values of different lengths.
        InfeasibleLimitsError: a value ≤ 0, NaN or infinite.
    """

    torque: np.ndarray | None = None
    du: np.ndarray | None = None

    def __post_init__(self):
        sizes = set()
        for kind in KINDS:
            arr = symmetric_limit(kind, getattr(self, kind))
            object.__setattr__(self, kind, arr)
            if arr is not None and arr.ndim == 1:
                sizes.add(arr.size)
        if len(sizes) > 1:
            raise ShapeError(f"per-drive limits of different lengths: {self!r}; give one value per drive "
                             "for each (or a scalar)")

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

    @property
    def has_input_limits(self) -> bool:
        """True when a torque or increment limit is set (what a QP back end must enforce)."""
        return self.torque is not None or self.du is not None

    @property
    def n_drives(self) -> int | None:
        """The drive count the per-drive values fix, or None (scalars only, or no limit)."""
        return next((arr.size for arr in self.values().values() if arr.ndim == 1), None)

    def for_drives(self, n_u: int) -> "Limits":
        """The same limits with every value an (n_u,) array (a scalar broadcast); ``self`` when
        already so.

        Raises:
            ShapeError: per-drive values that are not n_u long.
        """
        if all(arr.shape == (n_u,) for arr in self.values().values()):
            return self
        sized = {kind: symmetric_limit(kind, arr, n_u) for kind, arr in self.values().items()}
        return Limits(**sized)

    def scaled(self, factor: float) -> "Limits":
        """Every limit multiplied by ``factor`` > 0 (e.g. tightened by 1 − margin for a QP)."""
        return Limits(**{kind: arr * factor for kind, arr in self.values().items()})

    def to_dict(self) -> dict[str, float | list[float] | None]:
        """Plain-Python values by kind (None when unset): JSON and result-file metadata."""
        return {kind: None if getattr(self, kind) is None else getattr(self, kind).tolist() for kind in KINDS}

    def __eq__(self, other) -> bool:
        if not isinstance(other, Limits):
            return NotImplemented
        return all((a is None and b is None) or (a is not None and b is not None and a.shape == b.shape
                                                 and bool(np.array_equal(a, b)))
                   for a, b in ((getattr(self, k), getattr(other, k)) for k in KINDS))

    def __hash__(self) -> int:
        return hash(tuple((k, None if v is None else (v.shape, v.tobytes())) for k, v in
                          ((k, getattr(self, k)) for k in KINDS)))

    def __repr__(self) -> str:
        return "Limits(" + ", ".join(f"{k}={v!r}" for k, v in self.to_dict().items() if v is not None) + ")"



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
