"""Text tables of closed-loop results: the one column mechanism behind every table the CLI prints
(:func:`~parallel_gpc.studies.tracking.metrics_table`, the demo's
:func:`~parallel_gpc.studies.comparison.comparison_table` and
:func:`~parallel_gpc.studies.comparison.sensors_table`).

A table is a few left-aligned key columns (form, gain, sensors) followed by :class:`Column` s, each
one a header, a unit line and a cell function of a result and its metrics; a run that did not end
normally gets its outcome appended to its row. Columns appear only for what the robot has: no
angle columns without angular outputs, the drive unit (N·m or N) from the results' output space.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, Sequence

from .simulation import SimulationResult

#: width of the form column every table starts with
FORM_WIDTH = 20


@dataclass(frozen=True)
class Column:
    """One right-aligned column: ``name`` over ``unit`` (e.g. ``"[mm]"``), ``width`` characters,
    ``cell(result, metrics)`` → the formatted cell (``metrics`` is ``result.metrics()``)."""

    name: str
    width: int
    unit: str
    cell: Callable[[SimulationResult, dict], str]


def text_table(keys: Sequence[tuple[str, int]], columns: Sequence[Column],
               rows: Iterable[tuple[Sequence[str], SimulationResult]]) -> str:
    """Format rows of results.

    Args:
        keys: (header, width) of the left-aligned key columns.
        columns: the result columns.
        rows: (key cells, result) per row; the key cells match ``keys``.

    Returns:
        Header line, unit line, one line per row ("  (outcome)" appended when not ``ok``).
    """
    def line(key_cells, cells):
        return " ".join([*(f"{c:<{w}}" for c, (_, w) in zip(key_cells, keys)), *cells])

    lines = [line([h for h, _ in keys], [f"{c.name:>{c.width}}" for c in columns]),
             line(["" for _ in keys], [f"{c.unit:>{c.width}}" for c in columns])]
    for key_cells, res in rows:
        m = res.metrics()
        lines.append(line(key_cells, [c.cell(res, m) for c in columns])
                     + ("" if res.outcome == "ok" else f"  ({res.outcome})"))
    return "\n".join(lines)


def output_space_of(results: Iterable[SimulationResult]):
    """The output space of the first result (None without results)."""
    first = next(iter(results), None)
    return None if first is None else first.output_space


def error_columns(space, steady: Callable[[SimulationResult], float] | None = None,
                  fmt: str = ".2e") -> list[Column]:
    """RMS and max position error (mm), optionally the steady-state error (mm, ``steady(result)``
    in m), and — when the outputs have angles (or ``space`` is None) — RMS and max orientation
    error (mrad, the norm of the angular output errors)."""
    def scaled(key):
        return lambda res, m: f"{1e3 * m[key]:9{fmt}}"

    cols = [Column("rms pos", 9, "[mm]", scaled("rms_position_error_m")),
            Column("max pos", 9, "[mm]", scaled("max_position_error_m"))]
    if steady is not None:
        cols.append(Column("steady", 9, "[mm]", lambda res, m: f"{1e3 * steady(res):9.2e}"))
    if space is None or space.has_angles:
        cols += [Column("rms ang", 9, "[mrad]", scaled("rms_orientation_error_rad")),
                 Column("max ang", 9, "[mrad]", scaled("max_orientation_error_rad"))]
    return cols


def effort_columns(space, drive_unit: str | None = None) -> list[Column]:
    """Peak drive effort and the internal-force measure, in ``drive_unit`` (default: the output
    space's, N·m without one)."""
    unit = f"[{drive_unit or (space.drive_unit if space else 'N·m')}]"
    return [Column("peak u", 8, unit, lambda res, m: f"{m['peak_drive_effort']:8.2f}"),
            Column("int. f", 8, unit, lambda res, m: f"{m['max_internal_force']:8.1e}")]


def gain_column() -> Column:
    """The gain α of the state-disturbance estimate the run used."""
    return Column("est. α", 6, "", lambda res, m: f"{res.meta.get('disturbance_gain', float('nan')):6.2f}")


def solver_column() -> Column:
    """The back end the run's controller used (its default resolved: ``riccati``, ``qr``, …)."""
    return Column("solver", 20, "", lambda res, m: f"{str(res.meta.get('solver', '?')):>20}")


def step_time_columns(Ts: float | None = None) -> list[Column]:
    """Mean and largest (``p99`` without ``Ts``) controller step time in ms; with ``Ts`` the number
    of steps longer than Ts (deadline overruns)."""
    cols = [Column("mean step", 9, "[ms]", lambda res, m: f"{1e3 * m['mean_step_time_s']:9.3f}")]
    if Ts is None:
        return cols + [Column("p99 step", 9, "[ms]", lambda res, m: f"{1e3 * m['p99_step_time_s']:9.3f}")]
    return cols + [Column("max step", 9, "[ms]", lambda res, m: f"{1e3 * float(res.step_time.max()):9.3f}"),
                   Column("> Ts", 5, "", lambda res, m: f"{int((res.step_time > Ts).sum()):5d}")]
