"""Robustness study: tracking error of each GPC form under model mismatch, noise and a load.

For every prediction form (absolute, incremental, incremental-nonlinear) the controller keeps
the nominal model while the plant (the full constrained model, :class:`ConstrainedPlant`)
changes one thing at a time:

* **mass** — every body's mass and inertia scaled by s (−30 … +30 %: s = 0.7 … 1.3);
* **noise** — Gaussian measurement noise of standard deviation σ on the platform pose
  (m and rad) and σ·√2/Ts on its velocity (the noise of a finite-difference velocity);
* **disturbance** — a constant force F (N) along x on the platform, unknown to the model.

Each case is one closed-loop run of :func:`~parallel_gpc.simulation.simulate` along the
paper's S-curve (or a hold of the home pose); the table reports RMS/max position error,
orientation error, the steady-state error (mean over the last 10 % of the run), peak drive effort (N·m or N),
saturated steps and solver fallbacks. A run whose closed loop diverges (the platform leaves the
workspace, meets a singular pose …) is kept as a row with status ``diverged (Cause at t = … s)``
and the metrics of the part run (left out of the figure); Ctrl-C stops the study and keeps the
rows so far.
"""

from __future__ import annotations

import csv
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path


from ..gpc import (
    FORMS,
    GPCController,
    Horizons,
    Hold,
    Reference,
    Weights,
    PAPER_FORMS,
    check_reference,
    check_times,
    reference_for,
)
from ..model import ReducedModel, DEFAULT_ROBOT, ParallelRobot
from .. import errors
from ..errors import InvalidParameterError, writing
from ..studies import DIVERGENCE_ERRORS
from ..results import json_default
from .spec import SETTLE_FRACTION, Cell
from .runner import check_scheduler, run_sweep
from ..validation import finite_vector, positive

#: Plant mass/inertia scales of the default study (−30 … +30 %).
DEFAULT_MASS_SCALES = (0.7, 0.85, 1.15, 1.3)
#: Measurement-noise standard deviations on the pose (m, rad) of the default study.
DEFAULT_NOISE_LEVELS = (1e-5, 1e-4)
#: Constant platform forces along x (N) of the default study.
DEFAULT_DISTURBANCES = (10.0, 20.0)
#: Square-root weights of the study, the same for every form: Qy = 1 /m, Qu = 1e-4 /(N·m).
#: (Qu = 0, the paper's tracking setting, is dead-beat and diverges under noise or a lighter plant.)
DEFAULT_WEIGHTS = Weights(1.0, 1e-4)
#: Errors that mean "this closed loop diverged", recorded as a row instead of ending the study.
_DIVERGED = DIVERGENCE_ERRORS
#: The time and the cause in the message of a diverged run (SimulationResult.stopped).
_STOPPED = re.compile(r"at t = (\S+) s.*\(cause: (\w+):")

COLUMNS = ("form", "study", "value", "unit", "rms_position_error_mm", "max_position_error_mm",
           "rms_orientation_error_mrad", "steady_state_error_mm", "peak_drive_effort", "saturated_steps",
           "fallbacks", "steps", "status")


@dataclass(frozen=True)
class RobustnessCase:
    """One plant variation.

    Attributes:
        study: ``"nominal"``, ``"mass"``, ``"noise"`` or ``"disturbance"``.
        mass_scale: plant mass/inertia scale (1 = the controller's model).
        noise: pose measurement noise standard deviation (m, rad).
        force: constant platform force along x (N).
    """

    study: str
    mass_scale: float = 1.0
    noise: float = 0.0
    force: float = 0.0

    @property
    def value(self) -> float:
        """The varied quantity: mass change in %, σ in m, or F in N."""
        return {"nominal": 0.0, "mass": round(100.0 * (self.mass_scale - 1.0), 6), "noise": self.noise,
                "disturbance": self.force}[self.study]

    @property
    def unit(self) -> str:
        return {"nominal": "", "mass": "%", "noise": "m", "disturbance": "N"}[self.study]


def robustness_cases(mass_scales=DEFAULT_MASS_SCALES, noise_levels=DEFAULT_NOISE_LEVELS,
                     disturbances=DEFAULT_DISTURBANCES) -> list[RobustnessCase]:
    """The nominal case, then one case per mass scale, noise level and disturbance force.

    Raises:
        InvalidParameterError: a mass scale ≤ 0, a negative noise level or a non-finite value.
    """
    cases = [RobustnessCase("nominal")]
    for s in finite_vector("mass_scales", list(mass_scales)):
        if s <= 0:
            raise InvalidParameterError(f"mass scale {s} must be > 0 (1.0 = nominal, 0.7 = −30 %)")
        if s != 1.0:
            cases.append(RobustnessCase("mass", mass_scale=float(s)))
    for n in finite_vector("noise_levels", list(noise_levels)):
        if n < 0:
            raise InvalidParameterError(f"noise level {n} m must be ≥ 0")
        if n > 0:
            cases.append(RobustnessCase("noise", noise=float(n)))
    for f in finite_vector("disturbances", list(disturbances)):
        if f != 0:
            cases.append(RobustnessCase("disturbance", force=float(f)))
    return cases


