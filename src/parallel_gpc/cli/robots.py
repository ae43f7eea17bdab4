"""``parallel-gpc robots``: the embedded robots, read from their sidecars (no Pinocchio model built)."""

from __future__ import annotations


def robot_rows() -> list[tuple[str, str, str, str]]:
    """(name, DOF, drives, outputs) of every embedded robot, from its closure sidecar."""
    from ..model import embedded_robots, load_description

    rows = []
    for name in embedded_robots():
        d = load_description(name)
        rows.append((name, str(d.n_y), f"{len(d.drive_joints)} ({', '.join(d.drive_joints)})",
                     ", ".join(d.output_labels)))
    return rows


def cmd_robots(args) -> int:
    header = ("robot", "DOF", "drives", "outputs")
    rows = [header, *robot_rows()]
    widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
    for row in rows:
        print("  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip())
    print("use one with --robot NAME, or give a path to your own URDF + sidecar (see `parallel-gpc info`)")
    return 0


def register_robots(sub) -> None:
    """Add the ``robots`` sub-command."""
    p = sub.add_parser("robots", help="list the embedded robots (name, DOF, drives)")
    p.set_defaults(func=cmd_robots)
