"""The error status codes each route documents in the OpenAPI schema, with their bodies.

`document_errors(app)` adds to the schema those that follow from a route's shape: 401 when it needs a
signed-in member (and 403 for a write: the CSRF check), 403 when only an admin may call it, 404 for an id in
its path, 422 when it takes any parameter or body. A route names the codes its own logic answers with
`responses=errors(...)`.
"""

from typing import Any

from fastapi import FastAPI
from fastapi.dependencies.models import Dependant
from fastapi.dependencies.utils import get_flat_params
from fastapi.openapi.constants import REF_PREFIX
from fastapi.routing import APIRoute, RouteContext, iter_route_contexts
from pydantic.json_schema import models_json_schema

from backend.deps import SAFE_METHODS, current_caller, get_admin
from backend.schemas import Message, Refusal

MEANINGS: dict[int, str] = {
    206: "The requested byte range.",
    304: "Not modified since the ETag sent in If-None-Match.",
    401: "Not signed in, or the session expired or was signed out: sign in again.",
    403: "Not allowed: an admin's action, another member's item, or (signed in with the cookie) "
    "a missing or wrong CSRF token.",
    404: "Not found in the caller's household.",
    409: "Conflicts with the current state; the detail says which and what to do.",
    410: "The stored file is missing from the blob store.",
    413: "The upload is larger than the limit the detail names.",
    415: "The upload is not in a format the API reads; the detail lists those it does.",
    416: "The byte range lies outside the file.",
    422: "The request is invalid; the detail says what to change.",
    429: "Too many requests; try again after Retry-After seconds.",
    503: "A service the request needs (the task queue, Redis or the database) is not reachable.",
}
_WITHOUT_BODY = {206, 304, 416}


def errors(*codes: int) -> dict[int | str, dict[str, Any]]:
    """`responses=` for a route: each code with its meaning and the schema of its body."""
    documented: dict[int | str, dict[str, Any]] = {}
    for code in codes:
        documented[code] = {"description": MEANINGS[code]}
        if code not in _WITHOUT_BODY:
            documented[code]["model"] = Refusal if code == 422 else Message
    return documented


def _calls(dependant: Dependant) -> set[Any]:
    found = set()
    for dependency in dependant.dependencies:
        found |= {dependency.call, *_calls(dependency)}
    return found


def implied_codes(route: APIRoute | RouteContext) -> list[int]:
    calls, codes = _calls(route.dependant), []
    if current_caller in calls:
        codes.append(401)
        if get_admin in calls or not route.methods <= SAFE_METHODS:
            codes.append(403)
    if route.dependant.path_params:
        codes.append(404)
    if get_flat_params(route.dependant) or route.body_field:
        codes.append(422)
    return codes


def _reference(code: int) -> dict[str, Any]:
    response: dict[str, Any] = {"description": MEANINGS[code]}
    if code not in _WITHOUT_BODY:
        model = Refusal if code == 422 else Message
        schema = {"$ref": f"{REF_PREFIX}{model.__name__}"}
        response["content"] = {"application/json": {"schema": schema}}
    return response


def _uses_fastapis_422(response: dict[str, Any]) -> bool:
    schema = response.get("content", {}).get("application/json", {}).get("schema", {})
    return schema.get("$ref") == f"{REF_PREFIX}HTTPValidationError"


def document_errors(app: FastAPI) -> None:
    """Makes the app's OpenAPI schema list each route's implied error codes beside those it documents itself,
    and every 422 with the body the API sends (FastAPI's own 422 schema only knows malformed requests)."""
    build = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema:
            return app.openapi_schema
        schema = build()
        _, definitions = models_json_schema(
            [(Message, "serialization"), (Refusal, "serialization")], ref_template=REF_PREFIX + "{model}"
        )
        schema.setdefault("components", {}).setdefault("schemas", {}).update(definitions["$defs"])
        for route in iter_route_contexts(app.routes):  # included routers' routes with their prefixes
            if not (isinstance(route.original_route, APIRoute) and route.include_in_schema):
                continue
            for method in route.methods:
                responses = schema["paths"][route.path_format][method.lower()]["responses"]
                for code in implied_codes(route):
                    if str(code) not in responses or (code == 422 and _uses_fastapis_422(responses["422"])):
                        responses[str(code)] = _reference(code)
        return schema

    app.openapi = openapi  # type: ignore[method-assign]
