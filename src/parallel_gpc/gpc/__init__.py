"""GPC layer: criterion (5), predictions (6)–(13), receding-horizon controller, planning (20)–(21), references."""

from .prediction import (Horizons, Prediction, absolute_prediction, condense, deviation_gain, incremental_prediction,
                         simulative_prediction)
from .criterion import Criterion, Weights, build_problem
from .protocol import ControlModel
from .linear_model import DiscreteLinearModel
from ..limits import Limits
from .settings import PAPER_FORMS, TERMINALS, ControllerState, GPCSettings, stagewise_compiled, unit_interval
from .controller import FORMS, GPCController, StepInfo
from .references import Helix, Hold, OutputPath, Reference, SampledTrajectory, SCurve, path_for, pose_error_norms
from .robot_references import (REFERENCE_KINDS, check_reference, check_times, is_file_reference, reference_for,
                               workspace_radius)
from .planning import MODES, PlanComparison, PlanResult, PlanSettings, deadbeat_inputs, plan_modes, plan_point_to_point
from .plan_result import plan_table
from .plan_settings import INTERRUPTED
from .stability import closed_loop_poles, spectral_radius

__all__ = [
    "pose_error_norms", "check_times", "is_file_reference", "PAPER_FORMS", "TERMINALS", "unit_interval", "INTERRUPTED",
    "Horizons", "Prediction", "absolute_prediction", "condense", "deviation_gain", "incremental_prediction",
    "simulative_prediction",
    "Criterion", "Weights", "build_problem", "ControlModel", "DiscreteLinearModel", "ControllerState", "GPCSettings", "Limits",
    "stagewise_compiled",
    "FORMS", "GPCController", "StepInfo", "Helix", "Hold", "OutputPath", "Reference", "SampledTrajectory", "SCurve",
    "path_for", "REFERENCE_KINDS", "check_reference", "reference_for", "workspace_radius", "PlanResult",
    "PlanSettings", "deadbeat_inputs", "plan_point_to_point", "MODES", "PlanComparison", "plan_modes", "plan_table",
    "closed_loop_poles", "spectral_radius",
]
