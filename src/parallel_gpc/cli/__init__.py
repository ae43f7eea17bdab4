"""Command-line interface: a thin layer over the library (``parallel-gpc --help``).

One module per command (``robots``, ``info``, ``track``/``demo``, ``plan``, ``robustness``,
``sweep``, ``bench``, ``view``, ``gallery``), :mod:`~parallel_gpc.cli.main` (parser and entry
point) and :mod:`~parallel_gpc.cli.vocabulary` (the option words the commands share).
``python -m parallel_gpc`` runs the same :func:`main`.
"""

from .main import REGISTRARS, build_parser, main

__all__ = ["REGISTRARS", "build_parser", "main"]