@dataclass
class RobustnessResult:
    """Rows of a robustness study (one per form and case) and its settings.

    Attributes:
        rows: dicts with the keys of :data:`COLUMNS` (errors in mm/mrad, torques in N·m).
        settings: robot, forms, Ts, N, duration, weights, reference.
        interrupted: True if Ctrl-C stopped the study (the last row may cover a partial run).
    """

    rows: list = field(default_factory=list)
    settings: dict = field(default_factory=dict)
    interrupted: bool = False

    def format_table(self) -> str:
        """The rows as an aligned text table (the orientation column only for a robot with
        angular outputs; efforts in the robot's drive unit)."""
        angles = any(self.settings.get("angular", [True]))
        unit = self.settings.get("drive_unit", "N·m")
        keys = ("rms_position_error_mm", "max_position_error_mm", "rms_orientation_error_mrad", "steady_state_error_mm")
        names = ("RMS pos [mm]", "max pos [mm]", "RMS ang [mrad]", "steady [mm]")
        shown = [i for i in range(4) if angles or i != 2]
        head = ("form", "study", "value", *(names[i] for i in shown), f"peak u [{unit}]", "sat", "fallb", "status")
        lines = []
        for r in self.rows:
            value = "" if r["study"] == "nominal" else f"{r['value']:g} {r['unit']}"
            lines.append((r["form"], r["study"], value, *(_fmt(r[keys[i]], 4) for i in shown),
                          _fmt(r["peak_drive_effort"], 1), str(r["saturated_steps"]), str(r["fallbacks"]), r["status"]))
        widths = [max(len(h), *(len(line[i]) for line in lines)) if lines else len(h) for i, h in enumerate(head)]
        out = ["  ".join(h.ljust(w) for h, w in zip(head, widths))]
        out.append("  ".join("-" * w for w in widths))
        out += ["  ".join(c.ljust(w) for c, w in zip(line, widths)) for line in lines]
        return "\n".join(out)

    def save_csv(self, path) -> Path:
        path = Path(path)
        with writing(path, "CSV file"), path.open("w", newline="") as fh:
            wr = csv.DictWriter(fh, fieldnames=COLUMNS)
            wr.writeheader()
            wr.writerows(self.rows)
        return path

    def save_json(self, path) -> Path:
        path = Path(path)
        text = json.dumps({"settings": self.settings, "interrupted": self.interrupted, "rows": self.rows},
                          indent=1, default=json_default)
        with writing(path, "JSON file"):
            path.write_text(text)
        return path


def _fmt(x, digits: int) -> str:
    return "—" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"



def _reference(reference, robot: ParallelRobot, duration: float, max_condition: float) -> Reference:
    """The study's reference: a hold of the home pose, or a built-in path over 80 % of the run
    (the rest is a hold: steady state), a reference file or a Reference object."""
    if isinstance(reference, str) and reference == "hold":
        return Hold(tuple(robot.home_pose))
    return reference_for(reference, robot, 0.8 * duration, max_condition)


def _status(record: dict) -> str:
    """Row status of a sweep record: ok, interrupted, diverged (Error at t = … s: the run's part
    up to there measured; Error: raised before the first sample) or failed (Error: message)."""
    if record["status"] == "diverged":
        match = _STOPPED.search(record["error"])
        return f"diverged ({match.group(2)} at t = {match.group(1)} s)" if match else "diverged"
    if record["status"] != "failed":
        return record["status"]
    name = record["error"].split(":", 1)[0]
    cls = getattr(errors, name, None)
    if isinstance(cls, type) and issubclass(cls, _DIVERGED):
        return f"diverged ({name})"
    return f"failed ({record['error']})"


def _row(form: str, case: RobustnessCase, record: dict) -> dict:
    """The table row of one run from its sweep record (SI metrics to mm, mrad)."""
    row = {"form": form, "study": case.study, "value": case.value, "unit": case.unit}
    row.update({f"{k}_{unit}": 1e3 * record[f"{k}_{si}"] for k, si, unit in (
        ("rms_position_error", "m", "mm"), ("max_position_error", "m", "mm"),
        ("rms_orientation_error", "rad", "mrad"), ("steady_state_error", "m", "mm"))})
    row["peak_drive_effort"] = record["peak_drive_effort"]
    ok = record["status"] != "failed"  # diverged: the counts of the part run
    row.update({k: int(record[k]) if ok else 0 for k in ("saturated_steps", "fallbacks", "steps")})
    row["status"] = _status(record)
    return row


def robustness_cells(robot_name: str, forms, cases, ref: Reference, duration: float, Ts: float, N: int,
                     weights: Weights, seed: int) -> list[Cell]:
    """The study as sweep cells, one per case and form (case-major): the nominal controller
    (no torque limit) on the plant of the case, saturated at the robot's own drive limits."""
    cells = []
    for case in cases:
        for form in forms:
            cells.append(Cell(len(cells), {
                "robot": robot_name, "form": form, "Ts": Ts, "N": N, "Qy": weights.Qy, "Qu": weights.Qu,
                "reference": ref, "duration": duration, "mass_scale": case.mass_scale, "noise_std": case.noise,
                "velocity_noise_std": case.noise * math.sqrt(2.0) / Ts, "platform_force[0]": case.force,
                "plant_torque_limit": "robot", "seed": seed, "check_reference": False}))
    return cells


