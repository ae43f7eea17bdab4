"""Live meshcat viewer on a loopback address: the meshcat bridge in a thread of this process.

meshcat 0.3.2's ``meshcat.Visualizer()`` starts a server that listens on all interfaces
(0.0.0.0). :class:`LiveViewer` instead runs the meshcat bridge in a thread of this process with
its web and ZeroMQ sockets bound to a loopback address only, and stops it on exit (also on
KeyboardInterrupt). Its web server answers only requests whose ``Host`` header names it (403
with no content otherwise: DNS rebinding, see :mod:`parallel_gpc.viz.loopback`) and closes idle
HTTP connections and unresponsive websocket clients after its idle timeout.
"""

from __future__ import annotations

import asyncio
import socket
import sys
import threading
import time

import tornado.httpserver
import tornado.ioloop
import tornado.netutil
import tornado.web
import tornado.websocket
import zmq

from ..errors import ViewerError
from ..model import ParallelRobot
from ._meshcat import (
    VIEWER_HTML,
    VIEWER_ROOT,
    SceneTree,
    StaticFileHandlerNoCache,
    ViewerWindow,
    WebSocketHandler,
    ZMQWebSocketBridge,
    meshcat,
)
from .loopback import (IDLE_TIMEOUT_S, LOOPBACK, START_TIMEOUT_S, check_idle_timeout, check_port, loopback_host,
                       loopback_host_header, wait_forever, wait_until_interrupt)
from .scene import animate, draw_robot

_ZMQ_TIMEOUT_MS = 60_000


class _LoopbackOnly:
    """Tornado handler mixin: a request whose ``Host`` header does not name this loopback server
    is answered 403 with no content (the handler's method never runs)."""

    def prepare(self):
        if not loopback_host_header(self.request.headers.get("Host"), self.application.settings["server_port"]):
            self.set_status(403)
            self.finish()


class _LoopbackStaticFileHandler(_LoopbackOnly, StaticFileHandlerNoCache):
    """meshcat's viewer files, to loopback Host names only."""


class _QuietWebSocketHandler(_LoopbackOnly, WebSocketHandler):
    """meshcat's websocket handler without its prints to stderr, to loopback Host names only."""

    def open(self):
        self.bridge.websocket_pool.add(self)
        self.bridge.send_scene(self)

    def on_close(self):
        self.bridge.websocket_pool.discard(self)

    def write_message(self, message, binary=False):
        """Send, or drop the client quietly if it has gone (a browser tab closed mid-send)."""
        try:
            future = super().write_message(message, binary=binary)
        except tornado.websocket.WebSocketClosedError:
            self.bridge.websocket_pool.discard(self)
            return None
        future.add_done_callback(_consume)
        return future


def _consume(future) -> None:
    """Retrieve a send's outcome: a client that disconnected early is not an error to log."""
    if not future.cancelled():
        future.exception()


