"""``parallel-gpc sweep SPEC.toml``: a grid / Monte-Carlo sweep of closed-loop runs on Dask.

A thin layer over :func:`parallel_gpc.sweeps.runner.run_sweep`: expands the spec, runs
the cells not yet in ``--out`` (a local cluster by default, ``--workers 0`` serial,
``--scheduler tcp://HOST:PORT`` an existing cluster), writes ``results.parquet``/``results.csv``
and the plots of the spec's ``[plots]`` table (validated before any cell runs), and prints a
summary. Cells whose closed loop diverged are results (status ``diverged``, metrics of the part
run), counted in the summary and marked in the plots. ``--out`` is locked while the sweep runs.
Ctrl-C keeps the finished cells (a rerun resumes) and exits with code 130.
"""

from __future__ import annotations

import sys
from collections import Counter
from pathlib import Path

from ..errors import InvalidParameterError
from .defaults import EXIT_INTERRUPTED
from .vocabulary import PACKAGE_PATH
HELP = "grid / Monte-Carlo sweep of closed-loop runs on Dask (resumable, Parquet + CSV)"
DESCRIPTION = ("Expand a TOML spec ([sweep], [base], [grid], [random], [plots]) into cells, run them as independent "
               "tasks on a local or remote Dask cluster, and write a tidy table. A rerun skips the cells already "
               "in --out.")


def cmd_sweep(args) -> int:
    from ..plots import check_plots, plot_sweep
    from ..sweeps import SweepStore, check_scheduler, load_spec, run_sweep

    if args.dry_run is not None and args.dry_run < 0:
        raise InvalidParameterError(f"--dry-run {args.dry_run}: the number of cells to print must be ≥ 0")
    check_scheduler(args.scheduler)
    spec = load_spec(args.spec)
    check_plots(spec.plots, spec.columns)
    print(f"sweep {spec.name!r}: {spec.count} cells over {list(spec.axes) or 'no axes'}", file=sys.stderr)
    cells = spec.cells()
    if args.trajectories:
        cells = [type(c)(c.index, c.params, True) for c in cells]
    if args.dry_run is not None:
        for cell in cells[: args.dry_run]:
            print(f"  {cell.index:>5} {cell.key} {cell.params}")
        return 0
    out = Path(args.out or Path("out/sweep") / spec.name)
    store = SweepStore(out)
    with store.locked():
        store.save_spec(spec)
        result = run_sweep(cells, workers=args.workers, scheduler=args.scheduler, store=store,
                           progress=not args.no_progress, retry_failed=args.retry_failed)
    if result.skipped_lines:
        print(f"parallel-gpc: {store.journal}: skipped {result.skipped_lines} lines that are not records (their "
              "cells ran again)", file=sys.stderr)
    frame = result.frame()
    ok = int((frame["status"] == "ok").sum()) if len(frame) else 0
    print(f"{result.finished} of {result.total} cells finished ({result.ran} run now, {result.skipped} reused): "
          f"{ok} ok, {result.diverged} diverged, {result.failed} failed")
    for status in ("diverged", "failed"):
        errors = [r["error"] for r in result.records if r["status"] == status]
        kinds = Counter(_kind(e) for e in errors)
        for kind, count in kinds.most_common():
            example = next(e for e in errors if _kind(e) == kind)
            print(f"  {status} x{count}: {kind}, e.g. {example[:200]}")
    paths = [out / "results.parquet", out / "results.csv"]
    if ok and spec.plots:
        paths += plot_sweep(frame, spec.plots, out)
    print("wrote " + ", ".join(str(p) for p in paths))
    if not result.interrupted:
        return 0
    print(f"parallel-gpc: interrupted; {result.finished} finished cells are saved, rerun to resume", file=sys.stderr)
    return EXIT_INTERRUPTED


def _kind(error: str) -> str:
    """The exception type of a record's error: ``"Name: …"`` (failed) or ``"… (cause: Name: …)"`` (diverged)."""
    cause = error.partition("(cause: ")[2]
    return (cause or error).split(":", 1)[0]


def register_sweep(sub) -> None:
    """Add the ``sweep`` sub-command."""
    p = sub.add_parser("sweep", parents=[PACKAGE_PATH], help=HELP, description=DESCRIPTION)
    p.add_argument("spec", help="sweep spec (TOML), e.g. examples/sweep_tuning.toml")
    p.add_argument("--out", default=None, help="output folder (default out/sweep/<spec name>)")
    p.add_argument("--workers", type=int, default=None,
                   help="processes running cells: this one and a local cluster of WORKERS - 1 "
                        "(default: the cores this process may use); 1 = one worker process; 0 = serial in this process")
    p.add_argument("--scheduler", default=None, help="address tcp://HOST:PORT of a running Dask scheduler")
    p.add_argument("--retry-failed", action="store_true", help="run the cells recorded as failed again")
    p.add_argument("--trajectories", action="store_true", help="also save each cell's time histories (.npz)")
    p.add_argument("--dry-run", type=int, nargs="?", const=10, default=None, metavar="K",
                   help="only expand the spec: print the cell count and the first K cells (default 10)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_sweep)
