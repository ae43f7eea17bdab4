"""Gallery: serve a folder of exported animations on 127.0.0.1 with a generated index page.

No meshcat, no Pinocchio: ``parallel-gpc gallery`` works with the lean install.
"""

from __future__ import annotations

import html
import re
import sys
import threading
import urllib.parse
from functools import partial
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

from ..errors import InvalidParameterError, ViewerError
from .loopback import (IDLE_TIMEOUT_S, LOOPBACK, START_TIMEOUT_S, check_idle_timeout, check_port, loopback_host,
                       loopback_host_header, wait_forever, wait_until_interrupt)


def _page_title(path: Path) -> str:
    with open(path, encoding="utf-8", errors="replace") as f:
        head = f.read(4096)
    match = re.search(r"<title>(.*?)</title>", head, re.IGNORECASE | re.DOTALL)
    return html.unescape(match.group(1).strip()) if match else path.stem


def servable(directory, url_path: str) -> bool:
    """True if ``url_path`` (decoded, e.g. ``/motion.html``) names a regular file inside
    ``directory`` after resolving symlinks, with no dot-file or dot-folder component."""
    parts = [p for p in url_path.split("/") if p]
    if not parts or any(p.startswith(".") or "\\" in p for p in parts):
        return False
    root = Path(directory).resolve()
    target = root.joinpath(*parts).resolve()
    return target.is_relative_to(root) and target.is_file()


def gallery_index(directory) -> str:
    """HTML index page linking every ``*.html`` file of ``directory`` (except index.html)."""
    directory = Path(directory)
    pages = sorted(p for p in directory.glob("*.html") if p.name != "index.html" and servable(directory, "/" + p.name))
    items = "\n".join(
        f'<li><a href="{html.escape(p.name, quote=True)}">{html.escape(_page_title(p))}</a> '
        f"<small>({html.escape(p.name)})</small></li>" for p in pages
    ) or "<li>no exported animations (*.html) in this folder yet</li>"
    return (
        "<!DOCTYPE html>\n<html><head><meta charset=utf-8><title>parallel-gpc gallery</title></head>\n"
        "<body style=\"font:14px sans-serif;margin:2em\"><h1>parallel-gpc animations</h1>\n"
        f"<p>{html.escape(str(directory.resolve()))}</p>\n<ul>\n{items}\n</ul></body></html>\n"
    )


class _GalleryHandler(SimpleHTTPRequestHandler):
    """Files of one folder, with a generated index at ``/``.

    Served: regular files whose real path (symlinks resolved) lies inside the folder and whose
    URL has no component starting with a dot. Everything else (dotfiles, folder listings,
    symlinks leading out of the folder) is answered 404 Not Found. A request whose ``Host``
    header does not name this loopback server (DNS rebinding) is answered 403 with no content.
    The connection's socket times out after the server's ``idle_timeout`` (s).
    """

    def setup(self):
        self.timeout = self.server.idle_timeout  # applied to the socket by StreamRequestHandler.setup
        super().setup()

    def do_GET(self):  # noqa: N802 — http.server naming
        if self._route():
            super().do_GET()

    def do_HEAD(self):  # noqa: N802 — http.server naming
        if self._route():
            super().do_HEAD()

    def _route(self) -> bool:
        """Answer ``/`` and refused paths here; True when the default file handler may serve."""
        if not loopback_host_header(self.headers.get("Host"), self.server.server_address[1]):
            self.close_connection = True
            self.send_response(403)
            self.send_header("Content-Length", "0")
            self.send_header("Connection", "close")
            self.end_headers()
            return False
        url_path = urllib.parse.unquote(self.path.split("?", 1)[0].split("#", 1)[0])
        if url_path == "/":
            body = gallery_index(self.directory).encode("utf-8")
            self.send_response(200)
            self.send_header("Content-Type", "text/html; charset=utf-8")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            if self.command != "HEAD":
                self.wfile.write(body)
            return False
        if not servable(self.directory, url_path):
            self.send_error(404, "File not found")
            return False
        return True

    def list_directory(self, path):  # never list a folder
        self.send_error(404, "File not found")
        return None

    def log_message(self, format, *args):  # noqa: A002 — http.server signature
        pass


class _GalleryHTTPServer(ThreadingHTTPServer):
    """A threading HTTP server with an idle-connection timeout; a client that times out or
    disconnects mid-answer is dropped quietly (no traceback on stderr)."""

    daemon_threads = True

    def __init__(self, address, handler, idle_timeout: float):
        self.idle_timeout = idle_timeout
        super().__init__(address, handler)

    def handle_error(self, request, client_address):
        if not isinstance(sys.exc_info()[1], (TimeoutError, ConnectionError)):
            super().handle_error(request, client_address)


class GalleryServer:
    """Serve a folder of exported pages on a loopback address, as a context manager.

    Args:
        directory: folder holding the ``*.html`` files.
        host: bind address; must be IPv4 loopback (default 127.0.0.1).
        port: port (0: any free port).
        idle_timeout: seconds a connection may stay idle before it is closed (default 30).

    Attributes:
        url: ``http://127.0.0.1:<port>/`` (the generated index).
        server: the ``http.server.ThreadingHTTPServer`` (None when stopped).

    Raises:
        InvalidParameterError: bad host, port or idle timeout, or ``directory`` is not a folder.
    """

    def __init__(self, directory, host: str = LOOPBACK, port: int = 0, idle_timeout: float = IDLE_TIMEOUT_S):
        self.directory = Path(directory)
        if not self.directory.is_dir():
            what = "is not a folder" if self.directory.exists() else "does not exist"
            raise InvalidParameterError(f"gallery folder {str(directory)!r} {what}")
        self.host = loopback_host(host)
        self.requested_port = check_port(port)
        self.idle_timeout = check_idle_timeout(idle_timeout)
        self.server: ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None

    @property
    def port(self) -> int:
        if self.server is None:
            raise ViewerError("the gallery server is not running")
        return int(self.server.server_address[1])

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/"

    def start(self) -> "GalleryServer":
        """Bind and serve in a daemon thread.

        Raises:
            ViewerError: if the address cannot be bound (e.g. port in use).
        """
        handler = partial(_GalleryHandler, directory=str(self.directory))
        try:
            self.server = _GalleryHTTPServer((self.host, self.requested_port), handler, self.idle_timeout)
        except OSError as exc:
            raise ViewerError(f"cannot serve the gallery on {self.host}:{self.requested_port}: {exc}") from exc
        self._thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.1},
                                        name="parallel-gpc-gallery", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close the socket (idempotent)."""
        server, self.server = self.server, None
        if server is None:
            return
        server.shutdown()
        server.server_close()
        self._thread.join(START_TIMEOUT_S)

    def __enter__(self) -> "GalleryServer":
        return self.start()

    def __exit__(self, exc_type, exc, tb) -> bool:
        self.stop()
        return False


def serve_gallery(directory, port: int = 0, host: str = LOOPBACK, out=None, wait=wait_forever) -> None:
    """Serve ``directory``'s exported pages on 127.0.0.1 until Ctrl-C (prints the URL).

    Args:
        directory: folder of ``*.html`` animations. port: 0 for any free port.
        host: loopback bind address. out: stream for messages (default stdout).
        wait: blocks while serving; gets the :class:`GalleryServer` (default: until Ctrl-C).
    """
    out = sys.stdout if out is None else out
    with GalleryServer(directory, host, port) as server:
        wait_until_interrupt(server, f"gallery of {server.directory.resolve()}: {server.url}", out, wait)
    print("gallery stopped", file=out, flush=True)
