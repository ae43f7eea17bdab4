"""Output paths checked before a command runs, so a long run never ends in an unwritable path."""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import InvalidParameterError


def prepare_out_dir(path) -> Path:
    """Create the output folder ``path`` (with parents) and check that it is a writable folder.

    Raises:
        InvalidParameterError: ``path`` (or a parent) is an existing file, or not writable.
    """
    out = Path(path)
    for parent in (out, *out.parents):
        if parent.exists() and not parent.is_dir():
            raise InvalidParameterError(f"--out {str(path)!r}: {str(parent)!r} is an existing file, not a folder; "
                                        "give a folder (it is created if missing)")
        if parent.exists():
            break
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InvalidParameterError(f"--out {str(path)!r}: cannot create the folder ({exc.strerror or exc})") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise InvalidParameterError(f"--out {str(path)!r}: the folder is not writable")
    return out


def check_output_file(option: str, path) -> None:
    """A file to be written later: not a folder, in a folder that exists (or can be made) and is writable.

    Raises:
        InvalidParameterError: naming the option and the path.
    """
    target = Path(path)
    if target.is_dir():
        raise InvalidParameterError(f"{option} {str(path)!r} is a folder; give a file name")
    parent = target.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise InvalidParameterError(f"{option} {str(path)!r}: {str(parent)!r} is not a writable folder")
    if target.exists() and not os.access(target, os.W_OK):
        raise InvalidParameterError(f"{option} {str(path)!r} exists and is not writable")


def check_view_outputs(args) -> None:
    """Check ``--html PATH`` (if given) before the run."""
    if getattr(args, "html", None):
        check_output_file("--html", args.html)
