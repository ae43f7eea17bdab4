"""A sweep's output folder: an append-only journal of finished cells and the tidy result table.

Files in the folder:

* ``records.jsonl`` — one JSON record per finished cell, appended (and flushed) as each cell
  finishes, so Ctrl-C or a crash loses no finished cell. A rerun reads it and skips the cells
  whose key (the stable hash of the cell's parameters) it already holds. A line that is not a
  record (cut by a crash or a full disk, edited by hand, not UTF-8) is skipped and counted
  (:attr:`SweepStore.skipped_lines`); a last line cut mid-write is removed before the next
  append, so it never glues onto the next record.
* ``sweep.lock`` — held (``fcntl.flock``) by the sweep writing the folder, with its pid: a
  second sweep into the same folder is refused (:meth:`SweepStore.locked`).
* ``results.parquet`` and ``results.csv`` — the tidy table, one row per cell of the current
  spec: bookkeeping (key, index, status, error, wall time), the parameters, the metrics (SI).
* ``spec.json`` — the spec that produced the table. ``trajectories/KEY.npz`` — full time
  histories of the cells that asked for them.

:func:`load_results` is the one reader of a result table (folder, ``.parquet`` or ``.csv``).
"""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path

from ..errors import InvalidParameterError
from .spec import LEGACY_METRICS, METRIC_COLUMNS, RECORD_COLUMNS

#: Statuses of a finished cell (an interrupted cell is run again on resume; a diverged one is a
#: result, like an ok one, and is not retried).
FINISHED = ("ok", "diverged", "failed")


class SweepStore:
    """The output folder of one sweep (created if missing).

    Args:
        directory: folder path.

    Attributes:
        skipped_lines: lines of the journal the last :meth:`finished` skipped (not a record).
    """

    def __init__(self, directory):
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.journal = self.directory / "records.jsonl"
        self.skipped_lines = 0
        self._lock = None
        self._depth = 0
        self._repaired = False

    @contextlib.contextmanager
    def locked(self):
        """Hold the folder's exclusive lock (``sweep.lock``) for the block; re-entrant.

        Raises:
            InvalidParameterError: another process holds it (naming the folder and its pid).
        """
        import fcntl

        if self._depth == 0:
            fh = open(self.directory / "sweep.lock", "a+")
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                fh.seek(0)
                holder = fh.read().strip() or "unknown"
                fh.close()
                raise InvalidParameterError(
                    f"sweep folder {str(self.directory)!r} is in use by another sweep (pid {holder}); wait for it to "
                    "finish or give another --out") from None
            fh.seek(0)
            fh.truncate()
            fh.write(str(os.getpid()))
            fh.flush()
            self._lock = fh
        self._depth += 1
        try:
            yield self
        finally:
            self._depth -= 1
            if self._depth == 0:
                self._lock.close()  # closing the file releases the lock
                self._lock = None

    def finished(self, retry_failed: bool = False) -> dict[str, dict]:
        """Records of the finished cells by key (the last record of a key wins); with
        ``retry_failed`` only the cells that did not fail. Lines that are not a record are
        skipped and counted in :attr:`skipped_lines`."""
        wanted = tuple(s for s in FINISHED if s != "failed") if retry_failed else FINISHED
        out = {}
        self.skipped_lines = 0
        if not self.journal.exists():
            return out
        for line in self.journal.read_bytes().split(b"\n"):
            if not line.strip():
                continue
            record = _record(line)
            if record is None:
                self.skipped_lines += 1
            elif record["status"] in wanted:
                out[record["key"]] = record
        return out

    def _repair_tail(self) -> None:
        """Remove a last line cut mid-write (no newline at the end, not a whole record), or end a
        whole last record with its newline, so that the next append starts a line of its own."""
        if self._repaired or not self.journal.exists():
            self._repaired = True
            return
        with self.journal.open("rb+") as fh:
            size = fh.seek(0, os.SEEK_END)
            if size:
                fh.seek(max(0, size - 1))
                if fh.read(1) != b"\n":
                    data = self.journal.read_bytes()
                    start = data.rfind(b"\n") + 1
                    if _record(data[start:]) is None:
                        fh.truncate(start)
                    else:
                        fh.write(b"\n")
        self._repaired = True

    def append(self, record: dict) -> dict:
        """Journal one record (its trajectory, if any, goes to ``trajectories/KEY.npz``)."""
        record = dict(record)
        res = record.pop("trajectory", None)
        if res is not None:
            folder = self.directory / "trajectories"
            folder.mkdir(exist_ok=True)
            record["trajectory_file"] = str(res.save(folder / f"{record['key']}.npz").relative_to(self.directory))
        self._repair_tail()
        with self.journal.open("a", encoding="utf-8") as fh:
            fh.write(json.dumps(record, default=repr) + "\n")
            fh.flush()
        return record

    def save_spec(self, spec) -> Path:
        path = self.directory / "spec.json"
        path.write_text(json.dumps(spec.to_dict(), indent=1, default=repr))
        return path

    def write_tables(self, records) -> list[Path]:
        """Write ``results.parquet`` and ``results.csv`` from the records; returns the paths."""
        frame = records_frame(records)
        parquet, csv = self.directory / "results.parquet", self.directory / "results.csv"
        frame.to_parquet(parquet, index=False)
        frame.to_csv(csv, index=False)
        return [parquet, csv]


