"""parallel-gpc: Generalized Predictive Control of parallel robots (state-space GPC, Belda et al.).

The public API, one import away::

    from parallel_gpc import ParallelRobot, ReducedModel, GPCController, Horizons, Weights, simulate

Names are resolved lazily (PEP 562), so ``import parallel_gpc`` and the command line's
``--help`` do not import Pinocchio or matplotlib until a name that needs them is used.
Layers, left to right (a module imports only from layers to its left): ``model`` (robot,
reduced dynamics, plants) → ``solvers`` (least squares, QP back ends) → ``gpc`` (criterion,
predictions, controller, planning, references) → ``studies`` (simulation, tracking, the forms
compared) → ``sweeps`` (sweeps and the robustness study on Dask) → ``plots`` (figures) →
``bench`` (the benchmark harness) → ``viz`` (meshcat) → ``cli``. ``results`` (the one result file
format), ``limits`` (the one input-limits type, :class:`~parallel_gpc.limits.Limits`) and ``errors``
sit beside them and import only NumPy and the robot description.
"""

from __future__ import annotations

from ._lazy import lazy_exports
from .errors import ParallelGPCError

__version__ = "0.1.0"

#: public name -> submodule that defines it
_PUBLIC = {
    # model
    "ParallelRobot": "model", "RobotDescription": "model", "load_description": "model",
    "embedded_robots": "model", "DEFAULT_ROBOT": "model", "ReducedModel": "model",
    "discretize_zoh": "model", "rk4_step": "model", "ConstrainedPlant": "model", "ReducedPlant": "model",
    "OutputSpace": "model",
    # solvers
    "LeastSquaresProblem": "solvers", "SolveResult": "solvers", "make_solver": "solvers",
    "available_solvers": "solvers", "MinNormOf": "solvers",
    # gpc
    "Horizons": "gpc", "Weights": "gpc", "GPCController": "gpc", "FORMS": "gpc", "StepInfo": "gpc",
    "closed_loop_poles": "gpc", "spectral_radius": "gpc",
    "Prediction": "gpc", "build_problem": "gpc", "PlanSettings": "gpc", "PlanResult": "gpc",
    "plan_point_to_point": "gpc", "Reference": "gpc", "SCurve": "gpc", "Hold": "gpc",
    "SampledTrajectory": "gpc", "Helix": "gpc", "OutputPath": "gpc", "reference_for": "gpc",
    "check_reference": "gpc", "GPCSettings": "gpc", "ControllerState": "gpc", "DiscreteLinearModel": "gpc",
    "ControlModel": "gpc", "Criterion": "gpc", "stagewise_compiled": "gpc",
    "plan_modes": "gpc", "plan_table": "gpc",
    "path_for": "gpc",
    # estimation
    "Sensors": "estimation", "Measurement": "estimation", "StateEstimator": "estimation",
    # studies
    "run_loop": "studies", "simulate": "studies", "SimulationResult": "studies", "TrackingSettings": "studies",
    "run_tracking": "studies", "metrics_table": "studies",
    # sweeps
    "robustness_study": "sweeps", "load_spec": "sweeps", "run_sweep": "sweeps", "load_results": "sweeps",
    # plots
    "save_figure": "plots",
    # limits
    "Limits": "limits",
    # result files
    "save_result": "results", "load_result": "results", "ResultFile": "results",
}

__all__ = ["ParallelGPCError", "__version__", *_PUBLIC]


__getattr__, __dir__ = lazy_exports(__name__, globals(), _PUBLIC)
