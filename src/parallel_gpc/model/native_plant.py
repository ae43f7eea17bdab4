"""The compiled plant step: ``parallel_gpc._native.Plant`` built for one robot.

:class:`~parallel_gpc.model.plant.ConstrainedPlant` integrates one sample (RK4 sub-steps of
Pinocchio's ``constraintDynamics``) either in Python (the reference) or in one call to the
compiled core, which owns its own copy of the model (handed over in Pinocchio's serialization
format, so mass scale and gravity come along) and the same closure constraints.
"""

from __future__ import annotations

import numpy as np

from .native import compiled_part

#: constraint dimension of each closure kind (CONTACT_3D / CONTACT_6D)
_DIMS = {"point": 3, "weld": 6}


def compiled_plant(robot, baumgarte, proximal, native: bool | None):
    """The compiled integrator of ``robot``'s constrained dynamics, or None for the Python path.

    Args:
        robot: the plant's :class:`~parallel_gpc.model.robot.ParallelRobot`.
        baumgarte: (Kp in 1/s², Kd in 1/s) closure stabilization gains.
        proximal: (accuracy, mu, max_iter) of ``pin.ProximalSettings``.
        native: None (use the compiled core if available), False (never) or True (required).

    Raises:
        InvalidParameterError: ``native`` is not None/True/False, or True while the compiled core
            cannot be used (the message says why: not built, Pinocchio mismatch, switched off).
    """
    Plant = compiled_part(native, "Plant", "the compiled plant")
    if Plant is None:
        return None
    model = robot.model
    frames = [(model.frames[fa], model.frames[fb], c) for fa, fb, c in robot.closure_frames]
    plant = Plant(
        model.saveToString(), [_DIMS[c.kind] for _, _, c in frames],
        [int(Fa.parentJoint) for Fa, _, _ in frames], [np.array(Fa.placement.homogeneous) for Fa, _, _ in frames],
        [int(Fb.parentJoint) for _, Fb, _ in frames], [np.array(Fb.placement.homogeneous) for _, Fb, _ in frames],
        float(baumgarte[0]), float(baumgarte[1]), *map(float, proximal[:2]), int(proximal[2]))
    task = robot.task_output
    if task is not None:
        plant.set_task_output(task.frame_id, [int(r) for r in task.rows], np.array(task.R_ref))
    return plant