def robustness_study(robot_name: str = DEFAULT_ROBOT, forms=PAPER_FORMS, mass_scales=DEFAULT_MASS_SCALES,
                     noise_levels=DEFAULT_NOISE_LEVELS, disturbances=DEFAULT_DISTURBANCES,
                     duration: float = 2.5, Ts: float = 0.005, N: int = 10, progress: bool = False,
                     weights: Weights = DEFAULT_WEIGHTS, reference="auto", seed: int = 0,
                     on_row=None, workers: int = 0, scheduler=None) -> RobustnessResult:
    """Tracking error of each form under plant mismatch, measurement noise and a constant load.

    Args:
        robot_name: embedded robot name or path to a robot file.
        forms: prediction forms to compare (subset of ``FORMS``).
        mass_scales: plant mass/inertia scales (1 = nominal; 0.7 … 1.3 = −30 … +30 %).
        noise_levels: pose measurement-noise standard deviations σ (m, rad); velocity noise
            σ·√2/Ts (m/s, rad/s).
        disturbances: constant platform forces along x (N).
        duration: length of each run in s. Ts: sample time in s. N: prediction horizon
            (No = 0, Nu = N).
        progress: show a progress bar over the runs.
        weights: square-root weights Qy, Qu, the same for every form.
        reference: ``"auto"`` (the robot's default path: the paper's S-curve for planar
            outputs, the helix for spatial ones, an S-curve in the plane of two translational
            outputs, over 80 % of the run, then a hold), ``"s-curve"``,
            ``"circle"``, ``"line"``, ``"helix"``, ``"hold"`` (the home pose), a reference file
            (``.csv``: a column t and one per output label, SI units; ``.npz``) or a
            :class:`~parallel_gpc.references.Reference`. Checked once at its sample poses
            before the runs (:func:`~parallel_gpc.gpc.robot_references.check_reference`).
        seed: seed of the measurement noise (the same noise sequence for every form).
        on_row: optional callback receiving each row as soon as its run finishes.
        workers, scheduler: where the runs go (a preset of :func:`~parallel_gpc.sweeps.runner.run_sweep`):
            0 = serially in this process (default), n = a local Dask cluster of n processes,
            scheduler = an existing Dask cluster.

    Returns:
        :class:`RobustnessResult`; ``interrupted`` is True if Ctrl-C stopped it early.

    Raises:
        InvalidParameterError: an unknown form, a bad Ts, N, duration, scale or noise level.
        RobotFormatError: the robot cannot be loaded.
    """
    check_scheduler(scheduler)
    forms = tuple(forms)
    bad = [f for f in forms if f not in FORMS]
    if bad or not forms:
        raise InvalidParameterError(f"forms {list(forms)} must be a non-empty subset of {list(FORMS)}")
    Ts = positive("Ts", Ts, " s")
    duration = positive("duration", duration, " s")
    if duration < 2 * Ts:
        raise InvalidParameterError(f"duration = {duration} s must cover at least two samples of Ts = {Ts} s")
    horizons = Horizons(N)
    cases = robustness_cases(mass_scales, noise_levels, disturbances)
    robot = ParallelRobot.load(robot_name)
    ctrls = [GPCController.build(ReducedModel(robot), Ts, horizons, weights, form=form) for form in forms]  # validated once
    max_condition = min(c.max_condition for c in ctrls)
    ref = _reference(reference, robot, duration, max_condition)
    check_reference(robot, ref, check_times(ref, duration, Ts), max_condition)  # once, not in every cell
    result = RobustnessResult(settings={
        "robot": robot.name, "outputs": list(robot.description.output_labels),
        "angular": robot.output_angular.tolist(), "drive_unit": robot.drive_unit, "forms": list(forms), "Ts": Ts, "N": N, "duration": duration,
        "Qy": weights.Qy, "Qu": weights.Qu, "reference": reference if isinstance(reference, str) else repr(reference),
        "plant": "ConstrainedPlant, drive saturation at the robot's torque limits",
        "noise": "pose σ (m, rad); velocity σ·√2/Ts", "disturbance": "constant force along x (N)",
        "steady_state": f"mean position error over the last {SETTLE_FRACTION:.0%} of the run",
    })
    runs = [(form, case) for case in cases for form in forms]
    rows = {}

    def collect(record: dict) -> None:
        rows[record["index"]] = row = _row(*runs[record["index"]], record)
        if on_row is not None:
            on_row(row)

    cells = robustness_cells(robot_name, forms, cases, ref, duration, Ts, N, weights, seed)
    sweep = run_sweep(cells, workers=workers, scheduler=scheduler, progress=progress, on_record=collect)
    result.rows = [rows[i] for i in sorted(rows)]  # cluster runs finish out of order
    result.interrupted = sweep.interrupted
    return result
