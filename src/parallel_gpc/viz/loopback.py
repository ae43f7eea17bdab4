"""Loopback-only networking shared by the live viewer and the gallery (no meshcat import).

Binding 127.0.0.1 keeps other machines out, but not a web page in the user's browser: with DNS
rebinding, ``evil.example`` first resolves to the attacker and then to 127.0.0.1, and the page's
requests reach our server with ``Host: evil.example:PORT`` (and a matching ``Origin``). Our
servers therefore answer only requests whose ``Host`` header names the loopback interface
(:func:`loopback_host_header`) and refuse the others with 403 and no content. Idle connections
are closed after :data:`IDLE_TIMEOUT_S` so that a client that connects and sends nothing cannot
hold a server thread.
"""

from __future__ import annotations

import ipaddress
import math
import time

import numpy as np

from ..errors import InvalidParameterError

#: The only address our servers bind by default.
LOOPBACK = "127.0.0.1"
#: Seconds a server may take to start or stop.
START_TIMEOUT_S = 10.0
#: Seconds a connection may stay idle (no request, or a request not finished) before it is closed.
IDLE_TIMEOUT_S = 30.0


def loopback_host(host: str) -> str:
    """Return ``host`` as an IPv4 loopback address (``"localhost"`` becomes 127.0.0.1).

    Raises:
        InvalidParameterError: if ``host`` is not an IPv4 loopback address (127.0.0.0/8).
    """
    name = str(host).strip()
    if name.lower() == "localhost":
        return LOOPBACK
    try:
        addr = ipaddress.ip_address(name)
    except ValueError:
        addr = None
    if addr is None or addr.version != 4 or not addr.is_loopback:
        raise InvalidParameterError(
            f"bind address {host!r} is not an IPv4 loopback address; the viewer and gallery "
            f"serve on the loopback interface only (use {LOOPBACK} or localhost)"
        )
    return str(addr)


def loopback_host_header(value: str | None, port: int) -> bool:
    """True when an HTTP ``Host`` header names this loopback server: ``localhost``, an IPv4
    loopback address (127.0.0.0/8) or ``[::1]``, followed by ``:port`` (or no port when ``port``
    is 80). A missing header, any other name and any other port are refused.

    Args:
        value: the ``Host`` header (None when absent).
        port: the port the server listens on.
    """
    value = (value or "").strip().lower()
    name, given = value, "80"  # no port: the default HTTP port
    if not value.endswith("]") and ":" in value:  # name:port ("[::1]" alone has colons, no port)
        name, given = value.rsplit(":", 1)
    if not (given.isascii() and given.isdigit()) or int(given) != port:
        return False
    if name == "localhost" or name == "[::1]":
        return True
    try:
        addr = ipaddress.ip_address(name)
    except ValueError:
        return False
    return addr.version == 4 and addr.is_loopback


def check_idle_timeout(seconds) -> float:
    """The idle-connection timeout in s (finite, > 0).

    Raises:
        InvalidParameterError: not a positive finite number.
    """
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float, np.integer, np.floating)) \
            or not math.isfinite(seconds) or seconds <= 0:
        raise InvalidParameterError(f"idle timeout {seconds!r} must be a positive finite number of seconds")
    return float(seconds)


def check_port(port) -> int:
    if isinstance(port, bool) or not isinstance(port, (int, np.integer)) or not 0 <= int(port) <= 65535:
        raise InvalidParameterError(f"port {port!r} must be an integer in [0, 65535] (0: any free port)")
    return int(port)


def wait_forever(_server) -> None:
    """Block until Ctrl-C (KeyboardInterrupt); the default ``wait`` of the serving functions."""
    while True:
        time.sleep(0.5)


def wait_until_interrupt(server, message: str, out, wait=wait_forever) -> None:
    """Print ``message`` (the URL) to ``out``, then block in ``wait(server)`` until Ctrl-C. The print is inside
    the guarded block: a Ctrl-C sent as soon as the URL is read may land before ``print`` has returned (seen once
    under load: the gallery then exited 130 through the command line's interrupt path instead of stopping)."""
    try:
        print(f"{message}  (Ctrl-C to stop)", file=out, flush=True)
        wait(server)
    except KeyboardInterrupt:
        pass
