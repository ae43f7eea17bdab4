"""``python -m parallel_gpc``: the ``parallel-gpc`` command line."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
