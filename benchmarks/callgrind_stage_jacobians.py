"""Instruction count of the compiled stage Jacobians, for callgrind (repeatable under load, unlike wall clock).

Two calls of ``ReducedModel.stage_jacobians(..., start=1)`` (19 stages each) on a 20-stage trajectory
pre-simulated with ``simulate_factorized`` (so every stage has its base: the converged NMPC step's case).
The calls go through ``operator.methodcaller`` so that callgrind can count them alone
(``methodcaller_call`` has a symbol in libpython; the compiled module is stripped)::

    PYTHONPATH=src PARALLEL_GPC_THREADS=1 OPENBLAS_NUM_THREADS=1 valgrind --tool=callgrind \\
        --toggle-collect=methodcaller_call python benchmarks/callgrind_stage_jacobians.py planar_4rrr

"Collected" is the instructions of both calls (divide by 38 for one stage). Arguments: the robot (a bundled
name, default planar_4rrr).
"""

from __future__ import annotations

import operator
import sys

import numpy as np

from parallel_gpc import ParallelRobot, ReducedModel

TS = 0.002  # s
STAGES = 20


def main(name: str = "planar_4rrr") -> None:
    robot = ParallelRobot.load(name)
    model = ReducedModel(robot)
    rng = np.random.default_rng(7)
    pose = robot.home_pose + rng.uniform(-0.02, 0.02, model.n_y)  # m or rad
    X = np.concatenate([pose, rng.uniform(-0.3, 0.3, model.n_y)])  # m/s or rad/s
    u = np.tile(np.linspace(-1.0, 1.0, model.n_u), (STAGES, 1))  # N·m
    Xs = model.simulate_factorized(X, u, TS)[3]
    call = operator.methodcaller("stage_jacobians", Xs, u, TS, start=1)
    for _ in range(2):
        J = call(model)
    print(name, J.shape, "max |dPhi/dX| =", np.abs(J).max())


if __name__ == "__main__":
    main(*sys.argv[1:2])
