"""meshcat view: loopback-only servers, offline HTML, animation content, CLI view."""

from __future__ import annotations

import http.client
import io
import re
import socket
import threading
import time
import urllib.request
from pathlib import Path as FsPath
from types import SimpleNamespace

import numpy as np
import pinocchio as pin
import psutil
import pytest

from parallel_gpc.limits import Limits
from parallel_gpc import ParallelRobot, load_result, save_result, viz
from parallel_gpc.cli import main as cli_main
from parallel_gpc.errors import InvalidParameterError, ParallelGPCError, ShapeError, ViewerError

from conftest import line_motion

MeshcatPath = viz.meshcat.path.Path

NON_LOOPBACK = ["0.0.0.0", "192.168.1.5", "10.0.0.1", "::", "::1", "example.com", ""]




def listening() -> set[tuple[str, int]]:
    """(address, port) of every TCP socket this process listens on."""
    return {(c.laddr.ip, c.laddr.port) for c in psutil.Process().net_connections(kind="inet")
            if c.status == psutil.CONN_LISTEN}


def port_open(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.settimeout(1.0)
        return s.connect_ex(("127.0.0.1", port)) == 0


def zmq_port(url: str) -> int:
    return int(url.rsplit(":", 1)[1])


# ------------------------------------------------------------------------- live viewer
def test_live_viewer_listens_on_loopback_only():
    before = listening()
    with viz.LiveViewer() as viewer:
        assert viewer.url == f"http://127.0.0.1:{viewer.port}/static/"
        new = listening() - before
        ports = {port for _, port in new}
        assert {viewer.port, zmq_port(viewer.zmq_url)} <= ports
        assert {addr for addr, _ in new} == {"127.0.0.1"}, new
        page = urllib.request.urlopen(viewer.url, timeout=5).read().decode()
        assert "main.min.js" in page and "MeshCat.Viewer" in page
        web, zmq = viewer.port, zmq_port(viewer.zmq_url)
    assert listening() == before
    assert not port_open(web) and not port_open(zmq)
    assert not any(t.name == "parallel-gpc-meshcat" for t in threading.enumerate())
    assert viewer.vis is None


def test_live_viewer_stops_after_keyboard_interrupt():
    before = listening()
    with pytest.raises(KeyboardInterrupt):
        with viz.LiveViewer() as viewer:
            web, zmq = viewer.port, zmq_port(viewer.zmq_url)
            assert port_open(web)
            raise KeyboardInterrupt
    assert listening() == before
    assert not port_open(web) and not port_open(zmq)


@pytest.mark.parametrize("host", NON_LOOPBACK)
def test_non_loopback_bind_address_is_rejected(host):
    for make in (lambda: viz.LiveViewer(host=host), lambda: viz.GalleryServer(".", host=host)):
        with pytest.raises(InvalidParameterError, match=re.escape(repr(host))):
            make()


def test_loopback_aliases_and_ports():
    assert viz.loopback_host("localhost") == "127.0.0.1"
    assert viz.loopback_host("127.0.0.2") == "127.0.0.2"
    for port in (-1, 65536, 1.5, "80", True):
        with pytest.raises(InvalidParameterError, match="port"):
            viz.LiveViewer(port=port)


def test_live_viewer_reports_a_port_in_use():
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        before = listening()
        with pytest.raises(ViewerError, match=f"127.0.0.1:{port}"):
            viz.LiveViewer(port=port).start()
        assert listening() == before


def test_serve_until_interrupt_prints_url_and_stops(robot4):
    seen = {}

    def interrupt(viewer):
        seen["port"], seen["listening"] = viewer.port, listening()
        raise KeyboardInterrupt

    before = listening()
    out = io.StringIO()
    t, qs, poses = line_motion(robot4, n=5)
    viz.serve_until_interrupt(robot4, t, qs, reference=poses, out=out, wait=interrupt)
    assert ("127.0.0.1", seen["port"]) in seen["listening"]
    assert f"http://127.0.0.1:{seen['port']}/static/" in out.getvalue()
    assert "stopped" in out.getvalue()
    assert listening() == before and not port_open(seen["port"])
    with pytest.raises(InvalidParameterError, match="0.0.0.0"):
        viz.serve_until_interrupt(robot4, host="0.0.0.0", wait=interrupt)


# ------------------------------------------------------------------------- scene content
def test_placements_follow_the_legs_and_closures_close(robot4):
    scene = viz.RobotScene(SimpleNamespace(path=MeshcatPath(("meshcat",))), robot4)
    q = robot4.assemble([0.6, 0.4, 0.1])
    T = dict(zip(scene.paths, scene.placements(q)))
    data = robot4.model.createData()
    gdata = scene.geom_model.createData()
    pin.forwardKinematics(robot4.model, data, q)
    pin.updateGeometryPlacements(robot4.model, data, scene.geom_model, gdata)
    for k, g in enumerate(scene.geom_model.geometryObjects):
        # three.js cylinders are along y: the intrinsic fix-up maps y onto the URDF's z axis
        np.testing.assert_allclose(T[f"robot/{g.name}"][:3, 3], gdata.oMg[k].translation, atol=1e-12)
        np.testing.assert_allclose(T[f"robot/{g.name}"][:3, 1], gdata.oMg[k].rotation[:, 2], atol=1e-12)
    for c in robot4.description.closures:  # closed loops: the two closure spheres coincide
        np.testing.assert_allclose(T[f"robot/closures/{c.name}_a"][:3, 3], T[f"robot/closures/{c.name}_b"][:3, 3],
                                   atol=1e-9)
    open_q = q.copy()
    open_q[robot4.drive_idx[0]] += 0.2  # a drive moved without re-assembly: leg 1 opens
    T_open = dict(zip(scene.paths, scene.placements(open_q)))
    gap = np.linalg.norm(T_open["robot/closures/leg_1_a"][:3, 3] - T_open["robot/closures/leg_1_b"][:3, 3])
    assert gap > 0.05
    assert not np.allclose(T_open["robot/distal_1_0"], T["robot/distal_1_0"])  # legs follow q


def test_a_robot_without_visuals_is_drawn_as_a_stick_figure(robot4):
    """The five-bar of docs/your-robot has no <visual>: a sphere on every joint origin, a rod from
    each joint to its child joint and to the closure/output frames on its link (rods keep their
    length as q changes: each lies on one link), the output marked; the planar robot, whose links
    all have visuals, gets only its output marker."""
    robot = ParallelRobot.load(FsPath(__file__).resolve().parents[1] / "docs" / "your-robot" / "fivebar.urdf")
    scene = viz.RobotScene(SimpleNamespace(path=MeshcatPath(("meshcat",))), robot)
    assert scene.geom_model.ngeoms == 0
    joints = list(robot.model.names)[1:]
    assert {f"robot/stick/joint_{n}" for n in joints} | {"robot/output", "robot/closures/close_a",
                                                        "robot/closures/close_b"} <= set(scene.paths)
    rods = [p for p in scene.paths if p.startswith("robot/stick/rod_")]
    assert len(rods) == 2 + 2  # a→e on each leg, e→ee and e→tip2 (closure frames; ee is the output too)
    lengths = []
    for pose in ([0.0, 0.4], [0.03, 0.37]):
        q = robot.assemble(pose)
        T = dict(zip(scene.paths, scene.placements(q)))
        data = robot.model.createData()
        pin.framesForwardKinematics(robot.model, data, q)
        for n in joints:
            np.testing.assert_allclose(T[f"robot/stick/joint_{n}"][:3, 3], data.oMi[robot.model.getJointId(n)].translation,
                                       atol=1e-12)
        np.testing.assert_allclose(T["robot/output"][:3, 3][[0, 2]], pose, atol=1e-9)
        ends = scene.stick.ends(data)
        for path, (a, b) in zip(rods, ends):  # the cylinder's axis (y) runs from a to b
            np.testing.assert_allclose(T[path][:3, 3], (a + b) / 2, atol=1e-12)
            np.testing.assert_allclose(T[path][:3, 1] * np.linalg.norm(b - a), b - a, atol=1e-12)
        lengths.append([np.linalg.norm(b - a) for a, b in ends])
    np.testing.assert_allclose(lengths[0], lengths[1], atol=1e-12)
    planar = viz.RobotScene(SimpleNamespace(path=MeshcatPath(("meshcat",))), robot4)
    assert [p for p in planar.paths if p.startswith("robot/stick") or p == "robot/output"] == ["robot/output"]


def test_animation_keyframes_match_configurations(robot4):
    vis = SimpleNamespace(path=MeshcatPath(("meshcat",)))
    scene = viz.RobotScene(vis, robot4)
    t, qs, _ = line_motion(robot4, n=41)
    saturated = np.zeros((t.size, robot4.n_u), dtype=bool)
    saturated[10:20, 2] = True
    fps = 10.0
    anim = scene.animation(t, qs, saturated, fps=fps, max_frames=300)
    idx = viz.frame_indices(t, fps, 300)
    assert idx.tolist() == list(range(0, 41, 2))  # 2 s at 10 fps: 21 key frames
    clip = anim.clips[MeshcatPath(("meshcat", "robot", "distal_3_0"))]
    position = clip.tracks["position"]
    np.testing.assert_allclose(position.frames, (t[idx] - t[0]) * fps)
    expected = [scene.placements(qs[k])[scene.paths.index("robot/distal_3_0")][:3, 3] for k in idx]
    np.testing.assert_allclose(position.values, expected, atol=1e-12)
    visible = anim.clips[MeshcatPath(("meshcat", "robot", "saturation", "drive_3"))].tracks["visible"]
    assert visible.values == saturated[idx, 2].tolist() and any(visible.values)
    lowered = anim.lower()
    assert len(lowered) == len(scene.paths) + robot4.n_u


def test_frame_indices_are_bounded_and_keep_the_ends():
    t = np.linspace(0.0, 10.0, 1001)
    idx = viz.frame_indices(t, fps=30.0, max_frames=300)
    assert len(idx) == 300 and idx[0] == 0 and idx[-1] == 1000
    assert viz.frame_indices(t[:5], fps=30.0).tolist() == [0, 4]  # 0.04 s at 30 fps: the two ends
    assert viz.frame_indices(np.arange(5.0), fps=30.0).tolist() == [0, 1, 2, 3, 4]  # never more than K
    assert viz.frame_indices(np.array([0.0]), fps=30.0).tolist() == [0]
    with pytest.raises(InvalidParameterError, match="increasing"):
        viz.frame_indices(np.array([0.0, 1.0, 1.0]), fps=30.0)


def test_animate_checks_shapes(robot4):
    vis = SimpleNamespace(path=MeshcatPath(("meshcat",)))
    scene = viz.RobotScene(vis, robot4)
    t, qs, _ = line_motion(robot4, n=5)
    with pytest.raises(ShapeError, match=rf"expected \(5, {robot4.model.nq}\)"):
        scene.animation(t, qs[:, :-1])
    with pytest.raises(ShapeError, match="saturated"):
        scene.animation(t, qs, np.zeros((5, 3), dtype=bool))
    with pytest.raises(ShapeError, match="reference path"):
        viz.draw_path(vis, "reference", np.zeros((5, 1)), viz.REFERENCE_COLOR)


def test_saturation_flags():
    u = np.array([[10.0, -60.0], [59.0, 60.0]])
    assert viz.saturation_flags(u, Limits(torque=60.0)).tolist() == [[False, True], [False, True]]
    assert viz.saturation_flags(u, Limits(torque=[70.0, 60.0])).tolist() == [[False, True], [False, True]]
    assert viz.saturation_flags(u, Limits()) is None  # no torque limit: nothing to flag


# ------------------------------------------------------------------------- offline HTML
def test_export_html_is_self_contained(robot4, tmp_path):
    t, qs, poses = line_motion(robot4, n=21)
    before = listening()
    out = viz.export_html(tmp_path / "motion.html", robot4, t, qs, reference=poses, planned=poses,
                          saturated=np.zeros((t.size, robot4.n_u), bool), title="line <A to B>")
    assert listening() == before  # the private viewer is stopped
    page = out.read_text(encoding="utf-8")
    bundle = (FsPath(viz.VIEWER_ROOT) / "main.min.js").read_text()
    assert bundle[:2000] in page and bundle[-2000:] in page  # viewer inlined
    assert "new MeshCat.Viewer" in page and "<title>line &lt;A to B&gt;</title>" in page
    assert not re.search(r"<script[^>]*\bsrc\s*=", page, re.IGNORECASE)
    assert viz.network_references(page) == []
    # the only absolute URLs are the XHTML namespace string and the same-origin websocket
    # template of viewer.connect() (never called by the static page) inside the bundle
    urls = set(re.findall(r"(?:https?|wss?)://[^\s\"'<>)\\]+", page))
    assert urls <= {"http://www.w3.org/1999/xhtml", "ws://${location.host}`"}, urls
    assert page.count("fetch(\"data:application/octet-binary;base64,") > 10  # the scene commands


def test_network_references_detects_remote_loads():
    for snippet in ('<script src="https://cdn.example/x.js"></script>', "<link href='//cdn.example/a.css'>",
                    'fetch("http://example.com/scene")', "new WebSocket('ws://example.com')",
                    "<style>@import url(https://x/y.css)</style>"):
        assert viz.network_references(snippet), snippet
    assert viz.network_references('<a id="x">"http://www.w3.org/1999/xhtml"</a>') == []


# ------------------------------------------------------------------------- gallery
def test_gallery_binds_loopback_and_lists_pages(robot4, tmp_path):
    t, qs, _ = line_motion(robot4, n=5)
    viz.export_html(tmp_path / "a.html", robot4, t, qs, title="Run A")
    before = listening()
    with viz.GalleryServer(tmp_path) as gallery:
        new = listening() - before
        assert new == {("127.0.0.1", gallery.port)}
        index = urllib.request.urlopen(gallery.url, timeout=5).read().decode()
        assert 'href="a.html"' in index and "Run A" in index
        page = urllib.request.urlopen(gallery.url + "a.html", timeout=5).read().decode()
        assert "new MeshCat.Viewer" in page
        port = gallery.port
    assert listening() == before and not port_open(port)


def test_serve_gallery_stops_on_keyboard_interrupt(tmp_path):
    seen = {}

    def interrupt(server):
        seen["port"] = server.port
        assert port_open(server.port)
        raise KeyboardInterrupt

    out = io.StringIO()
    viz.serve_gallery(tmp_path, out=out, wait=interrupt)
    assert f"http://127.0.0.1:{seen['port']}/" in out.getvalue()
    assert not port_open(seen["port"])
    with pytest.raises(InvalidParameterError, match="does not exist"):
        viz.GalleryServer(tmp_path / "missing")


# ------------------------------------------------------------------------- Host header, idle timeout
def request(port: int, path: str, host: str | None, headers=()) -> tuple[int, bytes]:
    """GET ``path`` from 127.0.0.1:port with this exact Host header (None: none sent)."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    try:
        conn.putrequest("GET", path, skip_host=True, skip_accept_encoding=True)
        if host is not None:
            conn.putheader("Host", host)
        for name, value in headers:
            conn.putheader(name, value)
        conn.endheaders()
        response = conn.getresponse()
        return response.status, response.read()
    finally:
        conn.close()


def refused_hosts(port: int) -> list[str | None]:
    return [f"evil.example:{port}", "evil.example", f"127.0.0.1.evil.example:{port}", f"127.0.0.1:{port + 1}",
            f"0.0.0.0:{port}", f"192.168.1.5:{port}", "127.0.0.1", "", None]


def refused(answer: tuple[int, bytes], host: str | None) -> bool:
    """403 and no content (a missing Host header: Tornado's own 400 Bad Request, no content, also counts)."""
    return answer[1] == b"" and (answer[0] == 403 or (host is None and answer[0] == 400))


def loopback_hosts(port: int) -> list[str]:
    return [f"127.0.0.1:{port}", f"localhost:{port}", f"LocalHost:{port}", f"127.0.0.2:{port}", f"[::1]:{port}"]


def test_loopback_host_header():
    for value in loopback_hosts(8000) + ["localhost", "127.0.0.1", "[::1]"]:
        assert viz.loopback_host_header(value, 8000 if value.endswith("8000") else 80), value
    for value in refused_hosts(8000) + ["::1:8000", "127.1:8000", "0x7f000001:8000", "127.0.0.1:+8000",
                                        "127.0.0.1:８０００", "localhost:80"]:
        assert not viz.loopback_host_header(value, 8000), value
    for bad in (0, -1.0, float("nan"), float("inf"), "30", True, None):
        with pytest.raises(InvalidParameterError, match="idle timeout"):
            viz.GalleryServer(".", idle_timeout=bad)
        with pytest.raises(InvalidParameterError, match="idle timeout"):
            viz.LiveViewer(idle_timeout=bad)


def test_gallery_answers_loopback_host_names_only(robot4, tmp_path):
    """DNS rebinding: ``Host: evil.example:PORT`` with a matching Origin gets 403 and no content."""
    t, qs, _ = line_motion(robot4, n=3)
    viz.export_html(tmp_path / "a.html", robot4, t, qs, title="Run A")
    with viz.GalleryServer(tmp_path) as gallery:
        port = gallery.port
        for host in refused_hosts(port):
            for path in ("/", "/a.html"):
                assert refused(request(port, path, host, [("Origin", f"http://{host}")]), host), (host, path)
        for host in loopback_hosts(port):
            status, body = request(port, "/a.html", host)
            assert status == 200 and b"new MeshCat.Viewer" in body, host
        assert b"Run A" in request(port, "/", f"localhost:{port}")[1]


def test_live_viewer_answers_loopback_host_names_only():
    with viz.LiveViewer() as viewer:
        port = viewer.port
        for host in refused_hosts(port):
            assert refused(request(port, "/static/", host, [("Origin", f"http://{host}")]), host), host
            upgrade = [("Origin", f"http://{host}"), ("Connection", "Upgrade"), ("Upgrade", "websocket"),
                       ("Sec-WebSocket-Version", "13"), ("Sec-WebSocket-Key", "dGhlIHNhbXBsZSBub25jZQ==")]
            assert refused(request(port, "/", host, upgrade), host), host  # no scene over a websocket
        for host in loopback_hosts(port):
            status, body = request(port, "/static/", host)
            assert status == 200 and b"MeshCat.Viewer" in body, host
        upgrade = [("Connection", "Upgrade"), ("Upgrade", "websocket"), ("Sec-WebSocket-Version", "13"),
                   ("Sec-WebSocket-Key", "dGhlIHNhbXBsZSBub25jZQ==")]
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
        conn.putrequest("GET", "/", skip_host=True, skip_accept_encoding=True)
        conn.putheader("Host", f"127.0.0.1:{port}")
        for name, value in upgrade:
            conn.putheader(name, value)
        conn.endheaders()
        assert conn.getresponse().status == 101  # the loopback websocket is accepted
        conn.close()


def closed_after(port: int, limit: float) -> float | None:
    """Connect, send nothing, and return the seconds until the server closes (None: not in ``limit``)."""
    with socket.create_connection(("127.0.0.1", port), timeout=limit) as client:
        t0 = time.monotonic()
        try:
            data = client.recv(1024)
        except (TimeoutError, socket.timeout):
            return None
        except ConnectionResetError:
            data = b""
        return time.monotonic() - t0 if data == b"" else None


def test_servers_close_idle_connections(tmp_path):
    with viz.GalleryServer(tmp_path, idle_timeout=0.5) as gallery:
        waited = closed_after(gallery.port, 10.0)
        assert waited is not None and 0.3 <= waited < 10.0
        assert request(gallery.port, "/", f"127.0.0.1:{gallery.port}")[0] == 200  # still serving
    with viz.LiveViewer(idle_timeout=0.5) as viewer:
        waited = closed_after(viewer.port, 10.0)
        assert waited is not None and 0.3 <= waited < 10.0
        assert request(viewer.port, "/static/", f"127.0.0.1:{viewer.port}")[0] == 200


# ------------------------------------------------------------------------- files and CLI
def test_trajectory_roundtrip_and_cli_view(robot4, tmp_path, capsys):
    t, qs, poses = line_motion(robot4, n=9)
    sat = np.zeros((t.size, robot4.n_u), bool)
    npz = save_result(tmp_path / "run.npz", robot4, t, qs, reference=poses, saturated=sat)
    loaded = load_result(npz)
    assert loaded.robot == "planar_4rrr"
    np.testing.assert_array_equal(loaded.q, qs)
    np.testing.assert_array_equal(loaded.reference, poses)
    assert loaded.planned is None and loaded.saturated.dtype == bool

    assert cli_main(["view", str(npz), "--html", str(tmp_path / "out" / "run.html")]) == 0
    assert (tmp_path / "out" / "run.html").stat().st_size > 500_000
    assert cli_main(["view", str(npz)]) == 0  # default: RESULT.html next to the file
    assert (tmp_path / "run.html").exists()

    np.savez(tmp_path / "bad.npz", t=t, q=qs)
    assert cli_main(["view", str(tmp_path / "bad.npz")]) == 2
    assert "lacks the keys ['robot']" in capsys.readouterr().err
    with pytest.raises(ParallelGPCError, match="does not exist"):
        load_result(tmp_path / "none.npz")
