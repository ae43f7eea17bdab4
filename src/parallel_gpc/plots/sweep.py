"""Plots of a sweep's result table: heatmaps over two axes, a Pareto front, robustness bands.

Every function takes the tidy table (a pandas DataFrame from
:func:`~parallel_gpc.sweeps.store.load_results` or ``SweepResult.frame()``) and returns a
matplotlib :class:`~matplotlib.figure.Figure` (no pyplot, the caller's backend is untouched);
save it with ``fig.savefig(path)``. Only cells with status ``"ok"`` enter the statistics; the
others are shown as such: a heatmap square with no ok run is grey and labelled "diverged" (its
closed loops diverged) or "failed", a value marked ``*`` also had diverged runs, and the titles
count the cells left out. :func:`check_plots` validates a ``[plots]`` table before any cell runs.
"""

from __future__ import annotations

import inspect
import math
from pathlib import Path

import numpy as np

from ..errors import InvalidParameterError

#: metric column -> (label, display unit, factor from the SI value to the display unit)
METRIC_LABELS = {
    "rms_position_error_m": ("RMS position error", "mm", 1e3),
    "max_position_error_m": ("max position error", "mm", 1e3),
    "rms_orientation_error_rad": ("RMS orientation error", "mrad", 1e3),
    "max_orientation_error_rad": ("max orientation error", "mrad", 1e3),
    "steady_state_error_m": ("steady-state position error", "mm", 1e3),
    "peak_drive_effort": ("peak drive effort", "N·m or N", 1.0),
    "drive_energy_J": ("drive energy (positive work)", "J", 1.0),
    "effort_integral": ("effort integral ∫‖u‖² dt", "N²·m²·s or N²·s", 1.0),
    "mean_step_time_s": ("mean controller step time", "ms", 1e3),
    "p99_step_time_s": ("p99 controller step time", "ms", 1e3),
    "mean_internal_force": ("mean internal-force effort", "N·m or N", 1.0),
    "max_internal_force": ("max internal-force effort", "N·m or N", 1.0),
    "wall_time_s": ("wall time of the cell", "s", 1.0),
}


#: Most Pareto-front points that get a parameter label.
MAX_LABELS = 8


def _label(metric: str) -> tuple[str, float]:
    name, unit, factor = METRIC_LABELS.get(metric, (metric, "", 1.0))
    return (f"{name} [{unit}]" if unit else name), factor


def _columns(frame, *names) -> None:
    missing = [n for n in names if n not in frame.columns]
    if missing:
        raise InvalidParameterError(f"columns {missing} are not in the sweep table; it has {list(frame.columns)}")


def _ok(frame):
    return frame[frame["status"] == "ok"] if "status" in frame else frame


def _left_out(frame) -> str:
    """Title note counting the cells that are not ok: ``", 2 diverged, 1 failed"``."""
    if "status" not in frame:
        return ""
    counts = frame["status"].value_counts()
    return "".join(f", {int(counts[s])} {s}" for s in ("diverged", "failed", "interrupted") if s in counts)


def _select(frame, where: dict | None):
    """The rows whose columns equal the values of ``where`` (e.g. ``{"form": "nonlinear"}``)."""
    for column, value in (where or {}).items():
        _columns(frame, column)
        frame = frame[frame[column] == value]
        if frame.empty:
            raise InvalidParameterError(f"no cell has {column} = {value!r}")
    return frame


def _figure(size):
    from matplotlib.figure import Figure

    return Figure(figsize=size, layout="constrained")


def heatmap(frame, x: str, y: str, metric: str = "rms_position_error_m", agg: str = "mean", where=None):
    """A heatmap of ``metric`` over two parameter axes (``agg`` over the other parameters and
    random samples: "mean", "median", "max" or "min"), on the rows selected by ``where``
    (``{column: value}``). Cells with no successful run are grey and labelled "failed".

    Raises:
        InvalidParameterError: an axis or metric not in the table, an unknown ``agg``, or a
            ``where`` that selects nothing.
    """
    import matplotlib

    _columns(frame, x, y, metric)
    frame = _select(frame, where)
    if agg not in ("mean", "median", "max", "min"):
        raise InvalidParameterError(f"agg {agg!r} is not one of mean, median, max, min")
    label, factor = _label(metric)
    xs = sorted(frame[x].dropna().unique(), key=_sort_key)
    ys = sorted(frame[y].dropna().unique(), key=_sort_key)
    ok = _ok(frame)
    grid = np.full((len(ys), len(xs)), np.nan)
    for (xv, yv), group in ok.groupby([x, y]):
        values = group[metric].astype(float).dropna()
        if len(values):
            grid[ys.index(yv), xs.index(xv)] = factor * getattr(values, agg)()
    diverged = np.zeros(grid.shape, dtype=bool)
    if "status" in frame:
        for (xv, yv), group in frame[frame["status"] == "diverged"].groupby([x, y]):
            diverged[ys.index(yv), xs.index(xv)] = True
    fig = _figure((1.6 + 0.9 * len(xs), 1.4 + 0.55 * len(ys)))
    ax = fig.add_subplot()
    cmap = matplotlib.colormaps["viridis"].with_extremes(bad="0.8")
    image = ax.imshow(np.ma.masked_invalid(grid), origin="lower", aspect="auto", cmap=cmap)
    for (i, j), value in np.ndenumerate(grid):
        text = ("diverged" if diverged[i, j] else "failed") if np.isnan(value) \
            else f"{value:.3g}" + ("*" if diverged[i, j] else "")
        # black on a light cell, white on a dark one: the luminance of the cell's own colour
        r, g, b, _ = (0.8, 0.8, 0.8, 1.0) if np.isnan(value) else image.cmap(image.norm(value))
        ax.text(j, i, text, ha="center", va="center", fontsize=7, color="k" if 0.299 * r + 0.587 * g + 0.114 * b > 0.5 else "w")
    ax.set_xticks(range(len(xs)), [_tick(v) for v in xs])
    ax.set_yticks(range(len(ys)), [_tick(v) for v in ys])
    ax.set_xlabel(x)
    ax.set_ylabel(y)
    ax.set_title(f"{agg} {label}" + "".join(f", {k} = {v}" for k, v in (where or {}).items())
                 + (" (* some runs diverged)" if np.any(diverged & np.isfinite(grid)) else ""), fontsize=10)
    fig.colorbar(image, ax=ax, label=label)
    return fig


