"""The states of an unlimited closed loop, shared by the stage-wise tests' long-horizon cases."""

from __future__ import annotations

from parallel_gpc import GPCController, Horizons
from parallel_gpc.model.plant import ConstrainedPlant


def closed_loop_states(robot, model, ref, N: int, weights, Ts: float, samples: int = 12) -> list[tuple]:
    """(X, w) of ``samples`` steps of the unconstrained controller (absolute, qr) on the full plant
    along the reference ``ref``: the state (2 n_y,) and the window (N, n_y) each step saw."""
    loop = GPCController.build(model, Ts, Horizons(N), weights)
    plant = ConstrainedPlant(robot, ref.initial_state(), Ts=Ts)
    states = []
    for k in range(samples):
        w = ref.window(k * Ts, Ts, N)
        states.append((plant.X.copy(), w))
        plant.step(loop.step(plant.X, w).u)
    return states
