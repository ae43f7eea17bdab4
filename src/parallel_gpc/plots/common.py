"""Saving figures (the one place the plots touch the file system) and marks the figures share.

The plot functions of :mod:`plots_tracking`, :mod:`plots_planning`, :mod:`plots_robustness` and
:mod:`plots_bench` build :class:`matplotlib.figure.Figure` objects directly (no pyplot state,
no ``matplotlib.use()``), so they work headless and leave the caller's backend alone.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

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


#: Drive limit lines are drawn when the efforts reach this fraction of the limit; below it they
#: would squash the efforts into a flat line at zero, and the legend names the limit instead.
LIMIT_LINE_FRACTION = 0.1


def mark_drive_limit(ax, torque, peak: float, unit: str) -> None:
    """Show the drive limit on an effort axis: dotted lines at ± the largest limit when the
    efforts ``peak`` reach :data:`LIMIT_LINE_FRACTION` of it, else only a legend entry
    "drive limit ±L unit (off scale)" so that the efforts stay readable.

    Args:
        ax: the matplotlib axes of the drive efforts.
        torque: scalar or (n_u,) drive limit (N·m, N).
        peak: the largest |u| drawn on ``ax`` (same unit).
        unit: the drive unit for the legend ("N·m", "N").
    """
    lim = float(np.max(torque))
    if peak >= LIMIT_LINE_FRACTION * lim:
        for sign in (1, -1):
            ax.axhline(sign * lim, color="k", ls=":", lw=1, label="drive limit" if sign > 0 else None)
    else:
        ax.plot([], [], color="k", ls=":", lw=1, label=f"drive limit ±{lim:.3g} {unit} (off scale)")
