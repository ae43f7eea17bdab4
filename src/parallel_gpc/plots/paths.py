"""Path views in a robot's output space, shared by the tracking and planning figures: the plane or
space of the translational outputs present, axes named by the output labels in their units."""

from __future__ import annotations

from matplotlib.figure import Figure

from ..model import OutputSpace


def path_columns(space: OutputSpace) -> list[int]:
    """Outputs a path view draws: the translational ones (m), or every output when all are
    angles (rad)."""
    return space.translational or list(range(space.n_y))


def path_axes(fig: Figure, space: OutputSpace, position=(1, 1, 1)):
    """An axes for the path in the plane or space of the outputs of :func:`path_columns`:
    3-D for three or more (the first three), a plane for two, the coordinate over time for one;
    labelled with the output names and units. Returns (axes, columns drawn: 3, 2, or the one
    drawn over time). ``position``: (rows, columns, index) of ``fig.add_subplot``."""
    cols = path_columns(space)
    if len(cols) >= 3:
        ax = fig.add_subplot(*position, projection="3d")
        cols = cols[:3]
        ax.set_xlabel(space.axis_label(cols[0]))
        ax.set_ylabel(space.axis_label(cols[1]))
        ax.set_zlabel(space.axis_label(cols[2]))
        return ax, cols
    ax = fig.add_subplot(*position)
    if len(cols) == 2:
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel(space.axis_label(cols[0]))
        ax.set_ylabel(space.axis_label(cols[1]))
        return ax, cols
    ax.set_xlabel("t [s]")
    ax.set_ylabel(space.axis_label(cols[0]))
    return ax, cols[:1]


def draw_path(ax, cols: list[int], t: np.ndarray, poses: np.ndarray, *args, **kwargs):
    """Plot poses (K, n_y) on an axes of :func:`path_axes`: columns ``cols`` against each other,
    or the one column over the times t (s)."""
    if len(cols) == 1:
        return ax.plot(t, poses[:, cols[0]], *args, **kwargs)
    return ax.plot(*(poses[:, c] for c in cols), *args, **kwargs)
