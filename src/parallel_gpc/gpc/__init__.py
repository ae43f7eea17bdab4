"""GPC layer: criterion (5), predictions (6)–(13), receding-horizon controller, planning (20)–(21), references."""

from .prediction import Horizons, Prediction, absolute_prediction, condense, incremental_prediction, simulative_prediction
from .criterion import Criterion, Weights, build_problem
from .protocol import ControlModel
from .linear_model import DiscreteLinearModel
from ..limits import Limits
from .settings import ControllerState, GPCSettings
from .controller import FORMS, GPCController, StepInfo
from .references import Hold, Reference, SampledTrajectory, SCurve
from .planning import PlanResult, PlanSettings, deadbeat_inputs, plan_point_to_point

__all__ = [
    "Horizons", "Prediction", "absolute_prediction", "condense", "incremental_prediction", "simulative_prediction",
    "Criterion", "Weights", "build_problem", "ControlModel", "DiscreteLinearModel", "ControllerState", "GPCSettings", "Limits",
    "FORMS", "GPCController", "StepInfo", "Hold", "Reference", "SampledTrajectory", "SCurve", "PlanResult",
    "PlanSettings", "deadbeat_inputs", "plan_point_to_point",
]
