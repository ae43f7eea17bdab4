"""Model layer: robot description, closed-chain robot, reduced dynamics (eq. (1)–(4)), plants."""

from .description import DEFAULT_ROBOT, Closure, RobotDescription, embedded_robots, load_description, urdf_dir
from .robot import ClosureKinematics, ParallelRobot
from .dynamics import ReducedModel, ReducedTerms, discretize_zoh, kinetic_energy, rk4_step
from .plant import ConstrainedPlant, ReducedPlant

__all__ = [
    "DEFAULT_ROBOT", "Closure", "RobotDescription", "embedded_robots", "load_description", "urdf_dir",
    "ClosureKinematics", "ParallelRobot", "ReducedModel", "ReducedTerms", "discretize_zoh", "kinetic_energy",
    "rk4_step", "ConstrainedPlant", "ReducedPlant",
]
