"""Parameter sweeps: a spec (grid and/or seeded random samples) expanded into independent cells.

A *cell* is one closed-loop tracking run (:func:`~parallel_gpc.studies.tracking.run_tracking`, one
GPC form) with its settings given as a flat ``{name: value}`` dict. Names are the fields of
:class:`~parallel_gpc.studies.tracking.TrackingSettings` (``robot``, ``Ts``, ``N``, ``Nu``, ``Qy``,
``Qu``, ``solver``, ``torque_limit``, ``mass_scale``, ``noise_std``, ``reference``, ``duration``,
``seed`` …), plus ``form`` (default ``"nonlinear"``), ``velocity_noise_std`` (m/s, rad/s; then ``noise_std`` is the pose
noise only) and one element of a vector field as ``"platform_force[0]"``.

A spec has four tables (TOML or a dict)::

    [sweep]   name (a folder name), samples (random draws per grid point), seed (of the draws, ≥ 0),
              trajectories (true/false)
    [base]    settings shared by every cell
    [grid]    name = [values]: every combination (the last axis varies fastest)
    [random]  name = {uniform = [lo, hi]} | {loguniform = [lo, hi]} | {normal = [mean, std]}
              | {integers = [lo, hi]} (hi excluded) | {choice = [values]}

:func:`run_cell` is the unit of work: a pure function of the cell returning a flat metrics record
(SI units); a cell whose closed loop diverged records the metrics of the part run (status
``"diverged"``), a cell whose run raises records the error instead. Cells are keyed by a stable
hash of their parameters, so a rerun of the same spec finds the cells it already has.

Limits: a spec file is a regular UTF-8 file of at most :data:`SPEC_MAX_BYTES`, its values nest at
most :data:`MAX_DEPTH` deep, and a sweep has at most :data:`MAX_CELLS` cells (counted before
they are expanded).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import re
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InvalidParameterError
from ..gpc import pose_error_norms
from ..model import read_text_bounded
from ..studies import FLAT_KEYS, TrackingSettings

#: Fraction of the run at its end over which the steady-state error is averaged.
SETTLE_FRACTION = 0.1
#: Metric columns of a record (SI units; ``peak_drive_effort`` and the internal-force columns in the
#: drives' unit, N·m revolute or N prismatic, ``effort_integral`` ∫‖u‖² dt in its square times s);
#: NaN for a cell that failed.
METRIC_COLUMNS = ("rms_position_error_m", "max_position_error_m", "rms_orientation_error_rad",
                  "max_orientation_error_rad", "steady_state_error_m", "peak_drive_effort", "drive_energy_J",
                  "effort_integral", "mean_internal_force", "max_internal_force", "mean_step_time_s",
                  "p99_step_time_s", "fallbacks", "replaced_steps", "saturated_steps", "steps")
#: Metric columns named before their unit was the drives' own (sweep journals and tables written
#: then are read with the new names): old name -> current name.
LEGACY_METRICS = {"peak_torque_Nm": "peak_drive_effort", "effort_N2m2s": "effort_integral",
                  "mean_internal_force_Nm": "mean_internal_force", "max_internal_force_Nm": "max_internal_force"}
#: Columns that depend on the machine's speed, not on the cell (left out of equality checks).
TIMING_COLUMNS = ("mean_step_time_s", "p99_step_time_s", "wall_time_s")
#: Bookkeeping columns of a record, before its parameters.
RECORD_COLUMNS = ("key", "index", "status", "error", "wall_time_s")
#: Parameters a cell may set besides the TrackingSettings fields.
EXTRA_PARAMS = ("form", "velocity_noise_std")
#: Random distributions of the [random] table and their argument counts.
DISTRIBUTIONS = {"uniform": 2, "loguniform": 2, "normal": 2, "integers": 2, "choice": None}
_SETTINGS_FIELDS = FLAT_KEYS
_INDEXED = re.compile(r"^([A-Za-z_]\w*)\[(\d+)\]$")
_KEY_VERSION = 1
#: Largest spec file read, bytes (size checked before reading, the read bounded).
SPEC_MAX_BYTES = 1 << 20
#: Most cells of one sweep (grid points × random samples), checked before expanding.
MAX_CELLS = 100_000
#: Deepest nesting of tables and lists in a spec.
MAX_DEPTH = 32
#: A sweep name is one folder name: 1 … 100 characters, no ``/``, ``\\`` or control character,
#: not ``.`` or ``..``.
_NAME = re.compile(r"^(?!\.{1,2}$)[^/\\\x00-\x1f\x7f]{1,100}$")
#: Largest magnitude of an ``integers`` bound (NumPy's int64 draws).
_INT_BOUND = 2**63 - 1


def parameter_names() -> tuple[str, ...]:
    """The names a spec may set (an element of a vector field is written ``name[i]``)."""
    return _SETTINGS_FIELDS + EXTRA_PARAMS


def _check_name(name: str, where: str) -> None:
    if not isinstance(name, str):
        raise InvalidParameterError(f"[{where}] names {name!r}, which is not a parameter name (a string)")
    match = _INDEXED.match(name)
    base = match.group(1) if match else name
    if base not in parameter_names():
        raise InvalidParameterError(f"[{where}] names {name!r}, which is not a sweep parameter; valid: "
                                    f"{list(parameter_names())} (a vector element as e.g. 'platform_force[0]')")


def _canonical(value):
    """Plain JSON-able Python values (numpy scalars and tuples converted)."""
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_canonical(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


@dataclass(frozen=True)
class Cell:
    """One run of a sweep.

    Attributes:
        index: position in the expanded sweep (0-based).
        params: ``{name: value}`` settings of the run (see the module docstring).
        trajectory: also return the full time histories (``record["trajectory"]``).
    """

    index: int
    params: dict
    trajectory: bool = False

    @property
    def key(self) -> str:
        """Stable 16-hex-digit hash of the parameters (independent of index and order)."""
        text = json.dumps({"v": _KEY_VERSION, "params": _canonical(self.params)}, sort_keys=True, default=repr)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class SweepSpec:
    """A validated sweep description (see the module docstring for the tables).

    Attributes:
        name: label of the sweep (output folder name).
        base: settings shared by every cell.
        grid: axis name -> list of values (full product).
        random: name -> {distribution: arguments}, drawn ``samples`` times per grid point.
        samples: number of random draws (0 = grid only; ≥ 1 needed when ``random`` is set).
        seed: seed of the random draws.
        trajectories: return the full time histories of every cell.
        plots: plot requests of the CLI (``heatmap``, ``pareto``, ``bands`` tables).
    """

    name: str = "sweep"
    base: dict = field(default_factory=dict)
    grid: dict = field(default_factory=dict)
    random: dict = field(default_factory=dict)
    samples: int = 0
    seed: int = 0
    trajectories: bool = False
    plots: dict = field(default_factory=dict)

    def __post_init__(self):
        _check_depth(self.to_dict(), "the spec", 0)
        if not isinstance(self.name, str) or not _NAME.match(self.name):
            raise InvalidParameterError(f"[sweep] name = {self.name!r} must be one folder name (a string of 1 to 100 "
                                        "characters without '/', '\\' or control characters, not '.' or '..'): "
                                        "it names the output folder out/sweep/<name>")
        if not _is_int(self.seed) or self.seed < 0:
            raise InvalidParameterError(f"[sweep] seed = {self.seed!r} must be an integer ≥ 0")
        if not isinstance(self.trajectories, bool):
            raise InvalidParameterError(f"[sweep] trajectories = {self.trajectories!r} must be true or false")
        if not isinstance(self.plots, dict):
            raise InvalidParameterError(f"[plots] must be a table of plot kinds, got {self.plots!r}")
        for where, table in (("base", self.base), ("grid", self.grid), ("random", self.random)):
            if not isinstance(table, dict):
                raise InvalidParameterError(f"[{where}] must be a table of name = value, got {table!r}")
            for name in table:
                _check_name(name, where)
        for a, b in itertools.combinations(("base", "grid", "random"), 2):
            both = set(getattr(self, a)) & set(getattr(self, b))
            if both:
                raise InvalidParameterError(f"{sorted(both)} set in both [{a}] and [{b}]; give each parameter once")
        for name, values in self.grid.items():
            if not isinstance(values, list) or not values:
                raise InvalidParameterError(f"[grid] {name} = {values!r} must be a non-empty list of values")
        for name, dist in self.random.items():
            _check_distribution(name, dist)
        if not _is_int(self.samples) or self.samples < 0:
            raise InvalidParameterError(f"[sweep] samples = {self.samples!r} must be an integer ≥ 0")
        if self.random and self.samples == 0:
            raise InvalidParameterError("[random] is set but [sweep] samples = 0; give samples ≥ 1")
        if self.count > MAX_CELLS:
            sizes = " × ".join([*(str(len(v)) for v in self.grid.values()), *([str(self.samples)] if self.samples else [])])
            raise InvalidParameterError(f"the sweep has {self.count} cells ({sizes}); the limit is {MAX_CELLS}: "
                                        "fewer grid values or samples, or split it into several sweeps")

    @property
    def count(self) -> int:
        """Number of cells (grid points × max(samples, 1)), without expanding them."""
        return math.prod(len(v) for v in self.grid.values()) * max(self.samples, 1)

    @property
    def columns(self) -> tuple[str, ...]:
        """The columns of the sweep's result table: bookkeeping, parameters, metrics."""
        return (*RECORD_COLUMNS, *dict.fromkeys([*self.base, *self.axes]), *METRIC_COLUMNS)

    @property
    def axes(self) -> tuple[str, ...]:
        """The varied parameters: grid axes, then random ones."""
        return tuple(self.grid) + tuple(self.random)

    def cells(self) -> list[Cell]:
        """Every cell: the grid product, and for each grid point ``samples`` random draws."""
        rng = np.random.default_rng(self.seed)
        draws = [{name: _draw(rng, dist) for name, dist in self.random.items()} for _ in range(self.samples)]
        points = [dict(zip(self.grid, values)) for values in itertools.product(*self.grid.values())]
        combos = [{**p, **d} for p in points for d in (draws or [{}])]
        return [Cell(i, {**self.base, **c}, self.trajectories) for i, c in enumerate(combos)]

    def to_dict(self) -> dict:
        """The spec as nested tables (the inverse of :func:`load_spec` on a dict)."""
        return {"sweep": {"name": self.name, "samples": self.samples, "seed": self.seed,
                          "trajectories": self.trajectories},
                "base": self.base, "grid": self.grid, "random": self.random, "plots": self.plots}


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_real(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _check_depth(value, where: str, depth: int) -> None:
    """Refuse tables and lists nested deeper than :data:`MAX_DEPTH` (before any recursion over them)."""
    if depth > MAX_DEPTH:
        raise InvalidParameterError(f"{where} nests tables or lists more than {MAX_DEPTH} deep")
    if isinstance(value, dict):
        for v in value.values():
            _check_depth(v, where, depth + 1)
    elif isinstance(value, (list, tuple)):
        for v in value:
            _check_depth(v, where, depth + 1)


def _check_distribution(name: str, dist) -> None:
    if not isinstance(dist, dict) or len(dist) != 1 or next(iter(dist)) not in DISTRIBUTIONS:
        raise InvalidParameterError(f"[random] {name} = {dist!r} must be one of "
                                    f"{{{' | '.join(DISTRIBUTIONS)} = [arguments]}}")
    kind, args = next(iter(dist.items()))
    count = DISTRIBUTIONS[kind]
    if not isinstance(args, list) or not args or (count is not None and len(args) != count):
        raise InvalidParameterError(f"[random] {name}: {kind} takes a list of {count or '≥ 1'} values, got {args!r}")
    if kind == "integers" and not all(_is_int(a) and abs(a) <= _INT_BOUND for a in args):
        raise InvalidParameterError(f"[random] {name}: integers takes two integers [lo, hi] (hi excluded, "
                                    f"|bound| ≤ 2**63 − 1), got {args!r}")
    if kind in ("uniform", "loguniform", "normal") and not all(_is_real(a) for a in args):
        raise InvalidParameterError(f"[random] {name}: {kind} takes two finite numbers, got {args!r}")
    if kind in ("uniform", "loguniform", "integers") and not args[0] < args[1]:
        raise InvalidParameterError(f"[random] {name}: {kind} needs lo < hi, got {args}")
    if kind == "loguniform" and args[0] <= 0:
        raise InvalidParameterError(f"[random] {name}: loguniform needs lo > 0, got {args}")
    if kind == "normal" and args[1] < 0:
        raise InvalidParameterError(f"[random] {name}: normal needs std ≥ 0, got {args}")


def _draw(rng: np.random.Generator, dist: dict):
    kind, args = next(iter(dist.items()))
    if kind == "uniform":
        return float(rng.uniform(args[0], args[1]))
    if kind == "loguniform":
        return float(math.exp(rng.uniform(math.log(args[0]), math.log(args[1]))))
    if kind == "normal":
        return float(rng.normal(args[0], args[1]))
    if kind == "integers":
        return int(rng.integers(args[0], args[1]))
    return _canonical(args[int(rng.integers(len(args)))])


def load_spec(source) -> SweepSpec:
    """A :class:`SweepSpec` from a TOML file path or a dict of tables.

    Raises:
        InvalidParameterError: the file is not a regular UTF-8 file of at most
            :data:`SPEC_MAX_BYTES` (a device, a FIFO, a folder …), not TOML, nested deeper than
            :data:`MAX_DEPTH`; unknown tables or keys, an unknown parameter, an empty grid axis,
            a malformed distribution, a parameter set twice, a bad name, seed or samples, more
            than :data:`MAX_CELLS` cells.
    """
    if isinstance(source, (str, Path)):
        path = Path(source)
        try:
            tables = tomllib.loads(read_text_bounded(path, SPEC_MAX_BYTES, "sweep spec", InvalidParameterError))
        except tomllib.TOMLDecodeError as exc:
            raise InvalidParameterError(f"{path}: not valid TOML: {exc}") from None
        except RecursionError:
            raise InvalidParameterError(f"{path}: nests tables or lists too deeply (the limit is {MAX_DEPTH})") from None
        if not isinstance(tables.get("sweep", {}), dict):
            raise InvalidParameterError(f"{path}: [sweep] must be a table, got {tables['sweep']!r}")
        tables.setdefault("sweep", {}).setdefault("name", path.stem)
    elif isinstance(source, dict):
        tables = source
    else:
        raise InvalidParameterError(f"a sweep spec is a TOML path or a dict, got {type(source).__name__}")
    unknown = set(tables) - {"sweep", "base", "grid", "random", "plots"}
    if unknown:
        raise InvalidParameterError(f"unknown spec tables {sorted(unknown)}; valid: sweep, base, grid, random, plots")
    _check_depth(tables, "the spec", 0)
    for table in ("sweep", "base", "grid", "random", "plots"):
        if not isinstance(tables.get(table, {}), dict):
            raise InvalidParameterError(f"[{table}] must be a table, got {tables[table]!r}")
    head = dict(tables.get("sweep", {}))
    bad = set(head) - {"name", "samples", "seed", "trajectories"}
    if bad:
        raise InvalidParameterError(f"unknown [sweep] keys {sorted(bad)}; valid: name, samples, seed, trajectories")
    return SweepSpec(base=dict(tables.get("base", {})), grid=dict(tables.get("grid", {})),
                     random=dict(tables.get("random", {})), plots=dict(tables.get("plots", {})), **head)


def cell_settings(params: dict, n_y: int = 3) -> tuple[TrackingSettings, str]:
    """(TrackingSettings, form) of a cell's parameters; ``n_y`` = the robot's platform coordinates.

    Raises:
        InvalidParameterError: an index outside a vector field, or a vector set whole and by element.
    """
    params = dict(params)
    form = params.pop("form", "nonlinear")
    velocity_noise = params.pop("velocity_noise_std", None)
    kwargs = {}
    defaults = TrackingSettings().flat()
    for name, value in params.items():
        match = _INDEXED.match(name)
        if match is None:
            kwargs[name] = tuple(value) if isinstance(value, list) else value
            continue
        base, i = match.group(1), int(match.group(2))
        if base in params:
            raise InvalidParameterError(f"{base!r} is set whole and as {name!r}; give one of them")
        current = kwargs.get(base, (0.0,) * n_y if base == "platform_force" else defaults[base])
        if not isinstance(current, tuple):
            raise InvalidParameterError(f"{name!r}: {base} is not a vector setting (it is {current!r})")
        vector = list(current)
        if i >= len(vector):
            raise InvalidParameterError(f"{name!r}: {base} has {len(vector)} elements (indices 0…{len(vector) - 1})")
        vector[i] = value
        kwargs[base] = tuple(vector)
    if velocity_noise is not None:
        pose_noise = kwargs.get("noise_std", 0.0)
        if pose_noise or velocity_noise:
            kwargs["noise_std"] = (float(pose_noise),) * n_y + (float(velocity_noise),) * n_y
    return TrackingSettings.from_flat(**kwargs), form


def drive_q_indices(robot) -> np.ndarray:
    """(n_u,) indices of the drive joints in the configuration q (one-DOF joints)."""
    model = robot.model
    return np.array([model.joints[model.getJointId(name)].idx_q for name in robot.description.drive_joints])


def drive_work(res, drive_q) -> np.ndarray:
    """(K−1, n_u) mechanical work of each drive over each recorded sample interval (J):
    u_k,i (θ_k+1,i − θ_k,i) — exact, since the drive force u_k is constant over the interval.

    Args:
        res: a SimulationResult (``q`` (K, nq), ``u`` (K, n_u) in N·m or N).
        drive_q: (n_u,) drive indices in q (:func:`drive_q_indices`), joint angles in rad or m.
    """
    theta = res.q[:, drive_q]
    return res.u[:-1] * np.diff(theta, axis=0)


def result_metrics(res, drive_q, Ts: float) -> dict:
    """The :data:`METRIC_COLUMNS` of one :class:`~parallel_gpc.studies.simulation.SimulationResult`."""
    m = res.metrics()
    tail = max(1, int(round(SETTLE_FRACTION * len(res.t))))
    m["steady_state_error_m"] = float(np.mean(pose_error_norms(res.error[-tail:], res.angular)[0]))
    m["drive_energy_J"] = float(np.sum(np.abs(drive_work(res, drive_q))))  # no regeneration
    m["effort_integral"] = float(Ts * np.sum(res.u**2))
    return {k: m[k] for k in METRIC_COLUMNS}


def resolve_robot(robot: str) -> str:
    """The robot (or reference file) to load: an embedded name or an existing path as is; a
    relative path that is not here but was shipped to this Dask worker
    (``client.upload_file(path, load=False)``: the URDF and its sidecar, a CSV reference) is the
    worker's copy."""
    from ..model import embedded_robots

    if robot in embedded_robots() or Path(robot).exists():
        return robot
    try:
        from distributed import get_worker

        shipped = Path(get_worker().local_directory) / Path(robot).name
    except (ImportError, ValueError):  # not in a Dask worker
        return robot
    return str(shipped) if shipped.exists() else robot


def failed_record(cell: Cell, error: str) -> dict:
    """The record of a cell that failed with ``error`` (metrics NaN); also the blank record of a run."""
    record = {"key": cell.key, "index": cell.index, "status": "failed", "error": error, "wall_time_s": 0.0}
    record.update({name: _table_value(value) for name, value in cell.params.items()})
    record.update({k: math.nan for k in METRIC_COLUMNS})
    return record


def run_cell(cell: Cell) -> dict:
    """Run one cell; a flat record: bookkeeping, parameters, :data:`METRIC_COLUMNS`.

    ``status`` is ``"ok"``, ``"diverged"`` (the closed loop diverged: metrics of the part run,
    ``error`` holds :attr:`~parallel_gpc.studies.simulation.SimulationResult.stopped`),
    ``"interrupted"`` (Ctrl-C inside the run; metrics of the part run) or ``"failed"`` (``error``
    holds ``"ExceptionType: message"``, metrics are NaN). With ``cell.trajectory`` the record also
    holds ``"trajectory"``: the SimulationResult.
    """
    from ..gpc import is_file_reference
    from ..model import ParallelRobot
    from ..studies import run_tracking

    record = failed_record(cell, "")
    start = time.perf_counter()
    try:
        params = {**cell.params, "robot": resolve_robot(cell.params.get("robot", TrackingSettings.robot))}
        if is_file_reference(params.get("reference")):  # a CSV/npz reference shipped like a robot file
            params["reference"] = resolve_robot(params["reference"])
        robot = ParallelRobot.load(params["robot"])
        settings, form = cell_settings(params, robot.n_y)
        res = run_tracking(settings, forms=(form,), progress=False, robot=robot)[form]
        record.update(result_metrics(res, drive_q_indices(robot), settings.Ts))
        record["status"] = res.outcome
        if res.diverged:
            record["error"] = res.stopped
        if cell.trajectory:
            record["trajectory"] = res
    except Exception as exc:  # noqa: BLE001 - any failure of a cell is recorded, the sweep goes on
        record["error"] = f"{type(exc).__name__}: {' '.join(str(exc).split())}"
    record["wall_time_s"] = time.perf_counter() - start
    return record


def _table_value(value):
    """A parameter value as a table entry: scalars as is, vectors and objects as JSON/repr text."""
    value = _canonical(value)
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return json.dumps(value, default=repr)
