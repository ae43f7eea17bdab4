"""The words every command spells the same way: the GPC forms and the references.

``--forms`` takes space-separated names (``--forms absolute nonlinear``, or ``all``) in ``track``,
``demo`` and ``robustness``; ``--reference`` takes the same names in ``track`` and
``robustness``. A misspelling ends with one line naming the valid words (exit 2).
"""

from __future__ import annotations

from .defaults import FORMS, REFERENCES

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


def add_reference_argument(p, hold: str) -> None:
    """``--reference {auto,s-curve,helix,hold}`` (default auto); ``hold`` says what the hold is."""
    p.add_argument("--reference", choices=REFERENCES, default="auto",
                   help="auto: the paper's S-curve for planar robots, the 3-D helix (one turn) for spatial ones; "
                        f"s-curve; helix; hold: {hold} (default auto)")
