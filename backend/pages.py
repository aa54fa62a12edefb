"""The pages people use (static files from `frontend/`) and the 3D scene, reached only through the app.

`install_pages(app)` adds:
- `/` (the Start page's first-run checklist, also at `/home`), `/login`, `/record`, `/label`, `/progress`,
  `/admin`, `/household`, `/scene`: the HTML pages;
- `/static/…`: their CSS and ES modules (no build step);
- `/api/v1/system/queues`: queue lengths and the workers that answer (admins; see backend/system_status.py);
- `/scene/status`: whether the signed-in member's household scene can be shown (starting it when none runs),
  and why not, and how many scene tabs are open through this app;
- `/scene/viser/…` (HTTP) and the `/scene/viser` WebSocket: a proxy to the Viser service on 127.0.0.1 of the
  signed-in member's own household.

Each household has its own scene process, started on demand by this app (`scene/on_demand.py`) and stopping
by itself once nobody has watched it for a while. It announces in `data_dir()/scene/household-<id>.json`
(written by `scene/endpoint.py`, readable by this user only) where it listens and the headers to present: the
scene answers nobody who does not present them (`scene/access.py`), so it is watched only through this proxy.
"""

import asyncio
import contextlib
from dataclasses import dataclass, field
from typing import Any

import httpx
import websockets
from fastapi import FastAPI, HTTPException, Request, WebSocket, WebSocketDisconnect, status
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from starlette.datastructures import Headers
from websockets.asyncio.client import ClientConnection

from backend.db import get_session_factory
from backend.deps import Caller, get_caller
from backend.settings import get_settings
from backend.system_status import router as system_router
from core.paths import REPO_ROOT
from scene import on_demand
from scene.endpoint import announced

FRONTEND_DIR = REPO_ROOT / "frontend"
PAGES = ("home", "login", "record", "label", "progress", "admin", "household", "scene")
SCENE_PREFIX = "/scene/viser"
_HOP_BY_HOP = {
    "connection",
    "keep-alive",
    "proxy-authenticate",
    "proxy-authorization",
    "te",
    "trailers",
    "transfer-encoding",
    "upgrade",
    "host",
    "cookie",
    "content-length",
    "authorization",  # the member's own credentials stay with the app
}


_CLOSED = (WebSocketDisconnect, websockets.ConnectionClosed)


@dataclass(frozen=True)
class SceneEndpoint:
    url: str  # http://127.0.0.1:port
    household_id: int | None
    headers: dict[str, str] = field(default_factory=dict)  # to present on every request (the secret)

    @property
    def websocket_url(self) -> str:
        return "ws://" + self.url.split("://", 1)[1]

    def upstream_headers(self, incoming: Headers) -> dict[str, str]:
        """The browser's request headers the scene may see, and the scene's own."""
        own = {name.lower() for name in self.headers}
        kept = {k: v for k, v in incoming.items() if k.lower() not in _HOP_BY_HOP and k.lower() not in own}
        return {**kept, **self.headers}


class SceneStarting(HTTPException):
    """The household's scene is not announced yet: it has been started (or is coming up)."""

    def __init__(self) -> None:
        super().__init__(
            status.HTTP_503_SERVICE_UNAVAILABLE,
            "starting the 3D scene for your household (this takes a few seconds)…",
            headers={"Retry-After": "2"},
        )


class SceneViewers:
    """How many scene tabs this app proxies right now; a tab counts until the proxy has finished with it."""

    def __init__(self) -> None:
        self.open = 0


scene_viewers = SceneViewers()


def scene_endpoint(household_id: int) -> SceneEndpoint | None:
    """The household's running scene; None while it has none (then `on_demand.start_for` starts one)."""
    found = announced(household_id)
    return SceneEndpoint(found.url, found.household_id, found.headers) if found is not None else None


def install_pages(app: FastAPI, api_prefix: str = "/api/v1") -> None:
    app.include_router(system_router, prefix=api_prefix)
    app.mount("/static", StaticFiles(directory=FRONTEND_DIR / "static"), name="static")

    app.add_api_route("/", _page_handler("home"), methods=["GET"], include_in_schema=False)
    for page in PAGES:
        app.add_api_route(f"/{page}", _page_handler(page), methods=["GET"], include_in_schema=False)

    app.add_api_route("/scene/status", scene_status, methods=["GET"], include_in_schema=False)
    app.add_api_route(
        f"{SCENE_PREFIX}/{{path:path}}", scene_http, methods=["GET", "HEAD"], include_in_schema=False
    )
    app.add_api_websocket_route(SCENE_PREFIX, scene_websocket)
    app.add_api_websocket_route(f"{SCENE_PREFIX}/", scene_websocket)


def _page_handler(page: str) -> Any:
    path = FRONTEND_DIR / f"{page}.html"

    def handler() -> FileResponse:
        return FileResponse(path, media_type="text/html", headers={"Cache-Control": "no-cache"})

    handler.__name__ = f"page_{page}"
    return handler


# --- who may see the scene ----------------------------------------------------------------------------------


