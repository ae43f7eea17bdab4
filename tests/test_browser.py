"""The exported animation and the live viewer in headless Chromium.

Needs Debian's /usr/bin/chromium (Playwright drives it; no Playwright browser download). WebGL
runs on SwiftShader (``--use-angle=swiftshader --enable-unsafe-swiftshader``).
"""

from __future__ import annotations

import io
import os
import socket

import numpy as np
import pytest

from parallel_gpc import viz

import mechanisms as mech
from conftest import line_motion

pytestmark = pytest.mark.browser

CHROMIUM = "/usr/bin/chromium"
ARGS = [
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--no-sandbox",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
]
VIEWPORT = {"width": 800, "height": 600}
WAIT_MS = 30_000
#: Counts the scene commands the viewer has applied (``window.__handled``): patched into
#: ``MeshCat.Viewer`` as soon as the inlined bundle defines it, before the scene is sent.
COUNT_COMMANDS = """
(() => {
  let meshcat;
  window.__handled = 0;
  Object.defineProperty(window, "MeshCat", {configurable: true, get() { return meshcat; }, set(value) {
    meshcat = value;
    const proto = value.Viewer.prototype, apply = proto.handle_command_bytearray;
    proto.handle_command_bytearray = function (bytes) {
      const result = apply.call(this, bytes);
      window.__handled += 1;
      return result;
    };
  }});
})();
"""
COMMAND = 'fetch("data:application/octet-binary;base64,'


@pytest.fixture(scope="module")
def browser():
    if not os.path.exists(CHROMIUM):
        reason = f"{CHROMIUM} not found (apt-get install chromium); browser test skipped"
        print(reason)
        pytest.skip(reason)
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        yield browser
        browser.close()




def canvas_pixels(page) -> np.ndarray:
    """(H, W, 3) int array of the WebGL canvas, after two rendered frames."""
    from PIL import Image

    page.evaluate("viewer.set_dirty()")
    page.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
    png = page.locator("canvas").screenshot()
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=int)


def changed_fraction(a: np.ndarray, b: np.ndarray, threshold: int = 40) -> float:
    """Fraction of pixels whose summed RGB difference exceeds ``threshold``."""
    return float(np.mean(np.abs(a - b).sum(axis=2) > threshold))


def robot_colours(img: np.ndarray) -> tuple[int, int]:
    """Pixel counts of the green platform and the orange drive links (hue tests, any shading)."""
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    green = (g > r + 40) & (g > b + 40)
    orange = (r > 120) & (r > g + 50) & (g > b + 10)
    return int(green.sum()), int(orange.sum())


def seek(page, time_s: float) -> None:
    page.evaluate(f"viewer.animator.pause(); viewer.animator.seek({time_s})")


def set_robot_visible(page, visible: bool) -> None:
    value = "true" if visible else "false"
    page.evaluate('viewer.handle_command({type: "set_property", path: "/meshcat/robot", '
                  f'property: "visible", value: {value}}})')


def new_page(browser, requests: list):
    page = browser.new_page(viewport=VIEWPORT)
    page.add_init_script(COUNT_COMMANDS)
    page.on("request", lambda request: requests.append(request.url))
    return page


def wait_for_scene(page, n_commands: int) -> None:
    """Wait until the viewer has applied all ``n_commands`` scene commands (objects, camera, ...)."""
    assert n_commands > 10
    page.wait_for_selector("canvas", timeout=WAIT_MS)
    page.wait_for_function(f"window.__handled >= {n_commands}", timeout=WAIT_MS)
    assert page.evaluate(
        'viewer.scene_tree.find(["meshcat", "robot", "platform_0", "<object>"]).object.type') == "Mesh"


