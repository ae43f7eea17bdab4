"""Boundary checks shared by every module: shapes, finiteness, ranges.

Each helper raises one error of :mod:`parallel_gpc.errors` naming the value and what is valid.
"""

from __future__ import annotations

import math
import os
import stat

import numpy as np

from .errors import NonFiniteError, ShapeError, InvalidParameterError


def all_finite(arr: np.ndarray) -> bool:
    """True when every entry of the float array ``arr`` is finite (the method call skips
    ``np.all``'s dispatch: half the time on the control step's small arrays)."""
    return bool(np.isfinite(arr).all())


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
    if not all_finite(arr):
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


def read_only(value) -> np.ndarray | None:
    """A read-only float64 copy of ``value`` (None stays None): arrays an object shares with its
    callers, which must not change under it."""
    if value is None:
        return None
    arr = np.array(value, dtype=float, copy=True)
    arr.setflags(write=False)
    return arr


def positive(name: str, value: float, unit: str = "") -> float:
    """Return ``value`` as a float if it is a real number (not a string or bool), finite and > 0."""
    x = number(name, value)
    if not np.isfinite(x) or x <= 0.0:
        raise InvalidParameterError(f"{name} = {value!r}{unit} must be finite and > 0")
    return x


def number(name: str, value) -> float:
    """Return ``value`` as a float; a string, a bool or a non-real object is refused.

    Raises:
        InvalidParameterError: naming the value and its type.
    """
    if isinstance(value, (str, bytes, bool, np.bool_)) or np.ndim(value) != 0:
        raise InvalidParameterError(f"{name} = {value!r} ({type(value).__name__}) must be a real number")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise InvalidParameterError(f"{name} = {value!r} ({type(value).__name__}) must be a real number") from None


def rounded(values, digits: int = 6) -> list[float]:
    """``values`` rounded to ``digits`` decimals, as a list for a message or a table, without
    negative zeros (a pose component of −1e-12 m shows as 0.0, not -0.0)."""
    return (np.round(np.asarray(values, dtype=float), digits) + 0.0).tolist()


def check_sample_time(owner, Ts: float, what: str, whose: str, required: bool = True) -> None:
    """Refuse ``owner`` (a plant, a discrete model) whose own sample time ``owner.Ts`` differs from
    ``Ts`` (relative 1e-12); checked once, where a loop or a controller starts, never per sample.

    Args:
        owner: the object with a ``Ts`` attribute (s). Ts: the sample time it must have (s).
        what: the owner, for the message (``"plant"``, ``"model"``). whose: the other owner
            (``"the controller's"``).
        required: an owner without ``Ts`` (or with Ts None) is refused; False lets it pass.

    Raises:
        InvalidParameterError: naming both sample times and the fix.
    """
    own = getattr(owner, "Ts", None)
    if own is None:
        if required:
            raise InvalidParameterError(f"the {what} {type(owner).__name__} has no sample time Ts; build it with "
                                        f"{whose} Ts = {Ts!r} s")
        return
    if not math.isclose(float(own), float(Ts), rel_tol=1e-12, abs_tol=0.0):
        raise InvalidParameterError(f"{whose} Ts = {Ts!r} s differs from the {what}'s own sample time Ts = {own!r} s; "
                                    "give both the same Ts (one sample time per loop)")


#: Largest estimated memory (bytes) of the dense arrays one problem or one run allocates.
MAX_ALLOCATION_BYTES = 1 << 30


def _size_text(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if n < 1024 or unit == "TiB":
            return f"{n:.3g} {unit}"
        n /= 1024.0
    return f"{n:.3g} TiB"  # pragma: no cover


def check_allocation(what: str, n_floats: float, fix: str) -> None:
    """Refuse, before allocating, arrays of ``n_floats`` float64 beyond :data:`MAX_ALLOCATION_BYTES`.

    Args:
        what: what would be allocated, with the sizes that set it (named in the message).
        n_floats: estimated number of float64 values.
        fix: which parameter to reduce.

    Raises:
        InvalidParameterError: naming the estimate and the limit.
    """
    need = 8.0 * float(n_floats)
    if need > MAX_ALLOCATION_BYTES:
        raise InvalidParameterError(f"{what} would need about {_size_text(need)}; the limit is "
                                    f"{_size_text(MAX_ALLOCATION_BYTES)}: {fix}")


def regular_file(path, what: str, error=InvalidParameterError) -> int:
    """The size in bytes of ``path`` if it is a regular file (symlinks followed), before any read.

    Args:
        path: the file. what: its role, for the message (``"sidecar"``, ``"result file"``).
        error: the package error class to raise.

    Raises:
        error: missing, a folder, or not a regular file (a device such as /dev/zero, a FIFO, a socket).
    """
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise error(f"{what} {str(path)!r} does not exist") from None
    except OSError as exc:
        raise error(f"{what} {str(path)!r} cannot be opened: {exc.strerror or exc}") from None
    if stat.S_ISDIR(info.st_mode):
        raise error(f"{what} {str(path)!r} is a folder; give the path of a file")
    if not stat.S_ISREG(info.st_mode):
        raise error(f"{what} {str(path)!r} is not a regular file (a device, FIFO or socket)")
    return info.st_size