def _log_if_wide(ax, values) -> None:
    """Log scale on y when the positive values span more than two decades."""
    positive = values[np.isfinite(values) & (values > 0)]
    if positive.size and positive.max() > 100 * positive.min():
        ax.set_yscale("log")


def _sort_key(value):
    return (0, float(value), "") if isinstance(value, (int, float, np.number)) else (1, 0.0, str(value))


def _tick(value) -> str:
    return f"{value:g}" if isinstance(value, (float, np.floating)) else str(value)


def pareto_mask(cost, error) -> np.ndarray:
    """(n,) bool: the points no other point beats in both cost and error (both minimised)."""
    cost, error = np.asarray(cost, dtype=float), np.asarray(error, dtype=float)
    mask = np.zeros(len(cost), dtype=bool)
    for i in range(len(cost)):
        if not (np.isfinite(cost[i]) and np.isfinite(error[i])):
            continue
        dominated = (cost <= cost[i]) & (error <= error[i]) & ((cost < cost[i]) | (error < error[i]))
        mask[i] = not np.any(dominated)
    return mask


def pareto_front(frame, error: str = "rms_position_error_m", cost: str = "drive_energy_J", labels=(), where=None):
    """Tracking error against drive cost for every successful cell (of the rows selected by
    ``where``), the Pareto front joined and its points annotated with the ``labels`` columns."""
    _columns(frame, error, cost, *labels)
    frame = _select(frame, where)
    ok = _ok(frame)
    (ylabel, yf), (xlabel, xf) = _label(error), _label(cost)
    c, e = ok[cost].to_numpy(dtype=float) * xf, ok[error].to_numpy(dtype=float) * yf
    front = pareto_mask(c, e)
    fig = _figure((6.4, 4.6))
    ax = fig.add_subplot()
    ax.scatter(c[~front], e[~front], s=14, color="0.6", label="cells")
    order = np.argsort(c[front])
    ax.plot(c[front][order], e[front][order], "o-", color="C3", label="Pareto front")
    on_front = ok[front].iloc[order]
    step = max(1, math.ceil(len(on_front) / MAX_LABELS))  # label at most MAX_LABELS front points
    for j, ((_, row), xv, yv) in enumerate(zip(on_front.iterrows(), c[front][order], e[front][order])):
        if labels and j % step == 0:
            ax.annotate(", ".join(f"{k}={_tick(row[k])}" for k in labels), (xv, yv), fontsize=7,
                        textcoords="offset points", xytext=(6, 6 + 8 * (j // step % 2)))
    _log_if_wide(ax, e)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3)
    ax.set_title(f"{front.sum()} of {len(ok)} ok cells on the front" + _left_out(frame), fontsize=10)
    ax.legend(fontsize=8)
    return fig


def robustness_bands(frame, x: str = "mass_scale", metric: str = "rms_position_error_m", group: str | None = "form",
                     quantiles=(0.05, 0.95), where=None):
    """Median of ``metric`` over ``x`` (e.g. the plant mismatch), one line per value of ``group``,
    with a band between the given quantiles of the other samples (noise seeds, loads …), on the
    rows selected by ``where``."""
    _columns(frame, x, metric, *([group] if group else []))
    frame = _select(frame, where)
    lo, hi = quantiles
    if not 0.0 <= lo < hi <= 1.0:
        raise InvalidParameterError(f"quantiles {quantiles} must satisfy 0 ≤ low < high ≤ 1")
    ok = _ok(frame)
    label, factor = _label(metric)
    fig = _figure((6.4, 4.4))
    ax = fig.add_subplot()
    groups = ok.groupby(group) if group else [("all", ok)]
    for name, part in groups:
        stats = part.groupby(x)[metric].quantile([lo, 0.5, hi]).unstack()
        xs = stats.index.to_numpy(dtype=float)
        (line,) = ax.plot(xs, factor * stats[0.5], "o-", label=f"{group} = {name}" if group else "median")
        ax.fill_between(xs, factor * stats[lo], factor * stats[hi], alpha=0.2, color=line.get_color())
    _log_if_wide(ax, factor * ok[metric].to_numpy(dtype=float))
    ax.set_xlabel(x)
    ax.set_ylabel(label)
    ax.grid(True, alpha=0.3)
    ax.set_title(f"median and {lo:.0%}–{hi:.0%} band of the ok cells" + _left_out(frame), fontsize=10)
    ax.legend(fontsize=8)
    return fig


#: Plot kinds of a spec's [plots] table and the function drawing each.
PLOT_KINDS = {"heatmap": heatmap, "pareto": pareto_front, "bands": robustness_bands}


#: Arguments of the plot functions that name one column of the table.
_COLUMN_ARGUMENTS = ("x", "y", "metric", "error", "cost", "group")


def check_plots(plots, columns) -> None:
    """Validate a spec's ``[plots]`` table before any cell runs: known kinds, arguments the plot
    function takes, column names the table will have (``columns``), ``agg`` and ``quantiles``.
    (Whether a ``where`` selects any row is known only from the results.)

    Args:
        plots: the ``[plots]`` table. columns: the columns of the sweep's table
            (:attr:`~parallel_gpc.sweeps.spec.SweepSpec.columns`).

    Raises:
        InvalidParameterError: naming the plot, the argument and what is valid.
    """
    if not isinstance(plots, dict):
        raise InvalidParameterError(f"[plots] must be a table of plot kinds, got {plots!r}")
    columns = list(columns)
    for kind, requests in plots.items():
        if kind not in PLOT_KINDS:
            raise InvalidParameterError(f"[plots] {kind!r} is not one of {list(PLOT_KINDS)}")
        for kwargs in requests if isinstance(requests, list) else [requests]:
            if not isinstance(kwargs, dict):
                raise InvalidParameterError(f"[plots] {kind}: each plot is a table of arguments, got {kwargs!r}")
            try:
                bound = inspect.signature(PLOT_KINDS[kind]).bind(None, **kwargs)
            except TypeError as exc:
                raise InvalidParameterError(f"[plots] {kind} {kwargs}: {exc}") from None
            bound.apply_defaults()
            args = bound.arguments
            named = [args[k] for k in _COLUMN_ARGUMENTS if args.get(k) is not None]
            labels, where = args.get("labels", ()), args.get("where") or {}
            if not isinstance(labels, (list, tuple)) or not isinstance(where, dict):
                raise InvalidParameterError(f"[plots] {kind} {kwargs}: labels must be a list of columns and where "
                                            "a table {column = value}")
            bad = [c for c in [*named, *labels, *where] if not isinstance(c, str) or c not in columns]
            if bad:
                raise InvalidParameterError(f"[plots] {kind} {kwargs}: {bad} not among the sweep table's columns "
                                            f"{columns}")
            if args.get("agg", "mean") not in ("mean", "median", "max", "min"):
                raise InvalidParameterError(f"[plots] {kind}: agg {args['agg']!r} is not one of mean, median, max, min")
            q = args.get("quantiles", (0.05, 0.95))
            if not (isinstance(q, (list, tuple)) and len(q) == 2 and all(isinstance(v, (int, float))
                                                                       and not isinstance(v, bool) for v in q)
                    and 0.0 <= q[0] < q[1] <= 1.0):
                raise InvalidParameterError(f"[plots] {kind}: quantiles {q!r} must be [low, high] with "
                                            "0 ≤ low < high ≤ 1")


def plot_sweep(frame, plots: dict, directory) -> list:
    """Draw the plots a spec's ``[plots]`` table asks for into ``directory``; returns the paths.

    ``plots`` maps a kind (``heatmap``, ``pareto``, ``bands``) to the keyword arguments of its
    function, or a list of such tables (one figure each).

    Raises:
        InvalidParameterError: an unknown kind or argument.
    """
    from .common import save_figure

    paths = []
    for kind, requests in plots.items():
        if kind not in PLOT_KINDS:
            raise InvalidParameterError(f"[plots] {kind!r} is not one of {list(PLOT_KINDS)}")
        for i, kwargs in enumerate(requests if isinstance(requests, list) else [requests]):
            try:
                fig = PLOT_KINDS[kind](frame, **kwargs)
            except TypeError as exc:
                raise InvalidParameterError(f"[plots] {kind} {kwargs}: {exc}") from None
            suffix = "_".join(str(v) for k, v in sorted(kwargs.items()) if isinstance(v, str))
            paths.append(save_figure(fig, Path(directory) / (f"{kind}{i}_{suffix}.png" if suffix else f"{kind}{i}.png")))
    return paths
