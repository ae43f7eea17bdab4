"""Instruction count of the compiled rollout, for callgrind (repeatable under load, unlike wall clock).

Two calls of ``ReducedModel.simulate_factorized`` (20 stages each, Ts = 2 ms) near a trajectory pre-simulated
just before (inputs moved by 1e-4 and 2e-4 N·m: the line-search trials of a converged NMPC step, whose stages
find their warm starts in the pre-simulation). The calls go through ``operator.methodcaller`` so that callgrind
can count them alone (``methodcaller_call`` has a symbol in libpython; the compiled module is stripped)::

    PYTHONPATH=src PARALLEL_GPC_THREADS=1 OPENBLAS_NUM_THREADS=1 valgrind --tool=callgrind \\
        --toggle-collect=methodcaller_call python benchmarks/callgrind_rollout.py planar_4rrr

"Collected" is the instructions of both calls (divide by 2 for one rollout, by 40 for one stage). Arguments: the
robot (a bundled name, default planar_4rrr). ``bench_rollout.py`` replays the NMPC's own recorded trials instead.
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
    model.simulate_factorized(X, u, TS)
    for k in range(2):
        Xs = operator.methodcaller("simulate_factorized", X, u + 1e-4 * (k + 1), TS)(model)[3]
    print(name, Xs.shape, "final state", np.round(Xs[-1], 6))


if __name__ == "__main__":
    main(*sys.argv[1:2])
