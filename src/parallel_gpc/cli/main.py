"""The ``parallel-gpc`` parser and entry point.

Each sub-command module has a ``register_*`` function that adds its parser and sets ``func``;
the function receives the parsed arguments and returns an exit code. Command modules import
their heavy dependencies (Pinocchio, matplotlib, meshcat) inside the handler, so ``--help``
starts fast. Package errors and usage errors end the program with a one-line message and exit
code 2 (a traceback only with ``--debug``). Exit codes (:mod:`.defaults`): 0 done, 2 bad input, 3 a
closed loop of ``track`` or ``demo`` diverged (its samples are saved), 130 Ctrl-C (partial results saved).
"""

from __future__ import annotations

import argparse
import sys
import warnings

from .. import __version__
from ..errors import InvalidParameterError, ParallelGPCError, ParallelGPCWarning
from .bench import register_bench
from .demo import register_demo
from .gallery import register_gallery
from .info import register_info
from .plan import register_plan
from .robots import register_robots
from .robustness import register_robustness
from .sweep import register_sweep
from .track import register_track
from .view import register_view
from .vocabulary import apply_package_path

#: Sub-command registrars, in help order.
REGISTRARS = [register_robots, register_info, register_demo, register_track, register_plan, register_robustness,
              register_sweep, register_bench, register_view, register_gallery]


class Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors (an unknown choice, a missing value) raise
    :class:`~parallel_gpc.errors.InvalidParameterError`, which :func:`main` prints on one line."""

    def error(self, message: str):
        command = self.prog.removeprefix("parallel-gpc").strip()
        raise InvalidParameterError(f"{command}: {message}" if command else message)


def build_parser(registrars=None) -> argparse.ArgumentParser:
    """The ``parallel-gpc`` parser with every sub-command of ``registrars`` (default :data:`REGISTRARS`)."""
    parser = Parser(
        prog="parallel-gpc",
        description="Generalized Predictive Control of parallel robots (Pinocchio closed-chain models).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for register in REGISTRARS if registrars is None else registrars:
        register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one command; returns its exit code (2: bad input, 3: a closed loop diverged, 130: interrupted).
    The package's notices (:class:`~parallel_gpc.errors.ParallelGPCWarning`) print as one line on stderr,
    each distinct notice once (a command that loads the robot twice — controller and plant — says it once)."""
    with warnings.catch_warnings():
        shown = warnings.showwarning
        printed: set[str] = set()

        def one_line(message, category, *args, **kwargs):
            if not issubclass(category, ParallelGPCWarning):
                return shown(message, category, *args, **kwargs)
            if str(message) not in printed:
                printed.add(str(message))
                print(f"parallel-gpc: note: {message}", file=sys.stderr)

        warnings.showwarning = one_line
        return _run(argv)


def _run(argv: list[str] | None) -> int:
    parser = build_parser()
    args = None
    try:
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help()
            return 1
        apply_package_path(getattr(args, "package_path", None) or [])
        return int(args.func(args) or 0)
    except (ParallelGPCError, OSError) as exc:  # bad input or an unreadable/unwritable file
        if args is not None and args.debug:
            raise
        message = " ".join(str(exc).split())  # one line, even for multi-line parser messages
        print(f"parallel-gpc: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("parallel-gpc: interrupted", file=sys.stderr)
        return 130
