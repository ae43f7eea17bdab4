"""Model layer: robot description, closed-chain robot, reduced dynamics (eq. (1)–(4)), plants.

The description names (sidecar parsing, no Pinocchio) import at once; the rest lazily (PEP 562),
so reading a robot file's description or a result file does not import Pinocchio.
"""

from .._lazy import lazy_exports
from .description import (DEFAULT_ROBOT, SIDECAR_KEYS, Closure, RobotDescription, embedded_robots,
                          load_description, urdf_dir)

_PUBLIC = {
    "read_text_bounded": "file_checks", "read_bounded": "file_checks", "drive_resolution": "forward", "export_mjcf": "mjcf_export",
    "compiled_part": "native", "native_module": "native", "native_status": "native", "forward_status": "native_update",
    "available_cores": "native_update",
    "saturation_limit": "plant", "output_joint_ids": "skeleton", "output_world_axes": "skeleton", "stick_figure": "skeleton",
    "cached_identity": "discretization",
    "TaskOutput": "outputs", "ClosureKinematics": "robot", "ParallelRobot": "robot",
    "ReducedModel": "dynamics", "ReducedTerms": "dynamics", "discretize_zoh": "discretization",
    "kinetic_energy": "dynamics", "rk4_step": "discretization", "ConstrainedPlant": "plant", "ReducedPlant": "plant",
    "OutputSpace": "output_space", "effort_integral_unit": "output_space",
}

__all__ = ["DEFAULT_ROBOT", "SIDECAR_KEYS", "Closure", "RobotDescription", "embedded_robots", "load_description",
           "urdf_dir", *_PUBLIC]

__getattr__, __dir__ = lazy_exports(__name__, globals(), _PUBLIC)
