"""What the output coordinates y of a robot are: their names, units, and the unit of the drives.

Tables and figures label their columns and axes from an :class:`OutputSpace` instead of
assuming planar [x, y, ψ] outputs driven in N·m: ``robot.output_space`` for a robot, or the
``outputs`` of a closed-loop or planning result. This module depends on NumPy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InvalidParameterError

#: Display names of spelled-out angle labels (``psi`` → ψ); other labels are shown as written.
GREEK = {"psi": "ψ", "phi": "φ", "theta": "θ", "alpha": "α", "beta": "β", "gamma": "γ"}
#: Units of the drive efforts: revolute drives, prismatic drives, both kinds.
DRIVE_UNITS = ("N·m", "N", "N·m | N")


def effort_integral_unit(drive_unit: str) -> str:
    """Unit of the effort integral ∫‖u‖² dt ≈ Σ‖u‖²·Ts of drives in ``drive_unit``: N²·m²·s
    (revolute drives), N²·s (prismatic), ``(N·m | N)²·s`` for both kinds. Not an energy (J)."""
    return {"N·m": "N²·m²·s", "N": "N²·s"}.get(drive_unit, f"({drive_unit})²·s")


def drive_unit_of(drive_angular) -> str:
    """The common drive unit of drives of these kinds (True: revolute)."""
    kinds = set(drive_angular)
    return "N·m | N" if len(kinds) > 1 else "N·m" if True in kinds else "N"


@dataclass(frozen=True)
class OutputSpace:
    """Names and units of a robot's outputs y and of its drive efforts u.

    Attributes:
        labels: (n_y,) names of the output coordinates (the sidecar's ``[output] labels``).
        angular: (n_y,) True where the coordinate is an angle in rad, False for a length in m.
        drive_unit: unit of u: ``"N·m"`` (revolute drives), ``"N"`` (prismatic) or ``"N·m | N"``.
        drives: (n_u,) names of the drives (the drive joints), or empty when unknown (then the
            drives are shown as u1, u2, …).
        drive_angular: (n_u,) True for a revolute drive (effort in N·m), False for a prismatic
            one (N); may be empty when ``drive_unit`` is one kind (it then holds for every drive).
    """

    labels: tuple[str, ...]
    angular: tuple[bool, ...]
    drive_unit: str = "N·m"
    drives: tuple[str, ...] = ()
    drive_angular: tuple[bool, ...] = ()

    def __post_init__(self):
        labels = tuple(str(x) for x in self.labels)
        angular = tuple(bool(a) for a in np.asarray(self.angular, dtype=bool).ravel())
        if len(labels) != len(angular) or not labels:
            raise InvalidParameterError(f"output labels {list(labels)} and angular flags {list(angular)} must "
                                        "have one entry per output (at least one)")
        if len(set(labels)) != len(labels):
            raise InvalidParameterError(f"output labels {list(labels)} must be distinct")
        if self.drive_unit not in DRIVE_UNITS:
            raise InvalidParameterError(f"drive unit {self.drive_unit!r} is not one of {list(DRIVE_UNITS)}")
        drives = tuple(str(x) for x in self.drives)
        drive_angular = tuple(bool(a) for a in np.asarray(self.drive_angular, dtype=bool).ravel())
        if drive_angular and len(drive_angular) != len(drives):
            raise InvalidParameterError(f"drive names {list(drives)} and drive angular flags {list(drive_angular)} "
                                        "must have one entry per drive")
        if drives and not drive_angular and self.drive_unit not in ("N·m", "N"):
            raise InvalidParameterError(f"drives {list(drives)} in {self.drive_unit!r}: give drive_angular "
                                        "(one flag per drive) when the robot has both kinds")
        if drive_angular and self.drive_unit != drive_unit_of(drive_angular):
            raise InvalidParameterError(f"drive unit {self.drive_unit!r} does not match the drive kinds "
                                        f"{list(drive_angular)} (it would be {drive_unit_of(drive_angular)!r})")
        object.__setattr__(self, "labels", labels)
        object.__setattr__(self, "angular", angular)
        object.__setattr__(self, "drives", drives)
        object.__setattr__(self, "drive_angular", drive_angular)

    @classmethod
    def of(cls, robot) -> "OutputSpace":
        """The outputs of a :class:`~parallel_gpc.model.robot.ParallelRobot`."""
        return cls(tuple(robot.description.output_labels), tuple(robot.output_angular), robot.drive_unit,
                   tuple(robot.description.drive_joints), tuple(robot.drive_angular.tolist()))

    @classmethod
    def from_angular(cls, angular, n_y: int | None = None, drive_unit: str = "N·m") -> "OutputSpace":
        """Outputs known only by their angular flags (a result without labels): lengths named
        x, y, z (then y4, …), angles ψ when there is one, else φ, θ, ψ (then a4, …); ``angular``
        None is the planar convention [x m, y m, ψ rad, …] of ``n_y`` outputs."""
        if angular is None:
            angular = np.arange(3 if n_y is None else n_y) >= 2
        angular = np.asarray(angular, dtype=bool)
        lin = iter(("x", "y", "z"))
        ang = iter(("ψ",) if angular.sum() == 1 else ("φ", "θ", "ψ"))
        labels = [next(ang if a else lin, f"{'a' if a else 'y'}{i + 1}") for i, a in enumerate(angular)]
        return cls(tuple(labels), tuple(angular.tolist()), drive_unit)

    @property
    def n_y(self) -> int:
        return len(self.labels)

    @property
    def units(self) -> tuple[str, ...]:
        """(n_y,) ``"m"`` or ``"rad"`` per output."""
        return tuple("rad" if a else "m" for a in self.angular)

    @property
    def translational(self) -> list[int]:
        """Indices of the outputs in m (positions, prismatic joint coordinates), in order."""
        return [i for i, a in enumerate(self.angular) if not a]

    @property
    def rotational(self) -> list[int]:
        """Indices of the outputs in rad (rotation-vector components, revolute joint coordinates)."""
        return [i for i, a in enumerate(self.angular) if a]

    @property
    def has_angles(self) -> bool:
        return any(self.angular)

    def name(self, i: int) -> str:
        """Display name of output i (``psi`` shown as ψ)."""
        return GREEK.get(self.labels[i], self.labels[i])

    def axis_label(self, i: int, scale: str = "") -> str:
        """Axis label of output i with its unit, e.g. ``"x [m]"``; ``scale`` "m" gives mm/mrad."""
        return f"{self.name(i)} [{scale}{self.units[i]}]"

    @property
    def effort_unit(self) -> str:
        """Unit of the effort integral ∫‖u‖² dt (:func:`effort_integral_unit` of :attr:`drive_unit`)."""
        return effort_integral_unit(self.drive_unit)

    def drive_name(self, j: int) -> str:
        """Name of drive j (its joint), or ``u{j+1}`` when the drives are not named."""
        return self.drives[j] if j < len(self.drives) else f"u{j + 1}"

    def drive_effort_unit(self, j: int) -> str:
        """Unit of drive j's effort: ``"N·m"`` (revolute) or ``"N"`` (prismatic); the common
        :attr:`drive_unit` when the kinds are not known per drive."""
        if j < len(self.drive_angular):
            return "N·m" if self.drive_angular[j] else "N"
        return self.drive_unit

    def drive_label(self, j: int) -> str:
        """Legend label of drive j with its unit, e.g. ``"slider_1 [N]"``."""
        return f"{self.drive_name(j)} [{self.drive_effort_unit(j)}]"

    def describe(self) -> str:
        """The outputs with their units, e.g. ``"x [m], z [m]"``."""
        return ", ".join(f"{label} [{unit}]" for label, unit in zip(self.labels, self.units))
