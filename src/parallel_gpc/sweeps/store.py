"""A sweep's output folder: an append-only journal of finished cells and the tidy result table.

Files in the folder:

* ``records.jsonl`` — one JSON record per finished cell, appended (and flushed) as each cell
  finishes, so Ctrl-C or a crash loses no finished cell. A rerun reads it and skips the cells
  whose key (the stable hash of the cell's parameters) it already holds.
* ``results.parquet`` and ``results.csv`` — the tidy table, one row per cell of the current
  spec: bookkeeping (key, index, status, error, wall time), the parameters, the metrics (SI).
* ``spec.json`` — the spec that produced the table. ``trajectories/KEY.npz`` — full time
  histories of the cells that asked for them.

:func:`load_results` is the one reader of a result table (folder, ``.parquet`` or ``.csv``).
"""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import InvalidParameterError
from .spec import METRIC_COLUMNS, RECORD_COLUMNS

#: Statuses of a finished cell (an interrupted cell is run again on resume).
FINISHED = ("ok", "failed")


class SweepStore:
    """The output folder of one sweep (created if missing).

    Args:
        directory: folder path.
    """

    def __init__(self, directory):
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.journal = self.directory / "records.jsonl"

    def finished(self, retry_failed: bool = False) -> dict[str, dict]:
        """Records of the finished cells by key (the last record of a key wins); with
        ``retry_failed`` only the cells that succeeded."""
        wanted = ("ok",) if retry_failed else FINISHED
        out = {}
        if self.journal.exists():
            for line in self.journal.read_text().splitlines():
                if not line.strip():
                    continue
                try:
                    record = json.loads(line)
                except json.JSONDecodeError:  # a line cut short by a crash: that cell runs again
                    continue
                if record.get("status") in wanted:
                    out[record["key"]] = record
        return out

    def append(self, record: dict) -> dict:
        """Journal one record (its trajectory, if any, goes to ``trajectories/KEY.npz``)."""
        record = dict(record)
        res = record.pop("trajectory", None)
        if res is not None:
            folder = self.directory / "trajectories"
            folder.mkdir(exist_ok=True)
            record["trajectory_file"] = str(res.save(folder / f"{record['key']}.npz").relative_to(self.directory))
        with self.journal.open("a") as fh:
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
    """The result table of a sweep folder, ``results.parquet`` or ``results.csv`` as a DataFrame.

    Raises:
        InvalidParameterError: the path is neither a sweep folder nor a .parquet/.csv table.
        OSError: the file cannot be read.
    """
    import pandas as pd

    path = Path(path)
    if path.is_dir():
        path = path / "results.parquet"
    if path.suffix == ".parquet":
        return pd.read_parquet(path)
    if path.suffix == ".csv":
        return pd.read_csv(path)
    raise InvalidParameterError(f"{path} is not a sweep folder, a .parquet or a .csv result table")
