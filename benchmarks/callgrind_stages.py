"""Instruction counts of the compiled per-stage work, for callgrind (repeatable under load, unlike wall clock).

Two calls on a 20-stage trajectory pre-simulated just before with ``simulate_factorized`` (Ts = 2 ms), through
``operator.methodcaller`` so that callgrind can count them alone (``methodcaller_call`` has a symbol in libpython;
the compiled module is stripped)::

    PYTHONPATH=src PARALLEL_GPC_THREADS=1 OPENBLAS_NUM_THREADS=1 valgrind --tool=callgrind \\
        --toggle-collect=methodcaller_call python benchmarks/callgrind_stages.py planar_4rrr jacobians

* ``jacobians`` (default): ``ReducedModel.stage_jacobians(..., start=1)`` of that trajectory (19 stages, every
  one with its base: the converged NMPC step's case). "Collected" / 38 is one stage.
* ``rollout``: ``simulate_factorized`` with the inputs moved by 1e-4 and 2e-4 N·m (the line-search trials of a
  converged NMPC step, whose stages find their warm starts in the pre-simulation). "Collected" / 2 is one
  rollout, / 40 one stage.

Arguments: the robot (a bundled name, default planar_4rrr), then the mode. ``bench_rollout.py`` replays the
NMPC's own recorded trials instead.
"""

from __future__ import annotations

import operator
import sys

import numpy as np

from parallel_gpc import ParallelRobot, ReducedModel

TS = 0.002  # s
STAGES = 20
MODES = ("jacobians", "rollout")


def main(name: str = "planar_4rrr", mode: str = "jacobians") -> None:
    if mode not in MODES:
        raise SystemExit(f"mode {mode!r}: expected one of {', '.join(MODES)}")
    robot = ParallelRobot.load(name)
    model = ReducedModel(robot)
    rng = np.random.default_rng(7)
    pose = robot.home_pose + rng.uniform(-0.02, 0.02, model.n_y)  # m or rad
    X = np.concatenate([pose, rng.uniform(-0.3, 0.3, model.n_y)])  # m/s or rad/s
    u = np.tile(np.linspace(-1.0, 1.0, model.n_u), (STAGES, 1))  # N·m
    Xs = model.simulate_factorized(X, u, TS)[3]
    if mode == "jacobians":
        call = operator.methodcaller("stage_jacobians", Xs, u, TS, start=1)
        for _ in range(2):
            J = call(model)
        print(name, J.shape, "max |dPhi/dX| =", np.abs(J).max())
        return
    for k in range(2):
        Xs = operator.methodcaller("simulate_factorized", X, u + 1e-4 * (k + 1), TS)(model)[3]
    print(name, Xs.shape, "final state", np.round(Xs[-1], 6))


if __name__ == "__main__":
    main(*sys.argv[1:3])
