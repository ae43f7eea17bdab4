#!/usr/bin/env python3
"""Serve a folder of exported animations on 127.0.0.1: the same as ``parallel-gpc gallery [DIR] [--port PORT]``.

Usage: ``python viz/serve_gallery.py [DIR] [--port PORT]`` (DIR defaults to the current folder).
The logic lives in the package (:mod:`parallel_gpc.cli.gallery`, :mod:`parallel_gpc.viz.gallery`).
"""

import sys

from parallel_gpc.cli import main

if __name__ == "__main__":
    sys.exit(main(["gallery", *sys.argv[1:]]))
