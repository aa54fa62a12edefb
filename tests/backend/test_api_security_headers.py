"""Every response carries the security headers; the pages hold nothing that their Content-Security-Policy
would refuse (no inline scripts, styles or handlers); the proxied scene may be framed by the app only."""

import re

import pytest
from fastapi.testclient import TestClient

from backend.pages import FRONTEND_DIR, PAGES


def directives(policy: str) -> dict[str, str]:
    return dict(part.strip().split(" ", 1) for part in policy.split(";"))


@pytest.mark.parametrize("path", [f"/{page}" for page in PAGES] + ["/static/css/app.css", "/api/v1/health"])
def test_pages_and_the_api_carry_the_security_headers(wired_app, path: str) -> None:
    response = TestClient(wired_app).get(path)
    assert response.status_code == 200
    assert response.headers["X-Content-Type-Options"] == "nosniff"
    assert response.headers["Referrer-Policy"] == "same-origin"
    assert response.headers["X-Frame-Options"] == "DENY"
    policy = directives(response.headers["Content-Security-Policy"])
    assert policy["frame-ancestors"] == "'none'"
    assert policy["script-src"] == "'self'" and policy["style-src"] == "'self'"
    assert policy["object-src"] == "'none'" and policy["default-src"] == "'self'"
    assert policy["frame-src"] == "'self'"  # the Scene page frames the proxied scene


def test_error_answers_carry_them_too(wired_app) -> None:
    response = TestClient(wired_app).get("/api/v1/robots")
    assert response.status_code == 401
    assert response.headers["X-Content-Type-Options"] == "nosniff"
    assert "frame-ancestors 'none'" in response.headers["Content-Security-Policy"]


def test_the_proxied_scene_may_be_framed_by_the_app_only(wired_app) -> None:
    response = TestClient(wired_app).get("/scene/viser/")
    assert response.status_code == 401  # still signed-in members only
    assert response.headers["X-Frame-Options"] == "SAMEORIGIN"
    policy = directives(response.headers["Content-Security-Policy"])
    assert policy["frame-ancestors"] == "'self'"
    assert "'wasm-unsafe-eval'" in policy["script-src"]  # the Viser client unpacks itself with WebAssembly
    assert "http" not in response.headers["Content-Security-Policy"]  # nothing from other origins


def test_the_api_docs_may_load_swagger_ui_from_its_cdn_only(wired_app) -> None:
    response = TestClient(wired_app).get("/docs")
    assert response.status_code == 200
    policy = directives(response.headers["Content-Security-Policy"])
    for source in re.findall(r'(?:src|href)="(https://[^/"]+)', response.text):
        assert source in policy["script-src"] + policy["style-src"] + policy["img-src"], source
    assert policy["frame-ancestors"] == "'none'" and policy["connect-src"] == "'self'"


@pytest.mark.parametrize("page", PAGES)
def test_no_page_holds_what_its_policy_would_refuse(page: str) -> None:
    html = (FRONTEND_DIR / f"{page}.html").read_text()
    assert not re.search(r"<script(?![^>]*\bsrc=)[^>]*>", html), "an inline <script>"
    assert "<style" not in html and not re.search(r"\sstyle=", html), "an inline style"
    assert not re.search(r"\son[a-z]+=", html), "an inline event handler"
    assert "javascript:" not in html


def test_scripts_set_styles_through_the_cssom_only() -> None:
    for script in (FRONTEND_DIR / "static" / "js").rglob("*.js"):
        source = script.read_text()
        assert not re.search(r"setAttribute\(\s*[\"']style", source), script
        assert "eval(" not in source and "new Function" not in source, script