def _record(line: bytes) -> dict | None:
    """The record of one journal line, or None if it is not one (not UTF-8 JSON of an object
    with a string ``key`` and a known ``status``)."""
    try:
        record = json.loads(line.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError):
        return None
    if not isinstance(record, dict) or not isinstance(record.get("key"), str) \
            or record.get("status") not in (*FINISHED, "interrupted"):
        return None
    return {LEGACY_METRICS.get(k, k): v for k, v in record.items()}


def records_frame(records):
    """A pandas DataFrame of records: bookkeeping, parameters, metrics; sorted by cell index.

    A parameter column that mixes types (e.g. ``torque_limit`` = None and 60) keeps numbers as
    numbers where it can and becomes text otherwise, so it can be stored as Parquet.
    """
    import pandas as pd

    rows = [{k: v for k, v in r.items() if k != "trajectory"} for r in records]
    frame = pd.DataFrame(rows)
    if frame.empty:
        return pd.DataFrame(columns=[*RECORD_COLUMNS, *METRIC_COLUMNS])
    frame = frame.sort_values("index", kind="stable").reset_index(drop=True)
    head = [c for c in RECORD_COLUMNS if c in frame]
    tail = [c for c in METRIC_COLUMNS if c in frame]
    params = [c for c in frame.columns if c not in head and c not in tail]
    frame = frame[head + params + tail]
    for column in params:
        kinds = {type(v) for v in frame[column] if v is not None and v == v}
        if len(kinds) > 1 and not kinds <= {int, float, bool}:
            frame[column] = frame[column].map(lambda v: None if v is None else str(v))
    return frame


def load_results(path):
    """The result table of a sweep folder, ``results.parquet`` or ``results.csv`` as a DataFrame
    (columns of an older table renamed by :data:`~parallel_gpc.sweeps.spec.LEGACY_METRICS`).

    Raises:
        InvalidParameterError: the path is neither a sweep folder nor a .parquet/.csv table.
        OSError: the file cannot be read.
    """
    import pandas as pd

    path = Path(path)
    if path.is_dir():
        path = path / "results.parquet"
    if path.suffix in (".parquet", ".csv"):
        frame = pd.read_parquet(path) if path.suffix == ".parquet" else pd.read_csv(path)
        return frame.rename(columns=LEGACY_METRICS)
    raise InvalidParameterError(f"{path} is not a sweep folder, a .parquet or a .csv result table")
