"""Security headers on every HTTP response: Content-Security-Policy, framing rules, nosniff, Referrer-Policy.

The app's own pages load nothing but their own files (no inline script or style: `frontend/` keeps to that)
and may be framed by nobody. The Viser scene, proxied under /scene/viser/, is framed by the Scene page only;
its client starts from an inline script that unpacks WebAssembly and injects its code and styles inline, and
evaluates strings as code, so its own documents get a policy that allows that, still only from this origin.
The API's /docs page loads Swagger UI from its CDN and gets a policy of its own for that."""

from starlette.datastructures import MutableHeaders
from starlette.types import ASGIApp, Message, Receive, Scope, Send

SCENE_PATH = "/scene/viser"


def _policy(**directives: str) -> str:
    return "; ".join(f"{name.replace('_', '-')} {value}" for name, value in directives.items())


APP_POLICY = _policy(
    default_src="'self'",
    script_src="'self'",
    style_src="'self'",
    img_src="'self' data: blob:",
    media_src="'self' blob:",
    connect_src="'self'",
    frame_src="'self'",
    object_src="'none'",
    base_uri="'none'",
    form_action="'self'",
    frame_ancestors="'none'",
)
SCENE_POLICY = _policy(
    default_src="'self'",
    script_src="'self' 'unsafe-inline' 'unsafe-eval' 'wasm-unsafe-eval' blob:",
    style_src="'self' 'unsafe-inline'",
    img_src="'self' data: blob:",
    font_src="'self' data:",
    connect_src="'self' data: blob:",
    worker_src="'self' blob:",
    object_src="'none'",
    base_uri="'self'",
    form_action="'none'",
    frame_ancestors="'self'",
)
# FastAPI's /docs page: Swagger UI from its CDN, started by an inline script; framed by nobody either.
DOCS_CDN = "https://cdn.jsdelivr.net"
DOCS_POLICY = _policy(
    default_src="'self'",
    script_src=f"'self' 'unsafe-inline' {DOCS_CDN}",
    style_src=f"'self' 'unsafe-inline' {DOCS_CDN}",
    img_src="'self' data: https://fastapi.tiangolo.com",
    connect_src="'self'",
    object_src="'none'",
    base_uri="'none'",
    frame_ancestors="'none'",
)
DOCS_PATHS = ("/docs", "/docs/oauth2-redirect")
COMMON = {
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "same-origin",
    "Cross-Origin-Opener-Policy": "same-origin",
}


def headers_for(path: str) -> dict[str, str]:
    if path == SCENE_PATH or path.startswith(SCENE_PATH + "/"):
        return {**COMMON, "Content-Security-Policy": SCENE_POLICY, "X-Frame-Options": "SAMEORIGIN"}
    if path in DOCS_PATHS:
        return {**COMMON, "Content-Security-Policy": DOCS_POLICY, "X-Frame-Options": "DENY"}
    return {**COMMON, "Content-Security-Policy": APP_POLICY, "X-Frame-Options": "DENY"}


class SecurityHeaders:
    """Pure ASGI middleware (streams such as the runs' event stream pass through untouched)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        extra = headers_for(scope["path"])

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = MutableHeaders(scope=message)
                for name, value in extra.items():
                    headers[name] = value
            await send(message)

        await self.app(scope, receive, send_with_headers)
