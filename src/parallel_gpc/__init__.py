"""parallel-gpc: Generalized Predictive Control of parallel robots (state-space GPC, Belda et al.)."""

from .errors import ParallelGPCError
from .model.robot import ParallelRobot, load_description, embedded_robots, DEFAULT_ROBOT
from .model.dynamics import ReducedModel, discretize_zoh, rk4_step

__all__ = [
    "ParallelGPCError",
    "ParallelRobot",
    "load_description",
    "embedded_robots",
    "DEFAULT_ROBOT",
    "ReducedModel",
    "discretize_zoh",
    "rk4_step",
]
__version__ = "0.1.0"
