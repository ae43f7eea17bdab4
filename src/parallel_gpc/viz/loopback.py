"""Loopback-only networking shared by the live viewer and the gallery (no meshcat import)."""

from __future__ import annotations

import ipaddress
import time

import numpy as np

from ..errors import InvalidParameterError

#: The only address our servers bind by default.
LOOPBACK = "127.0.0.1"
#: Seconds a server may take to start or stop.
START_TIMEOUT_S = 10.0


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


def check_port(port) -> int:
    if isinstance(port, bool) or not isinstance(port, (int, np.integer)) or not 0 <= int(port) <= 65535:
        raise InvalidParameterError(f"port {port!r} must be an integer in [0, 65535] (0: any free port)")
    return int(port)


def wait_forever(_server) -> None:
    """Block until Ctrl-C (KeyboardInterrupt); the default ``wait`` of the serving functions."""
    while True:
        time.sleep(0.5)


def wait_until_interrupt(server, message: str, out, wait=wait_forever) -> None:
    """Print ``message`` (the URL) to ``out``, then block in ``wait(server)`` until Ctrl-C."""
    print(f"{message}  (Ctrl-C to stop)", file=out, flush=True)
    try:
        wait(server)
    except KeyboardInterrupt:
        pass