def test_exported_html_renders_offline_and_animates(browser, robot4, tmp_path):
    t, qs, poses = line_motion(robot4, n=101)
    path = viz.export_html(tmp_path / "line.html", robot4, t, qs, reference=poses, title="browser test")
    requests = []
    page = new_page(browser, requests)
    try:
        page.goto(path.resolve().as_uri())
        wait_for_scene(page, path.read_text(encoding="utf-8").count(COMMAND))
        assert page.evaluate("viewer.animator.actions.length") > 0
        assert page.evaluate("viewer.animator.duration") == pytest.approx(2.0)

        seek(page, 0.0)
        start = canvas_pixels(page)
        assert start.std() > 10 and len(np.unique(start.reshape(-1, 3), axis=0)) > 100  # not blank
        green, orange = robot_colours(start)
        assert green > 500 and orange > 500, (green, orange)  # platform and drives in view

        set_robot_visible(page, False)
        hidden = canvas_pixels(page)
        assert changed_fraction(start, hidden) > 0.02
        hidden_green, hidden_orange = robot_colours(hidden)  # left: the small origin triad
        assert hidden_green < green / 10 and hidden_orange < orange / 10, (hidden_green, hidden_orange)
        set_robot_visible(page, True)

        seek(page, 2.0)
        end = canvas_pixels(page)
        assert changed_fraction(start, end) > 0.01
        seek(page, 0.0)
        assert changed_fraction(start, canvas_pixels(page)) < 0.001  # seeking is deterministic
    finally:
        page.close()
    remote = [u for u in requests if not u.startswith(("file:", "data:", "blob:", "about:"))]
    assert remote == [], remote
    assert requests and requests[0].startswith("file:")


def test_live_viewer_renders_over_loopback_and_closes(browser, robot4):
    requests = []
    page = new_page(browser, requests)
    try:
        with viz.LiveViewer() as viewer:
            viz.draw_robot(viewer.vis, robot4)
            port = viewer.port
            page.goto(viewer.url)
            wait_for_scene(page, viewer.vis.static_html().count(COMMAND))  # same commands as sent
            green, orange = robot_colours(canvas_pixels(page))
            assert green > 500 and orange > 500, (green, orange)
            assert page.evaluate("viewer.connection.readyState") == 1  # websocket open
        # stopped with the browser still connected: the websocket is closed, the port too
        page.wait_for_function("viewer.connection.readyState === 3", timeout=WAIT_MS)
        with socket.socket() as s:
            assert s.connect_ex(("127.0.0.1", port)) != 0
    finally:
        page.close()
    assert requests and all(u.startswith(f"http://127.0.0.1:{port}/") or u.startswith(f"ws://127.0.0.1:{port}")
                            for u in requests), requests


def test_a_resolved_stl_mesh_renders(browser, tmp_path):
    """planar_3rrr whose platform is an STL prism (green, from a package folder): the exported page
    draws it; hiding its node removes the green."""
    from parallel_gpc import ParallelRobot

    visuals = {"platform": ("package://pkg/meshes/plate.stl", (0.16, 0.16, 0.03), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))}
    path, packages = mech.meshed_3rrr(tmp_path, visuals, {"packages/pkg/meshes/plate.stl": mech.prism_stl()})
    robot = ParallelRobot.load(path, package_path=packages)
    (plate,) = [g.name for g in viz.visual_model(robot).geometryObjects if g.meshPath.endswith("plate.stl")]
    q = robot.q_home
    page_path = viz.export_html(tmp_path / "mesh.html", robot, np.array([0.0, 0.1]), np.array([q, q]))
    page = new_page(browser, [])
    try:
        page.goto(page_path.resolve().as_uri())
        page.wait_for_selector("canvas", timeout=WAIT_MS)
        page.wait_for_function(f"window.__handled >= {page_path.read_text(encoding='utf-8').count(COMMAND)}",
                               timeout=WAIT_MS)
        found = page.evaluate(f'viewer.scene_tree.find(["meshcat", "robot", "{plate}", "<object>"]).object.type')
        assert found == "Mesh"
        seek(page, 0.0)
        green, _ = robot_colours(canvas_pixels(page))
        page.evaluate(f'viewer.handle_command({{type: "set_property", path: "/meshcat/robot/{plate}", '
                      'property: "visible", value: false})')
        hidden, _ = robot_colours(canvas_pixels(page))
        assert green > 500 and hidden < green / 10, (green, hidden)
    finally:
        page.close()
