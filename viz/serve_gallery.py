#!/usr/bin/env python3
"""Serve a folder of exported animations (``parallel-gpc ... --html``) on 127.0.0.1.

Usage: ``python viz/serve_gallery.py [DIR] [--port PORT]`` (DIR defaults to the current folder).
Prints the URL of a generated index page listing the ``*.html`` files; Ctrl-C stops the server.
The logic lives in :func:`parallel_gpc.viz.serve_gallery`.
"""

from __future__ import annotations

import argparse
import sys

from parallel_gpc.errors import ParallelGPCError
from parallel_gpc.viz import serve_gallery


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("directory", nargs="?", default=".", metavar="DIR",
                        help="folder of exported *.html animations (default: current folder)")
    parser.add_argument("--port", type=int, default=0, help="port on 127.0.0.1 (default 0: any free port)")
    args = parser.parse_args(argv)
    try:
        serve_gallery(args.directory, port=args.port)
    except ParallelGPCError as exc:
        print(f"serve_gallery: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
