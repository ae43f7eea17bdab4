"""Defaults the parsers show in ``--help``, kept here so ``--help`` imports neither Pinocchio nor
matplotlib. ``tests/test_cli.py`` checks each against the library's own default."""

#: = :data:`parallel_gpc.DEFAULT_ROBOT`.
DEFAULT_ROBOT = "planar_4rrr"
#: = :data:`parallel_gpc.FORMS`.
FORMS = ("absolute", "incremental", "incremental-delayed", "nonlinear")
#: = the fields of ``parallel_gpc.TrackingSettings()`` that ``track`` and ``demo`` expose.
TRACKING = {"Ts": 0.002, "N": 20, "No": 0, "Qy": 1.0, "Qu": 0.0, "disturbance_gain": None, "mass_scale": 1.0,
            "platform_force": (0.0, 0.0, 0.0), "duration": None, "iterations": 1}
#: = the default of ``parallel_gpc.GPCSettings.tolerance``: the nonlinear form's iterations' relative step tolerance.
TOLERANCE = 1e-8
#: = the same fields of ``parallel_gpc.studies.DEMO_SETTINGS`` (the ``demo`` command).
DEMO = {**TRACKING, "Ts": 0.01, "N": 30, "Qu": 1e-3, "mass_scale": 1.2, "platform_force": (5.0, -5.0, 0.5),
        "duration": 3.0, "disturbance_gain": 0.5}
#: = :data:`parallel_gpc.gpc.settings.PAPER_FORMS`, the forms the paper compares.
PAPER_FORMS = ("absolute", "incremental", "nonlinear")
#: = :data:`parallel_gpc.gpc.robot_references.REFERENCE_KINDS`: the built-in references.
REFERENCES = ("auto", "s-curve", "circle", "line", "helix", "hold")

#: Exit code of a command whose input was refused (one-line error on stderr).
EXIT_BAD_INPUT = 2
#: Exit code of ``track`` / ``demo`` when a closed loop diverged: the run was valid input, its
#: samples up to the divergence are saved and the message says where and why.
EXIT_DIVERGED = 3
#: Exit code of a command stopped by Ctrl-C (after saving what it computed).
EXIT_INTERRUPTED = 130
