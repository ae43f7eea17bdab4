"""Render a picture of each embedded robot in the meshcat view: docs/robots/<name>.png.

Exports the view of the robot at its home pose (``parallel_gpc.viz.export_html``, a
self-contained page) and screenshots it in headless Chromium (/usr/bin/chromium, driven by
Playwright, WebGL on SwiftShader), as tests/test_browser.py does. Run from the repository root:

    PYTHONPATH=src python docs/robots/render_robots.py [NAME ...]
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import math

import numpy as np
import pinocchio as pin

from parallel_gpc import ParallelRobot, viz
from parallel_gpc.model.robot import embedded_robots

HERE = Path(__file__).resolve().parent
CHROMIUM = "/usr/bin/chromium"
ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-sandbox",
        "--disable-background-networking", "--disable-component-update", "--no-first-run", "--disable-sync"]


def export(robot: ParallelRobot, folder: Path) -> Path:
    """The view of ``robot`` at home (two identical key frames) as an HTML file in ``folder``."""
    qs = np.array([robot.q_home, robot.q_home])
    return viz.export_html(folder / f"{robot.name}.html", robot, [0.0, 1.0], qs, title=f"{robot.name} at home")


def frame_robot(page, robot: ParallelRobot, elevation_deg: float = 22.0) -> None:
    """Centre the scene on the joints at home and look from −y, slightly above, at a distance
    that fits them (meshcat's camera orbits the origin; its frame is y-up)."""
    data = robot.model.createData()
    pin.forwardKinematics(robot.model, data, robot.q_home)
    pts = np.array([data.oMi[j].translation for j in range(1, robot.model.njoints)])
    centre, span = 0.5 * (pts.min(axis=0) + pts.max(axis=0)), float(np.ptp(pts, axis=0).max())
    shift = np.eye(4)
    shift[:3, 3] = -centre
    dist, el = 1.1 * span + 0.15, math.radians(elevation_deg)
    page.evaluate('m => viewer.handle_command({type: "set_transform", path: "/meshcat", matrix: new Float32Array(m)})',
                  shift.T.reshape(-1).tolist())
    page.evaluate('p => viewer.handle_command({type: "set_property", path: "/Cameras/default/rotated/<object>", '
                  'property: "position", value: p})', [0.0, dist * math.sin(el), dist * math.cos(el)])
    page.add_style_tag(content=".dg { display: none !important; }")  # the controls banner


def main(names: list[str]) -> None:
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as tmp, sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            for name in names:
                page = browser.new_page(viewport={"width": 800, "height": 600})
                robot = ParallelRobot.load(name)
                page.goto(export(robot, Path(tmp)).as_uri())
                page.wait_for_selector("canvas", timeout=30_000)
                page.wait_for_timeout(3000)  # the scene commands are applied
                frame_robot(page, robot)
                page.wait_for_timeout(1000)  # redrawn
                out = HERE / f"{name}.png"
                page.screenshot(path=str(out))
                page.close()
                print(f"wrote {out}")
        finally:
            browser.close()


if __name__ == "__main__":
    main(sys.argv[1:] or embedded_robots())
