"""The live viewer's websocket open to its own page only, and a clean stop on SIGTERM.

A websocket is not bound by the browser's same-origin rule: any web page open in the user's browser
can connect to ``ws://127.0.0.1:PORT`` and, without a check, receive the whole scene and drive the
timeline. Browsers always send the page's ``Origin`` with the handshake, so the server refuses (403)
a handshake whose ``Origin`` is not the viewer's own page: ``http(s)://`` a loopback name
(``127.0.0.1``, ``localhost``, ``[::1]``) or the host it was asked to serve, on the port it serves.
A client that sends no ``Origin`` is not a web page (a script of the user's) and is let in.

viser builds its websockets server inside its own thread and keeps no handle on it, so
:func:`own_origin_only` wraps ``websockets.asyncio.server.serve`` while the server is being
created (``ViserServer`` returns once it serves), chaining the check before viser's own handler.
"""

from __future__ import annotations

import http
import signal
import threading
from contextlib import contextmanager
from typing import Iterator
from urllib.parse import urlsplit

__all__ = ["own_origin_only", "origin_allowed", "stop_on_sigterm", "LOOPBACK_NAMES"]

LOOPBACK_NAMES = ("127.0.0.1", "localhost", "::1")
_WILDCARD = ("", "0.0.0.0", "::")


def origin_allowed(origin: str | None, host: str, port: int) -> bool:
    """Whether a handshake with header ``Origin: origin`` may open the viewer served on ``host:port``."""
    if origin is None:
        return True
    try:
        u = urlsplit(origin.strip())
        o_port = u.port or {"http": 80, "https": 443}.get(u.scheme)
    except ValueError:
        return False
    names = set(LOOPBACK_NAMES) | ({host.lower()} if host not in _WILDCARD else set())
    return u.scheme in ("http", "https") and (u.hostname or "").lower() in names and o_port == port


@contextmanager
def own_origin_only(host: str) -> Iterator[None]:
    """While the block creates a websockets server (viser's), its handshakes are checked by
    :func:`origin_allowed` first; refused ones get 403 and never reach the application."""
    import websockets.asyncio.server as ws

    original = ws.serve

    def serve(handler, *args, process_request=None, **kw):
        def check(connection, request):
            port = connection.local_address[1] if connection.local_address else -1
            if not origin_allowed(request.headers.get("Origin"), host, int(port)):
                return connection.respond(http.HTTPStatus.FORBIDDEN, "this viewer accepts its own page only\n")
            return process_request(connection, request) if process_request is not None else None

        return original(handler, *args, process_request=check, **kw)

    ws.serve = serve
    try:
        yield
    finally:
        ws.serve = original


def stop_on_sigterm() -> None:
    """SIGTERM (``kill``, a service manager) ends the viewer as Ctrl-C does: a KeyboardInterrupt in
    the main thread, so the server closes its connections with close frames and the command exits."""
    if threading.current_thread() is not threading.main_thread():
        return

    def interrupt(signum, frame):  # noqa: ARG001 - the signal module's signature
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, interrupt)
