"""The FastAPI application: `uvicorn backend.main:app` (or `varbot api`)."""

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from backend.api.responses import document_errors
from backend.api.routes import (
    attempts,
    auth,
    clips,
    coaching,
    health,
    labels,
    members,
    models,
    robots,
    runs,
    scene,
    snapshots,
)
from backend.blobs import BlobNotFound
from backend.errors import ApiError
from backend.headers import SecurityHeaders
from backend.pages import install_pages

API_PREFIX = "/api/v1"


def create_app() -> FastAPI:
    app = FastAPI(
        title="varbot",
        summary="Teach a robot what your own spoken commands mean.",
        version="1",
        openapi_url=f"{API_PREFIX}/openapi.json",
        docs_url="/docs",
        redoc_url=None,
    )
    for module in (
        auth,
        members,
        robots,
        clips,
        snapshots,
        attempts,
        coaching,
        labels,
        runs,
        models,
        scene,
        health,
    ):
        app.include_router(module.router, prefix=API_PREFIX)
    app.include_router(health.router, include_in_schema=False)  # plain /health for process supervisors
    document_errors(app)
    install_pages(app)  # the pages (frontend/) and the signed-in proxy to the 3D scene
    app.add_middleware(SecurityHeaders)

    @app.exception_handler(ApiError)
    async def api_error(_request: Request, exc: ApiError) -> JSONResponse:
        return JSONResponse({"detail": exc.detail}, status_code=exc.status_code, headers=exc.headers)

    @app.exception_handler(BlobNotFound)
    async def blob_missing(_request: Request, exc: BlobNotFound) -> JSONResponse:
        return JSONResponse({"detail": "the stored file is missing from the blob store"}, status_code=410)

    return app


app = create_app()
