"""The parsers' console output (urdfdom's ``Error:`` lines on file descriptor 2) captured while a
model is built, and put into our error message instead of around it."""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile

from ..errors import RobotFormatError


@contextlib.contextmanager
def captured_c_stderr():
    """Capture what C code writes to file descriptor 2 (e.g. urdfdom's ``Error:`` lines).

    Yields a list that holds the captured text (one string) after the block.
    """
    captured: list[str] = []
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield captured
        finally:
            try:
                import ctypes

                ctypes.CDLL(None).fflush(None)
            except (OSError, AttributeError):  # pragma: no cover - no C library handle
                pass
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            captured.append(tmp.read(1 << 16).decode("utf-8", "replace"))


def quiet_build(build, description):
    """``build(description)`` with the parsers' console output (urdfdom's ``Error:`` lines)
    captured; on a package error the captured text goes into its message instead.
    """
    with captured_c_stderr() as out:
        try:
            return build(description)
        except RobotFormatError as exc:
            error = exc
    noise = " ".join(out[0].split())
    raise RobotFormatError(f"{error}" + (f" (parser output: {noise[:300]})" if noise else "")) from error
