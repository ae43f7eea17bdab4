"""Shared fixtures: the two embedded robots, a 3-PRR with prismatic drives and a random-state generator."""

from __future__ import annotations

import math

import numpy as np
import pytest

from parallel_gpc import ParallelRobot, ReducedModel

POSE_A = np.array([0.2, 0.2, math.radians(-20.0)])
POSE_B = np.array([0.8, 0.8, math.radians(20.0)])


@pytest.fixture(scope="session", params=["planar_4rrr", "planar_3rrr"])
def robot(request) -> ParallelRobot:
    return ParallelRobot.load(request.param)


@pytest.fixture(scope="session")
def robot4() -> ParallelRobot:
    return ParallelRobot.load("planar_4rrr")


@pytest.fixture(scope="session")
def robot3() -> ParallelRobot:
    return ParallelRobot.load("planar_3rrr")


@pytest.fixture(scope="session")
def prr3(tmp_path_factory) -> ParallelRobot:
    """A planar 3-PRR (prismatic drives s1..s3 in N, pose output x, y, rz) written from the docs
    (:func:`mechanisms.prr3_urdf`)."""
    import mechanisms as mech

    folder = tmp_path_factory.mktemp("prr3")
    return ParallelRobot.load(mech.write(folder, "prr3_test", mech.prr3_urdf(), mech.prr3_sidecar()))


def random_states(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Random reachable states X = [y, ẏ] on the A→B segment, with velocities up to ~1 m/s."""
    states = []
    for _ in range(n):
        s = rng.uniform(0.0, 1.0)
        pose = POSE_A + s * (POSE_B - POSE_A) + rng.uniform(-0.05, 0.05, 3) * np.array([1, 1, 2])
        states.append(np.concatenate([pose, rng.uniform(-1.0, 1.0, 3)]))
    return states


@pytest.fixture
def model4(robot4) -> ReducedModel:
    return ReducedModel(robot4)


def line_motion(robot, n: int = 41, duration: float = 2.0):
    """(t, qs, poses): the platform along a line from [0.3, 0.3, -0.2] to [0.7, 0.7, 0.2]."""
    t = np.linspace(0.0, duration, n)
    poses = np.array([0.3, 0.3, -0.2]) + np.outer(t / duration, [0.4, 0.4, 0.4])
    qs, q = [], None
    for pose in poses:
        q = robot.assemble(pose, q)
        qs.append(q)
    return t, np.array(qs), poses
