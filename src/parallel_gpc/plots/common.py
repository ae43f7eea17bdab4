"""Saving figures: the one place the plots touch the file system.

The plot functions of :mod:`plots_tracking`, :mod:`plots_planning`, :mod:`plots_robustness` and
:mod:`plots_bench` build :class:`matplotlib.figure.Figure` objects directly (no pyplot state,
no ``matplotlib.use()``), so they work headless and leave the caller's backend alone.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import writing

if TYPE_CHECKING:  # saving needs no matplotlib import of its own
    from matplotlib.figure import Figure


def save_figure(fig: Figure, path, dpi: int = 110, **kwargs) -> Path:
    """Write ``fig`` to ``path`` (format from the suffix, parent folders created); returns the path.

    Raises:
        OutputError: the file cannot be written (the path and the reason named).
    """
    path = Path(path)
    with writing(path, "figure"):
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=dpi, **kwargs)
    return path
