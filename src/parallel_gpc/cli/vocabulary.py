"""The words every command spells the same way: the GPC forms and the references.

``--forms`` takes space-separated names (``--forms absolute nonlinear``, or ``all``) in ``track``,
``demo`` and ``robustness``; ``--reference`` takes the same names in ``track`` and
``robustness``. A misspelling ends with one line naming the valid words (exit 2). The options of
the commands that load a robot file come from two parent parsers (argparse ``parents=``):
:data:`PACKAGE_PATH` (``--package-path``) and :data:`ROBOT` (``--robot`` and ``--package-path``).
"""

from __future__ import annotations

import argparse

from .defaults import DEFAULT_ROBOT, FORMS, REFERENCES

def add_forms_argument(p, default: tuple[str, ...] | None = None, *aliases: str) -> None:
    """``--forms F [F ...]`` (choices :data:`FORMS` and ``all``; ``default`` None: all of them)."""
    shown = "all" if default is None else " ".join(default)
    p.add_argument("--forms", *aliases, nargs="+", choices=[*FORMS, "all"], metavar="FORM",
                   default=["all"] if default is None else list(default), dest="forms",
                   help="GPC forms, space-separated: absolute, incremental, incremental-delayed (eq. (8)-(9) as "
                        "printed: each increment acts one sample later), nonlinear; or all "
                        f"(default {shown})")


def selected_forms(names: list[str]) -> list[str]:
    """The forms of ``--forms`` (``all``: every form), in the order given, each once."""
    return list(FORMS) if "all" in names else list(dict.fromkeys(names))


#: How ``--reference`` shows its values: a built-in name or a reference file.
REFERENCE_METAVAR = "{" + ",".join(REFERENCES) + ",FILE.csv,FILE.npz}"


def reference_argument(text: str) -> str:
    """``--reference`` value: a name of :data:`REFERENCES` or a ``.csv`` / ``.npz`` path (the file
    is read, and its columns checked, when the robot is known)."""
    if text in REFERENCES or text.lower().endswith((".csv", ".npz")):
        return text
    raise argparse.ArgumentTypeError(f"{text!r} is not one of {', '.join(REFERENCES)}, nor a .csv or .npz file")


def add_reference_argument(p, hold: str, extra: str = "") -> None:
    """``--reference {auto,s-curve,circle,line,helix,hold,FILE.csv,FILE.npz}`` (default auto);
    ``hold`` says what the hold is, ``extra`` adds a command's own remark."""
    p.add_argument("--reference", type=reference_argument, default="auto", metavar=REFERENCE_METAVAR,
                   help="a path in the robot's own outputs, sized to its workspace around home and checked before "
                        "the run: auto (the paper's S-curve for planar x, y, psi robots, the helix for 3 "
                        "translations, an S-curve in the plane of 2, a line for 1), s-curve, circle, line, helix; "
                        f"hold: {hold}; or a file: FILE.csv (a column t and one column per output label, SI units: "
                        f"s, m, rad) or a plan/reference FILE.npz{extra} (default auto)")


def add_limit_arguments(p) -> None:
    """The state-limit options (``--limits``, ``--output-box``, ``--velocity-limit``, ``--hard-limits``)."""
    p.add_argument("--limits", choices=["robot", "none"], default="robot",
                   help="the robot file's limits: its drive limit ([drives] torque_limit, unless --torque-limit "
                        "gives one) and its [limits] table (drive strokes, workspace, velocities), or none "
                        "(default robot; the run prints which apply)")
    p.add_argument("--output-box", type=float, nargs="+", default=None, metavar="LO HI",
                   help="workspace box: lower and upper bound of each output in turn (m, rad), e.g. for x, y, ψ: "
                        "-0.1 0.1 -0.1 0.1 -3.2 3.2 (soft unless --hard-limits)")
    p.add_argument("--velocity-limit", type=float, nargs="+", default=None, metavar="V",
                   help="output velocity limit |ẏ| ≤ V (m/s, rad/s): one value or one per output")
    p.add_argument("--hard-limits", action="store_true",
                   help="every state limit hard (default: soft, exact penalty, unless the robot file says otherwise)")


def limits_line(args, limits, drive_unit: str) -> str:
    """The line ``track``, ``demo`` and ``plan`` print about the limits in force: where they come
    from (``--limits``), their units (efforts in the robot's drive unit, the rest SI) and each limit."""
    source = "robot file and flags" if args.limits == "robot" else "flags only"
    return f"limits ({source}; efforts in {drive_unit}, positions in m and rad): {limits.describe()}"


def _add_package_path(p) -> None:
    """``--package-path DIR`` (repeatable): folders of the packages named by ``package://`` mesh URIs,
    searched before ``PARALLEL_GPC_PACKAGE_PATH`` and ``ROS_PACKAGE_PATH`` (applied by :func:`apply_package_path`)."""
    p.add_argument("--package-path", action="append", default=[], metavar="DIR", dest="package_path",
                   help="folder holding the packages of package:// mesh URIs (repeatable; searched in the order "
                        "given, before $PARALLEL_GPC_PACKAGE_PATH and $ROS_PACKAGE_PATH); meshes only matter for "
                        "the view")


#: parent parser of the commands that load a robot file named elsewhere (``info``, ``sweep``,
#: ``view``): ``--package-path DIR``.
PACKAGE_PATH = argparse.ArgumentParser(add_help=False)
_add_package_path(PACKAGE_PATH)
#: parent parser of the commands that run one robot (``track``, ``demo``, ``plan``, ``robustness``):
#: ``--robot NAME|PATH`` (default :data:`~.defaults.DEFAULT_ROBOT`) and ``--package-path DIR``.
ROBOT = argparse.ArgumentParser(add_help=False)
ROBOT.add_argument("--robot", default=DEFAULT_ROBOT, help=f"embedded robot name or path (default {DEFAULT_ROBOT})")
_add_package_path(ROBOT)


def apply_package_path(folders: list[str]) -> None:
    """Put the ``--package-path`` folders in front of ``PARALLEL_GPC_PACKAGE_PATH`` for this process
    and the workers it starts, so every robot the command loads searches them first.

    Raises:
        RobotFormatError: a folder that does not exist (naming it).
    """
    import os

    from ..model.meshes import PACKAGE_PATH_ENV, package_roots

    if not folders:
        return
    roots = package_roots(folders, environ={})  # validates each folder (one error naming it)
    previous = os.environ.get(PACKAGE_PATH_ENV, "")
    os.environ[PACKAGE_PATH_ENV] = os.pathsep.join([*map(str, roots), *([previous] if previous else [])])
