"""The closed loop the step benchmarks time: a controller on the full plant along a reference, each
step timed by a given clock (imported by bench_riccati.py and bench_native.py, run from benchmarks/)."""

from __future__ import annotations

import numpy as np

from parallel_gpc.model.plant import ConstrainedPlant


def closed_loop_steps(robot, ref, ctl, N: int, samples: int, clock, Ts: float, on_step=None) -> tuple[list, np.ndarray]:
    """(step times (s, by ``clock``), applied inputs (samples, m)) of ``ctl`` (reset first) in closed loop
    on the full plant from the reference's initial state; ``on_step(k, ctl)`` after each step."""
    ctl.reset()
    plant = ConstrainedPlant(robot, ref.initial_state(), Ts=Ts)
    times, us = [], []
    for k in range(samples):
        w = ref.window(k * Ts, Ts, N)
        t0 = clock()
        info = ctl.step(plant.X, w)
        times.append(clock() - t0)
        us.append(info.u)
        if on_step is not None:
            on_step(k, ctl)
        plant.step(info.u)
    return times, np.array(us)
