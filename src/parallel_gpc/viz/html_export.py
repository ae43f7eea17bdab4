"""Offline HTML export: one self-contained page per trajectory (the viewer bundle inlined)."""

from __future__ import annotations

import html
import re
from pathlib import Path

from ..errors import ViewerError, writing
from ..model import ParallelRobot
from .live import LiveViewer
from .scene import animate


_NETWORK_PATTERNS = [
    r"""\b(?:src|href|action|poster|data)\s*=\s*["']?\s*(?:https?:)?//[^\s"'>]*""",
    r"""url\(\s*["']?\s*(?:https?:)?//[^\s"')]*""",
    r"""@import\s+["']?(?:url\()?\s*["']?(?:https?:)?//[^\s"')]*""",
    r"""\b(?:fetch|import|importScripts)\s*\(\s*["'](?:https?:)?//[^"']*""",
    r"""new\s+(?:WebSocket|EventSource)\s*\(\s*["'](?:wss?:|https?:)?//[^"']*""",
]


def network_references(page: str) -> list[str]:
    """Places in an HTML text that would load something over the network (http(s) or ws(s) URLs)."""
    return [m.group(0) for pattern in _NETWORK_PATTERNS for m in re.finditer(pattern, page, re.IGNORECASE)]


def _decorate(page: str, title: str, legend: str) -> str:
    page = page.replace("<title>MeshCat</title>", f"<title>{html.escape(title)}</title>", 1)
    caption = (
        '<div id="parallel-gpc-caption" style="position:fixed;left:8px;bottom:8px;padding:4px 8px;'
        'font:12px sans-serif;background:rgba(255,255,255,0.8);border-radius:4px;pointer-events:none">'
        f"<b>{html.escape(title)}</b><br>{html.escape(legend)}</div>"
    )
    return page.replace("</body>", caption + "</body>", 1)


def export_html(path, robot: ParallelRobot, t, qs, reference=None, planned=None, saturated=None,
                title: str | None = None, fps: float = 30.0, max_frames: int = 300) -> Path:
    """Write a self-contained HTML animation of a trajectory (works offline).

    Builds the scene on a private :class:`LiveViewer` (127.0.0.1, stopped on return) and saves
    ``vis.static_html()``, which inlines the meshcat viewer bundle.

    Args:
        path: output file (.html); parent folders are created.
        robot, t, qs, reference, planned, saturated, fps, max_frames: as in :func:`animate`.
        title: page title (default: the robot name).

    Returns:
        the written path.

    Raises:
        ViewerError: if the page would load anything from the network.
    """
    path = Path(path)
    title = title or f"parallel-gpc: {robot.name}"
    with LiveViewer() as viewer:
        scene = animate(viewer.vis, robot, t, qs, saturated=saturated, reference=reference, planned=planned,
                        fps=fps, max_frames=max_frames)
        page = viewer.vis.static_html()
    legend = "links as in the robot file" if scene.geom_model.ngeoms else ""
    if scene.stick.rods:
        legend += (", " if legend else "") + "links without visuals: grey rods, blue joints"
    legend += ", output red, closures yellow/black"
    legend += ", reference grey" if reference is not None else ""
    legend += ", planned magenta" if planned is not None else ""
    legend += ", drive at torque limit red" if saturated is not None else ""
    page = _decorate(page, title, legend)
    found = network_references(page)
    if found:
        raise ViewerError(f"exported page would load from the network: {found[:3]}; not written to {str(path)!r}")
    with writing(path, "animation page"):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(page, encoding="utf-8")
    return path
