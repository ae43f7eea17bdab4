"""The closed loop the step benchmarks time: a controller on the full plant along a reference, each
step timed by a given clock (imported by bench_riccati.py and bench_native.py, run from benchmarks/)."""

from __future__ import annotations

import numpy as np

from parallel_gpc.model.plant import ConstrainedPlant


def closed_loop_steps(robot, ref, ctl, N: int, samples: int, clock, Ts: float, on_step=None) -> tuple[list, np.ndarray]:
    """(step times (s, by ``clock``), applied inputs (samples, m)) of ``ctl`` (reset first) in closed loop
    on the full plant from the reference's initial state; ``on_step(k, ctl)`` after each step."""
    return interleaved_loops(robot, ref, {"": ctl}, N, samples, clock, Ts,
                             None if on_step is None else lambda key, k, c: on_step(k, c))[""]


def interleaved_loops(robot, ref, ctls: dict, N: int, samples: int, clock, Ts: float, on_step=None) -> dict:
    """{key: (step times, applied inputs)} of each controller of ``ctls`` in its own closed loop (reset
    first, its own plant), the loops advanced together one sample at a time: a burst of machine noise
    lands on every configuration alike instead of on one configuration's whole run (the ratios of their
    medians are then measured on the same stretch of time); ``on_step(key, k, ctl)`` after each step."""
    plants, out = {}, {}
    for key, ctl in ctls.items():
        ctl.reset()
        plants[key] = ConstrainedPlant(robot, ref.initial_state(), Ts=Ts)
        out[key] = ([], [])
    for k in range(samples):
        w = ref.window(k * Ts, Ts, N)
        for key, ctl in ctls.items():
            plant, (times, us) = plants[key], out[key]
            t0 = clock()
            info = ctl.step(plant.X, w)
            times.append(clock() - t0)
            us.append(info.u)
            if on_step is not None:
                on_step(key, k, ctl)
            plant.step(info.u)
    return {key: (times, np.array(us)) for key, (times, us) in out.items()}