class _ReadOnlyHandshake:
    """A WebSocket handshake seen as a safe read (GET) by the session check shared with the API."""

    method = "GET"

    def __init__(self, headers: Headers, cookies: dict[str, str]) -> None:
        self.headers = headers
        self.cookies = cookies


def _scene_caller(headers: Headers, cookies: dict[str, str]) -> tuple[Caller, SceneEndpoint]:
    """The signed-in member allowed to see the scene, and where the scene listens; HTTPException otherwise."""
    with get_session_factory()() as session:
        caller = get_caller(_ReadOnlyHandshake(headers, cookies), session, get_settings())  # type: ignore[arg-type]
    endpoint = scene_endpoint(caller.household_id)
    if endpoint is None:
        on_demand.start_for(caller.household_id)
        raise SceneStarting()
    return caller, endpoint


async def scene_status(request: Request) -> JSONResponse:
    """For the Scene page: whether the scene can be shown to this member, and if not, why (always 200 for a
    signed-in member, so that the page can explain instead of failing)."""
    try:
        await asyncio.to_thread(_scene_caller, request.headers, dict(request.cookies))
    except HTTPException as exc:
        if exc.status_code == status.HTTP_401_UNAUTHORIZED:
            raise
        starting = isinstance(exc, SceneStarting)
        return JSONResponse(
            {"available": False, "starting": starting, "detail": exc.detail, "viewers": scene_viewers.open}
        )
    return JSONResponse({"available": True, "detail": "the scene is running", "viewers": scene_viewers.open})


async def scene_http(path: str, request: Request) -> Response:
    caller_and_endpoint = await asyncio.to_thread(_scene_caller, request.headers, dict(request.cookies))
    endpoint = caller_and_endpoint[1]
    forwarded = endpoint.upstream_headers(request.headers)
    try:
        async with httpx.AsyncClient(timeout=10) as client:
            upstream = await client.request(
                request.method, f"{endpoint.url}/{path}", params=request.query_params, headers=forwarded
            )
    except httpx.HTTPError as exc:
        raise HTTPException(
            status.HTTP_502_BAD_GATEWAY,
            f"the 3D scene did not answer ({exc.__class__.__name__}); reload the page to start it again",
        ) from exc
    headers = {k: v for k, v in upstream.headers.items() if k.lower() not in _HOP_BY_HOP}
    headers.pop("content-encoding", None)  # httpx has already decoded the body
    headers["Cache-Control"] = "no-store"
    return Response(upstream.content, status_code=upstream.status_code, headers=headers)


def _same_origin(websocket: WebSocket) -> bool:
    origin = websocket.headers.get("origin")
    if origin is None:  # not a browser: the session cookie still has to be valid
        return True
    host = websocket.headers.get("host", "")
    return origin.split("://", 1)[-1] == host


async def scene_websocket(websocket: WebSocket) -> None:
    if not _same_origin(websocket):
        await websocket.close(code=status.WS_1008_POLICY_VIOLATION, reason="cross-site connection refused")
        return
    try:
        _caller, endpoint = await asyncio.to_thread(_scene_caller, websocket.headers, dict(websocket.cookies))
    except HTTPException as exc:
        await websocket.close(code=status.WS_1008_POLICY_VIOLATION, reason=str(exc.detail)[:120])
        return
    offered = [p.strip() for p in websocket.headers.get("sec-websocket-protocol", "").split(",") if p.strip()]
    try:
        upstream = await websockets.connect(
            endpoint.websocket_url,
            subprotocols=offered or None,  # type: ignore[arg-type]
            additional_headers=endpoint.headers,
            max_size=50 * 1024 * 1024,
            compression=None,
            open_timeout=5,
        )
    except (OSError, websockets.WebSocketException, TimeoutError):
        await websocket.close(code=status.WS_1011_INTERNAL_ERROR, reason="the 3D scene is not reachable")
        return
    scene_viewers.open += 1
    try:
        await websocket.accept(subprotocol=upstream.subprotocol)
        await _pump(websocket, upstream)
    except _CLOSED:
        pass  # the tab was closed while the scene was being reached
    finally:
        await upstream.close()
        scene_viewers.open -= 1  # last: once the count drops, the proxy is done with the tab


async def _pump(browser: WebSocket, upstream: ClientConnection) -> None:
    """Relay messages both ways until one side is gone, then close the other. A closed tab or a stopped
    scene is how a connection ends, not an error."""

    async def to_scene() -> None:
        while True:
            message = await browser.receive()
            if message["type"] == "websocket.disconnect":
                return
            if message.get("bytes") is not None:
                await upstream.send(message["bytes"])
            elif message.get("text") is not None:
                await upstream.send(message["text"])

    async def to_browser() -> None:
        async for message in upstream:
            if isinstance(message, bytes):
                await browser.send_bytes(message)
            else:
                await browser.send_text(message)

    tasks = [asyncio.create_task(to_scene()), asyncio.create_task(to_browser())]
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in tasks:
            task.cancel()
        for task in tasks:
            with contextlib.suppress(asyncio.CancelledError, *_CLOSED):
                await task
    with contextlib.suppress(RuntimeError, *_CLOSED):  # the tab may be gone already
        await browser.close()