class _LoopbackBridge(ZMQWebSocketBridge):
    """meshcat's ZeroMQ/websocket bridge with its web server bound to ``host`` only.

    The stock bridge calls ``app.listen(port)``, which listens on every interface. Must be
    constructed inside a running asyncio loop (the thread's loop).
    """

    def __init__(self, host: str, port: int, idle_timeout: float):  # noqa: D107 — replaces the parent's set-up
        self.host = host
        self.idle_timeout = idle_timeout
        self.websocket_pool = set()
        self.tree = SceneTree()
        self.app = self.make_app()
        self.ioloop = tornado.ioloop.IOLoop.current()
        # web sockets first: if the port is taken, nothing is bound yet (libzmq would release
        # its listener only asynchronously)
        self.sockets = tornado.netutil.bind_sockets(port, address=host, family=socket.AF_INET)
        try:
            self.zmq_socket, self.zmq_stream, _ = self.setup_zmq(f"tcp://{host}:*")
        except zmq.ZMQError:
            for sock in self.sockets:
                sock.close()
            raise
        self.zmq_url = self.zmq_socket.getsockopt_string(zmq.LAST_ENDPOINT)
        self.http_server = tornado.httpserver.HTTPServer(self.app, idle_connection_timeout=idle_timeout,
                                                         body_timeout=idle_timeout)
        self.http_server.add_sockets(self.sockets)
        self.fileserver_port = self.sockets[0].getsockname()[1]
        self.app.settings["server_port"] = self.fileserver_port
        self.web_url = f"http://{host}:{self.fileserver_port}/static/"

    def make_app(self):
        return tornado.web.Application([
            (r"/static/(.*)", _LoopbackStaticFileHandler, {"path": VIEWER_ROOT, "default_filename": VIEWER_HTML}),
            (r"/", _QuietWebSocketHandler, {"bridge": self}),
        ], log_function=lambda handler: None, websocket_ping_interval=self.idle_timeout,
            websocket_ping_timeout=self.idle_timeout)

    def forward_to_websockets(self, frames):
        """Send one scene command to every client (a copy of the pool: clients may leave meanwhile)."""
        _, _, data = frames
        for websocket in list(self.websocket_pool):
            websocket.write_message(data, binary=True)

    async def shutdown(self) -> None:
        """Stop listening, close browser connections and the ZeroMQ socket."""
        self.http_server.stop()
        for ws in list(self.websocket_pool):
            ws.close(1001, "server stopping")
        for _ in range(20):
            if not self.websocket_pool:
                break
            await asyncio.sleep(0.025)
        for ws in list(self.websocket_pool):
            stream = getattr(ws.ws_connection, "stream", None)
            if stream is not None:
                stream.close()
        await self.http_server.close_all_connections()
        self.zmq_stream.close(linger=0)
        await _released(self.host, zmq_port_of(self.zmq_url))


def zmq_port_of(url: str) -> int:
    """Port of a ``tcp://host:port`` ZeroMQ endpoint."""
    return int(url.rsplit(":", 1)[1])


