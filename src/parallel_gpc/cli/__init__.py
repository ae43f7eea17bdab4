"""Command-line interface: a thin layer over the library (``parallel-gpc --help``).

One module per command (``robots``, ``info``, ``track``/``demo``, ``plan``, ``robustness``,
``bench``, ``view``, ``gallery``) and :mod:`~parallel_gpc.cli.main` (parser and entry point).
``python -m parallel_gpc`` runs the same :func:`main`.
"""

from .main import REGISTRARS, build_parser, main

__all__ = ["REGISTRARS", "build_parser", "main"]
