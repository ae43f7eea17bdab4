"""The problems the benchmark times: what to run, the closed-loop samples along the S-curve,
and the controllers that replay them.

:class:`BenchConfig` says which robots, horizons and stretches; :func:`closed_loop_states` runs the
absolute controller on the full constrained plant and cuts the run into stretches of consecutive
samples (state, input and plan held before each); :func:`replay` replays a controller from such a
stretch so that every repetition of :mod:`parallel_gpc.bench.harness` meets the same problems.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..gpc import GPCController, Weights, Horizons, SCurve
from ..limits import Limits
from ..model import ReducedModel, ConstrainedPlant, ParallelRobot
from ..studies import simulate
from .report import PYTHON_REFERENCE
from .store import BenchEntry


__all__ = ["BenchConfig", "robot_C", "closed_loop_states", "replay_controllers", "replay"]


@dataclass
class BenchConfig:
    """What to run.

    Attributes:
        robots: embedded robot names. Ns: horizons. Ts: sample time (s).
        spatial, spatial_Ns: further robots (tracking the helix about their home pose) and their
            horizons. closed_loop_s: simulated seconds of the 1 kHz closed loop (0: skipped).
        qu: square-root input weight of the benchmark problems: small (the S-curve is tracked
            to < 0.1 mm at Ts = 2 ms, N = 20) and positive (strictly convex QPs with unique
            solutions to compare, and qpmpc needs a positive input weight).
        segments: start times (s) of the stretches of consecutive samples along the S-curve.
        segment_length: samples per stretch; the first ``warmup`` of each are not timed.
        reps: interleaved repetitions (after one untimed recording pass).
        limit_quantile: the torque limit is this quantile of |u| of the unconstrained solutions.
        qp_solvers: qpsolvers back ends. direct: persistent back ends.
    """

    robots: tuple[str, ...] = ("planar_4rrr", "planar_3rrr")
    Ns: tuple[int, ...] = (10, 20, 40)
    spatial: tuple[str, ...] = ("delta_3rus", "hexapod_6ups", "hexapod_8ups")
    spatial_Ns: tuple[int, ...] = (20,)
    closed_loop_s: float = 10.0
    Ts: float = 0.002
    qu: float = 1e-5
    segments: tuple[float, ...] = (0.35, 0.75, 1.15, 1.55)
    segment_length: int = 30
    warmup: int = 5
    reps: int = 5
    limit_quantile: float = 0.5
    qp_solvers: tuple[str, ...] = ("osqp", "proxqp", "daqp")
    direct: tuple[str, ...] = ("osqp-direct", "proxqp-direct", "daqp-direct")
    qpmpc_solvers: tuple[str, ...] = ("proxqp", "daqp")
    progress: bool = True

    @classmethod
    def quick(cls) -> "BenchConfig":
        """A short run (< 3 min on 2 cores): fewer stretches, samples and repetitions."""
        return cls(segments=(0.5, 1.2), segment_length=9, warmup=3, reps=3, closed_loop_s=2.0)

    @classmethod
    def tiny(cls) -> "BenchConfig":
        """The smallest meaningful run (tests): one robot, one horizon, two repetitions."""
        return cls(robots=("planar_4rrr",), Ns=(10,), spatial=(), segments=(0.8,), segment_length=5, warmup=2,
                   reps=2, progress=False, closed_loop_s=0.02)


# ------------------------------------------------------------------------------- problems
@dataclass
class _Sample:
    """One control instant along the S-curve: time, state, reference window, and the input
    applied and the plan held just before it (to start a controller mid-curve)."""

    t: float
    X: np.ndarray
    w: np.ndarray | None
    u_prev: np.ndarray
    plan: np.ndarray


def closed_loop_states(robot: ParallelRobot, cfg: BenchConfig, ref: SCurve) -> dict[float, list[_Sample]]:
    """States of a closed-loop run (absolute GPC, N = 20, full constrained plant) on the S-curve,
    cut into the configured stretches of consecutive samples."""
    Ts = cfg.Ts
    ctl = GPCController.build(ReducedModel(robot), Ts, Horizons(20), Weights(1.0, cfg.qu), form="absolute")
    plant = ConstrainedPlant(robot, ref.initial_state(), Ts=Ts)
    plans = [ctl.plan.copy()]
    step = ctl.step

    def recording_step(X, w):
        info = step(X, w)
        plans.append(ctl.plan.copy())
        return info

    ctl.step = recording_step
    end = max(cfg.segments) + cfg.segment_length * Ts + Ts
    res = simulate(ctl, plant, ref, end, progress=False)
    X = np.hstack([res.pose, res.velocity])
    out = {}
    for start in cfg.segments:
        k0 = int(round(start / Ts))
        out[start] = [_Sample(float(res.t[k]), X[k].copy(), None, res.u[k - 1].copy(), plans[k])
                      for k in range(k0, k0 + cfg.segment_length)]
    return out


def _start_at(ctl: GPCController, smp: _Sample) -> None:
    """Put a controller in the state it would have at ``smp`` had it run from the start."""
    ctl.reset(smp.u_prev)
    N = ctl.horizons.N
    plan = smp.plan[:N]
    ctl.plan = np.vstack([plan, np.repeat(plan[-1:], N - len(plan), axis=0)])


def replay_controllers(model_factory, cfg: BenchConfig, N: int, tau):
    """The full-step configurations: (name, controller). ``model_factory(native)`` builds the
    controller's model: ``native=None`` the default (the compiled core when built), ``False`` the
    pure-Python reference (with QR: the issues' reference path), timed in the same run for the
    speed-up rows. ``FORM`` rows run the default solver (:func:`~parallel_gpc.gpc.settings.default_solver`:
    the stage-wise Riccati path at the benchmark's Qu), ``FORM qr`` the square-root QR reference."""
    H = Horizons(N)
    W = Weights(1.0, cfg.qu)
    limits = Limits(torque=tau)
    out = []
    for form in ("absolute", "incremental", "nonlinear"):  # the default solver (stage-wise here), QR, Python + QR
        out.append((f"{form}", GPCController.build(model_factory(None), cfg.Ts, H, W, form=form)))
        out.append((f"{form} qr", GPCController.build(model_factory(None), cfg.Ts, H, W, form=form, solver="qr")))
        out.append((f"{form}{PYTHON_REFERENCE}", GPCController.build(model_factory(False), cfg.Ts, H, W, form=form,
                                                                      solver="qr")))
        out.append((f"{form} +limits", GPCController.build(model_factory(None), cfg.Ts, H, W, form=form,
                                                           limits=limits)))
    for form in ("absolute", "incremental"):  # the paper's Fig. 2 weights: Qu = 0, minimum-norm QR
        out.append((f"{form} Qu=0", GPCController.build(model_factory(None), cfg.Ts, H, Weights(1.0, 0.0), form=form)))
    for form in ("absolute", "incremental"):  # limits through DAQP alone (no QR first)
        out.append((f"{form} +limits daqp-direct", GPCController.build(model_factory(None), cfg.Ts, H, W, form=form,
                                                                       solver="daqp-direct", limits=limits)))
    out.append(("absolute +limits bvls", GPCController.build(model_factory(None), cfg.Ts, H, W, solver="bvls",
                                                             limits=limits)))
    out.append(("absolute cholesky", GPCController.build(model_factory(None), cfg.Ts, H, W, solver="cholesky")))
    return out


def replay(ctl: GPCController, robot: ParallelRobot, stretches, ref: SCurve, N: int, entry: BenchEntry | None = None,
            warmup: int = 0) -> list[list[tuple]]:
    """Run ``ctl`` in closed loop on the full plant over each stretch (from the recorded state,
    with the recorded input and plan) and keep, per sample, (X, w, controller state before the
    step): the problems this controller really meets, replayed identically in every repetition.
    With ``entry``, the step times of this closed loop (controller and plant alternating, as in
    a real-time loop) are recorded there too."""
    Ts = ctl.Ts
    out = []
    for stretch in stretches:
        _start_at(ctl, stretch[0])
        plant = ConstrainedPlant(robot, stretch[0].X, Ts=Ts)
        rows = []
        for k, smp in enumerate(stretch):
            X, w = plant.X, ref.window(smp.t, Ts, N)
            rows.append((X, w, ctl.state))
            t0 = time.perf_counter()
            info = ctl.step(X, w)
            dt = time.perf_counter() - t0
            if entry is not None and k >= warmup:
                entry.times.append(dt)
                entry.failures += int(info.fallback)
            plant.step(info.u)
        out.append(rows)
    return out



def robot_C(robot: ParallelRobot) -> np.ndarray:
    return np.hstack([np.eye(robot.n_y), np.zeros((robot.n_y, robot.n_y))])
