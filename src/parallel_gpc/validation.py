"""Boundary checks shared by every module: shapes, finiteness, ranges.

Each helper raises one error of :mod:`parallel_gpc.errors` naming the value and what is valid.
"""

from __future__ import annotations

import numpy as np

from .errors import NonFiniteError, ShapeError, InvalidParameterError


def finite_vector(name: str, value, size: int | None = None) -> np.ndarray:
    """Return ``value`` as a finite 1-D float array, optionally of length ``size``.

    Raises:
        ShapeError: if it is not 1-D or has the wrong length.
        NonFiniteError: if it holds NaN or inf.
    """
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0 and size == 1:
        arr = arr.reshape(1)
    if arr.ndim != 1 or (size is not None and arr.shape[0] != size):
        want = f"({size},)" if size is not None else "1-D"
        raise ShapeError(f"{name} has shape {arr.shape}; expected {want}")
    if not np.all(np.isfinite(arr)):
        raise NonFiniteError(f"{name} = {arr} contains NaN or inf; it must be finite")
    return arr


def finite_matrix(name: str, value, shape: tuple[int | None, int | None]) -> np.ndarray:
    """Return ``value`` as a finite 2-D float array of ``shape`` (None = any size)."""
    arr = np.asarray(value, dtype=float)
    ok = arr.ndim == 2 and all(s is None or s == a for s, a in zip(shape, arr.shape))
    if not ok:
        raise ShapeError(f"{name} has shape {arr.shape}; expected {shape}")
    if not np.all(np.isfinite(arr)):
        raise NonFiniteError(f"{name} contains NaN or inf; it must be finite")
    return arr


def positive(name: str, value: float, unit: str = "") -> float:
    """Return ``value`` as a float if it is finite and > 0."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise InvalidParameterError(f"{name} = {value!r} is not a number") from None
    if not np.isfinite(x) or x <= 0.0:
        raise InvalidParameterError(f"{name} = {value!r}{unit} must be finite and > 0")
    return x
