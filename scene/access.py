"""Only the app's proxy may watch the scene. Viser listens on 127.0.0.1 only, and every request to it (the
viewer's files and the WebSocket) must carry this start's secret in `SECRET_HEADER`; any other local process
or browser page gets 403 before Viser sees the request. The secret reaches the proxy through the endpoint file
(`scene.endpoint`, one per household, readable by the app's user only), with the header to present it in.

Viser 1.1 has no access check of its own and no unix-socket option; it starts its server with
`websockets.asyncio.server.serve(..., process_request=...)`. `guarded_viser_server` wraps that one call, while
the server starts, with the secret check in front of Viser's own request handler, and fails closed: if Viser
ever starts its server another way, the scene refuses to start instead of running unguarded."""

import hmac
import secrets
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from http import HTTPStatus
from typing import Any

import viser
import websockets.asyncio.server
from websockets.asyncio.server import ServerConnection
from websockets.http11 import Request, Response

from scene.endpoint import SECRET_HEADER

LOOPBACK = "127.0.0.1"
REFUSED = "The 3D scene is shown through the app only: open /scene there and sign in.\n"

ProcessRequest = Callable[[ServerConnection, Request], Any]


def new_secret() -> str:
    return secrets.token_urlsafe(32)


def presents(request: Request, secret: str) -> bool:
    return hmac.compare_digest(request.headers.get(SECRET_HEADER, "").encode(), secret.encode())


def checking_secret(secret: str, then: ProcessRequest | None) -> ProcessRequest:
    """A `process_request` that answers 403 without the secret and hands every other request to `then`."""

    def check(connection: ServerConnection, request: Request) -> Response | Any:
        if not presents(request, secret):
            return connection.respond(HTTPStatus.FORBIDDEN, REFUSED)
        return then(connection, request) if then is not None else None

    return check


@contextmanager
def _serving_with_secret(secret: str) -> Iterator[list[str]]:
    """While Viser starts, its `serve(...)` call gets the secret check; yields the hosts it served on."""
    original = websockets.asyncio.server.serve
    hosts: list[str] = []

    def serve(
        handler: Any, host: str, port: int, *, process_request: ProcessRequest | None = None, **kw: Any
    ) -> Any:
        hosts.append(host)
        return original(handler, host, port, process_request=checking_secret(secret, process_request), **kw)

    websockets.asyncio.server.serve = serve  # type: ignore[assignment]
    try:
        yield hosts
    finally:
        websockets.asyncio.server.serve = original  # type: ignore[assignment]


def guarded_viser_server(secret: str, port: int = 0) -> viser.ViserServer:
    """A Viser server on 127.0.0.1 that answers only requests carrying `secret` in `SECRET_HEADER`."""
    with _serving_with_secret(secret) as hosts:
        server = viser.ViserServer(host=LOOPBACK, port=port, label="varbot scene", verbose=False)
    if not hosts or set(hosts) != {LOOPBACK}:
        server.stop()
        raise RuntimeError(
            f"viser {viser.__version__} did not start its server through websockets' serve() on {LOOPBACK} "
            f"(calls: {hosts}); the scene would not be guarded, so it does not start (see scene/access.py)"
        )
    return server
