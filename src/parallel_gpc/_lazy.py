"""Lazy re-exports (PEP 562) for package ``__init__`` modules.

A package lists its public names and the submodule that defines each; a name is imported on
first use, so importing the package (or a light submodule of it) does not pull in Pinocchio,
matplotlib or meshcat.
"""

from __future__ import annotations

import importlib


def lazy_exports(package: str, namespace: dict, public: dict[str, str]):
    """``(__getattr__, __dir__)`` for ``package`` that import ``public[name]`` (a submodule
    relative to the package) on first access of ``name`` and cache it in ``namespace``."""

    def __getattr__(name: str):
        module = public.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f".{module}", package), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(public))

    return __getattr__, __dir__
