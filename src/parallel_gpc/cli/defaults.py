"""Defaults the parsers show in ``--help``, kept here so ``--help`` imports neither Pinocchio nor
matplotlib. ``tests/test_cli.py`` checks each against the library's own default."""

#: = :data:`parallel_gpc.DEFAULT_ROBOT`.
DEFAULT_ROBOT = "planar_4rrr"
#: = :data:`parallel_gpc.FORMS`.
FORMS = ("absolute", "incremental", "nonlinear")
#: = the fields of ``parallel_gpc.TrackingSettings()`` that ``track`` and ``demo`` expose.
TRACKING = {"Ts": 0.002, "N": 20, "No": 0, "Qy": 1.0, "Qu": 0.0}
