"""Defaults the parsers show in ``--help``, kept here so ``--help`` imports neither Pinocchio nor
matplotlib. ``tests/test_cli.py`` checks each against the library's own default."""

#: = :data:`parallel_gpc.DEFAULT_ROBOT`.
DEFAULT_ROBOT = "planar_4rrr"
#: = :data:`parallel_gpc.FORMS`.
FORMS = ("absolute", "incremental", "incremental-delayed", "nonlinear")
#: = the fields of ``parallel_gpc.TrackingSettings()`` that ``track`` and ``demo`` expose.
TRACKING = {"Ts": 0.002, "N": 20, "No": 0, "Qy": 1.0, "Qu": 0.0, "disturbance_gain": None, "mass_scale": 1.0,
            "platform_force": (0.0, 0.0, 0.0), "duration": None}
#: = the same fields of ``parallel_gpc.studies.DEMO_SETTINGS`` (the ``demo`` command).
DEMO = {**TRACKING, "Ts": 0.01, "N": 30, "Qu": 1e-3, "mass_scale": 1.2, "platform_force": (5.0, -5.0, 0.5),
        "duration": 3.0, "disturbance_gain": 0.5}
#: = :data:`parallel_gpc.gpc.robot_references.REFERENCE_KINDS`: the built-in references.
REFERENCES = ("auto", "s-curve", "circle", "line", "helix", "hold")
#: How ``--reference`` shows its values: a built-in name or a reference file.
REFERENCE_METAVAR = "{" + ",".join(REFERENCES) + ",FILE.csv,FILE.npz}"
#: ``--reference`` help shared by ``track`` and ``robustness``.
REFERENCE_HELP = ("a path in the robot's own outputs, sized to its workspace around home and checked before the "
                  "run: auto (the S-curve for planar x, y, psi robots, the helix for 3 translations, an S-curve in "
                  "the plane of 2, a line for 1), s-curve, circle, line, helix, hold; or a file: FILE.csv (a column "
                  "t and one column per output label, SI units: s, m, rad) or a plan/reference FILE.npz")


def reference_argument(text: str) -> str:
    """``--reference`` value: a name of :data:`REFERENCES` or a ``.csv`` / ``.npz`` path (checked
    when the robot is known)."""
    import argparse

    if text in REFERENCES or text in ("path", "scurve") or text.lower().endswith((".csv", ".npz")):
        return text
    raise argparse.ArgumentTypeError(f"{text!r} is not one of {', '.join(REFERENCES)}, nor a .csv or .npz file")
