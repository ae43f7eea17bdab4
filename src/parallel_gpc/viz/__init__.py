"""meshcat view of a parallel robot: scene and animation, offline HTML, loopback servers, gallery.

Modules, by seam: :mod:`~parallel_gpc.viz.visuals` (the robot file's shapes and meshes),
:mod:`~parallel_gpc.viz.scene` (drawing a robot, paths and one animation per
trajectory), :mod:`~parallel_gpc.viz.html_export` (self-contained offline pages),
:mod:`~parallel_gpc.viz.live` (the meshcat bridge on 127.0.0.1 in a thread),
:mod:`~parallel_gpc.viz.gallery` (a folder of exported pages on 127.0.0.1) and
:mod:`~parallel_gpc.viz.loopback` (bind address, Host header and idle timeout checks). Every server
binds a loopback address only, answers loopback Host names only and is stopped by the code that
started it.

Names are resolved lazily, so the gallery (and ``import parallel_gpc.viz``) needs neither
meshcat nor Pinocchio; the scene, the live viewer and the HTML export import both.
"""

from __future__ import annotations

import importlib

#: public name -> submodule that defines it
_PUBLIC = {
    "LOOPBACK": "loopback", "loopback_host": "loopback", "loopback_host_header": "loopback",
    "IDLE_TIMEOUT_S": "loopback",
    "GalleryServer": "gallery", "gallery_index": "gallery", "serve_gallery": "gallery",
    "RobotScene": "scene", "animate": "scene", "draw_path": "scene", "draw_robot": "scene",
    "frame_indices": "scene", "set_camera": "scene", "visual_model": "visuals", "Marks": "scene",
    "REFERENCE_COLOR": "scene", "PLANNED_COLOR": "scene", "SATURATION_COLOR": "scene",
    "export_html": "html_export", "network_references": "html_export",
    "LiveViewer": "live", "serve_until_interrupt": "live", "zmq_port_of": "live",
    "meshcat": "_meshcat", "VIEWER_ROOT": "_meshcat",
    "saturation_flags": "parallel_gpc.results",
}

__all__ = list(_PUBLIC)


def __getattr__(name: str):
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'parallel_gpc.viz' has no attribute {name!r}")
    target = module if module.startswith("parallel_gpc.") else f"{__name__}.{module}"
    value = getattr(importlib.import_module(target), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))
