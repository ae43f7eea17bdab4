"""Model layer: robot description, closed-chain robot, reduced dynamics (eq. (1)–(4)), plants."""

from .description import (DEFAULT_ROBOT, SIDECAR_KEYS, Closure, RobotDescription, embedded_robots,
                          load_description, urdf_dir)
from .outputs import TaskOutput
from .robot import ClosureKinematics, ParallelRobot
from .dynamics import ReducedModel, ReducedTerms, discretize_zoh, kinetic_energy, rk4_step
from .plant import ConstrainedPlant, ReducedPlant

__all__ = [
    "DEFAULT_ROBOT", "SIDECAR_KEYS", "Closure", "RobotDescription", "embedded_robots", "load_description",
    "urdf_dir", "TaskOutput", "ClosureKinematics", "ParallelRobot", "ReducedModel", "ReducedTerms",
    "discretize_zoh", "kinetic_energy", "rk4_step", "ConstrainedPlant", "ReducedPlant",
]
