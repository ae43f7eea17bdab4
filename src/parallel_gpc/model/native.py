"""Access to the compiled core ``parallel_gpc._native`` (C++ against Pinocchio's C++ API).

The compiled functions are the fast path of the model update and the plant; the Python modules
stay the reference, and tests compare the two. The compiled core is used when

* the extension module imports (``pip install .`` builds it; a source checkout on ``PYTHONPATH``
  has it only after ``python native/build_inplace.py``),
* it was built against the Pinocchio version that is imported now (the model is handed over in
  Pinocchio's serialization format, and the libraries must match), and
* the environment variable ``PARALLEL_GPC_NATIVE`` is not ``0`` (``0`` forces the Python path,
  e.g. to time the reference or to rule the compiled core out while debugging).

:func:`native_module` returns the module or None; :func:`native_status` says which and why.
"""

from __future__ import annotations

import os
from functools import lru_cache

from ..errors import InvalidParameterError

__all__ = ["native_module", "native_status", "native_enabled", "compiled_part"]

#: environment variable that switches the compiled core off when set to "0"
ENV_SWITCH = "PARALLEL_GPC_NATIVE"


@lru_cache(maxsize=1)
def _load():
    """(module or None, reason) — the import is tried once per process."""
    try:
        from .. import _native  # type: ignore[attr-defined]
    except ImportError as exc:
        return None, f"not built ({exc}); pip install . builds it"
    import pinocchio as pin

    if _native.pinocchio_version != pin.__version__:
        return None, (f"built against Pinocchio {_native.pinocchio_version}, but Pinocchio {pin.__version__} is "
                      "imported: reinstall parallel-gpc (pip install .) to rebuild it")
    return _native, f"compiled core in use (Pinocchio {pin.__version__})"


def native_enabled() -> bool:
    """False when ``PARALLEL_GPC_NATIVE=0`` asks for the pure-Python reference path (read at each call:
    the switch may change while a program runs)."""
    return os.environ.get(ENV_SWITCH, "1").strip() != "0"


def native_module():
    """The extension module ``parallel_gpc._native``, or None (not built, Pinocchio version
    mismatch, or switched off by ``PARALLEL_GPC_NATIVE=0``)."""
    if not native_enabled():
        return None
    return _load()[0]


def native_status() -> str:
    """One line: whether the compiled core is used, and if not, why."""
    if not native_enabled():
        return f"pure-Python reference path ({ENV_SWITCH}=0)"
    return _load()[1]


def compiled_part(native, part: str, what: str):
    """The compiled class ``part`` (``"ModelUpdate"``, ``"Plant"``, ``"Riccati"``) for an object
    built with ``native``, or None for its Python reference path.

    Args:
        native: None = the compiled class when it is available, False = never, True = required.
        part: attribute name of the class in ``parallel_gpc._native``.
        what: what it is, for the message (e.g. ``"the compiled plant"``).

    Raises:
        InvalidParameterError: ``native`` is not None/True/False, or True while the class is not
            available (the message says why: not built, Pinocchio mismatch, switched off).
    """
    if native not in (None, True, False):
        raise InvalidParameterError(f"native = {native!r}; valid: None (automatic), True or False")
    if native is False:
        return None
    module = native_module()
    cls = None if module is None else getattr(module, part, None)
    if cls is None and native:
        why = native_status() if module is None else f"the compiled core has no {part}"
        raise InvalidParameterError(f"native=True asks for {what}, but it is not available: {why}")
    return cls
