"""``parallel-gpc gallery [DIR] [--port PORT]``: serve a folder of exported animations on 127.0.0.1.

Prints the URL of a generated index page listing the ``*.html`` files; Ctrl-C stops the server.
Needs neither meshcat nor Pinocchio.
"""

from __future__ import annotations


def cmd_gallery(args) -> int:
    from ..viz import serve_gallery

    serve_gallery(args.directory, port=args.port)
    return 0


def add_gallery_arguments(p) -> None:
    """Add DIR and --port."""
    p.add_argument("directory", nargs="?", default=".", metavar="DIR",
                   help="folder of exported *.html animations (default: current folder)")
    p.add_argument("--port", type=int, default=0, help="port on 127.0.0.1 (default 0: any free port)")


def register_gallery(sub) -> None:
    """Add the ``gallery`` sub-command."""
    p = sub.add_parser("gallery", help="serve a folder of exported *.html animations on 127.0.0.1 (Ctrl-C stops)")
    add_gallery_arguments(p)
    p.set_defaults(func=cmd_gallery)