async def _released(host: str, port: int, timeout: float = 2.0) -> None:
    """Wait until nothing listens on (host, port): libzmq closes its listener in its I/O thread,
    after ``close()`` returns."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # ignore TIME_WAIT leftovers
            try:
                probe.bind((host, port))
                return
            except OSError:
                pass
        await asyncio.sleep(0.01)


class _Window(ViewerWindow):
    """A meshcat client window on an existing server (no subprocess, no print, closable)."""

    def __init__(self, zmq_url: str, web_url: str):  # noqa: D107 — replaces the parent's set-up
        self.server_proc = None
        self.zmq_url = zmq_url
        self.web_url = web_url
        self.connect_zmq()
        self.zmq_socket.setsockopt(zmq.RCVTIMEO, _ZMQ_TIMEOUT_MS)
        self.zmq_socket.setsockopt(zmq.SNDTIMEO, _ZMQ_TIMEOUT_MS)

    def close(self) -> None:
        self.zmq_socket.close(linger=0)


class LiveViewer:
    """Our own meshcat server on a loopback address, as a context manager.

    >>> with LiveViewer() as viewer:          # doctest: +SKIP
    ...     draw_robot(viewer.vis, robot)
    ...     print(viewer.url)

    Args:
        host: bind address; must be IPv4 loopback (default 127.0.0.1).
        port: web server port (0: any free port). The ZeroMQ command port is always a free one.
        idle_timeout: seconds an HTTP connection may stay idle, and a websocket client may leave
            a ping unanswered, before it is closed (default 30).

    Attributes:
        vis: the ``meshcat.Visualizer`` talking to this server (None when stopped).
        url: the viewer page, ``http://127.0.0.1:<port>/static/``.
        port: the bound web server port.
        zmq_url: the bound ZeroMQ endpoint (``tcp://127.0.0.1:<port>``).

    Raises:
        InvalidParameterError: if ``host`` is not a loopback address, ``port`` is out of range or
            ``idle_timeout`` is not a positive number.
    """

    def __init__(self, host: str = LOOPBACK, port: int = 0, idle_timeout: float = IDLE_TIMEOUT_S):
        self.host = loopback_host(host)
        self.requested_port = check_port(port)
        self.idle_timeout = check_idle_timeout(idle_timeout)
        self.vis: meshcat.Visualizer | None = None
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop_event: asyncio.Event | None = None
        self._bridge: _LoopbackBridge | None = None
        self._error: BaseException | None = None

    @property
    def url(self) -> str:
        return self._require_bridge().web_url

    @property
    def port(self) -> int:
        return int(self._require_bridge().fileserver_port)

    @property
    def zmq_url(self) -> str:
        return self._require_bridge().zmq_url

    def _require_bridge(self) -> _LoopbackBridge:
        if self._bridge is None:
            raise ViewerError("the live viewer is not running; use it as a context manager or call start()")
        return self._bridge

    def start(self) -> "LiveViewer":
        """Start the server thread and connect :attr:`vis`.

        Raises:
            ViewerError: if the server cannot bind its sockets or does not start in 10 s.
        """
        if self._thread is not None:
            raise ViewerError("the live viewer is already running")
        ready = threading.Event()
        self._error = None
        self._thread = threading.Thread(target=self._run, args=(ready,), name="parallel-gpc-meshcat", daemon=True)
        self._thread.start()
        if not ready.wait(START_TIMEOUT_S) or self._error is not None:
            error = self._error
            self.stop()
            raise ViewerError(
                f"cannot start the meshcat server on {self.host}:{self.requested_port}: "
                f"{error or 'no answer within 10 s'}"
            ) from error
        self.vis = meshcat.Visualizer(window=_Window(self._bridge.zmq_url, self._bridge.web_url))
        return self

    def _run(self, ready: threading.Event) -> None:
        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(self._serve(ready))
        finally:
            loop.run_until_complete(loop.shutdown_asyncgens())
            loop.close()
            ready.set()

    async def _serve(self, ready: threading.Event) -> None:
        try:
            bridge = _LoopbackBridge(self.host, self.requested_port, self.idle_timeout)
        except (OSError, zmq.ZMQError) as exc:
            self._error = exc
            return
        self._stop_event = asyncio.Event()
        self._loop = asyncio.get_running_loop()
        self._bridge = bridge
        ready.set()
        try:
            await self._stop_event.wait()
        finally:
            await bridge.shutdown()

    def stop(self) -> None:
        """Disconnect :attr:`vis`, stop the server and wait for its thread (idempotent)."""
        if self.vis is not None:
            self.vis.window.close()
            self.vis = None
        thread, self._thread = self._thread, None
        if thread is None:
            return
        if self._loop is not None:
            try:
                self._loop.call_soon_threadsafe(self._stop_event.set)
            except RuntimeError:  # the loop already ended
                pass
        thread.join(START_TIMEOUT_S)
        self._loop = self._stop_event = self._bridge = None
        if thread.is_alive():
            raise ViewerError("the meshcat server thread did not stop within 10 s")

    def __enter__(self) -> "LiveViewer":
        return self.start()

    def __exit__(self, exc_type, exc, tb) -> bool:
        self.stop()
        return False

    def __repr__(self) -> str:
        state = f"url={self._bridge.web_url!r}" if self._bridge is not None else "stopped"
        return f"LiveViewer(host={self.host!r}, {state})"


def serve_until_interrupt(robot: ParallelRobot, t=None, qs=None, *, reference=None, planned=None,
                          saturated=None, host: str = LOOPBACK, port: int = 0, out=None,
                          wait=wait_forever) -> None:
    """Show a trajectory (or the home pose) in a live viewer until Ctrl-C, then stop cleanly.

    Args:
        robot: the robot. t, qs, reference, planned, saturated: as in :func:`animate`; without
            ``qs`` the robot is drawn at home.
        host, port: loopback bind address and web port (0: any free port).
        out: stream for the URL message (default stdout).
        wait: blocks while serving; gets the :class:`LiveViewer` (default: sleep until Ctrl-C).
    """
    out = sys.stdout if out is None else out
    with LiveViewer(host, port) as viewer:
        if qs is None:
            draw_robot(viewer.vis, robot)
        else:
            animate(viewer.vis, robot, t, qs, saturated=saturated, reference=reference, planned=planned)
        wait_until_interrupt(viewer, f"meshcat viewer: {viewer.url}", out, wait)
    print("viewer stopped", file=out, flush=True)
