"""The OpenAPI document lists every status code each operation answers, and the bodies it answers with."""

import pytest


@pytest.fixture(scope="module")
def operations() -> dict[tuple[str, str], dict]:
    from backend.main import create_app

    paths = create_app().openapi()["paths"]
    return {
        (method.upper(), path): operation
        for path, item in paths.items()
        for method, operation in item.items()
    }


def codes(operations, method: str, path: str) -> set[int]:  # type: ignore[no-untyped-def]
    return {int(code) for code in operations[method, "/api/v1" + path]["responses"]}


@pytest.mark.parametrize(
    ("method", "path", "expected"),
    [
        ("POST", "/clips", {201, 401, 403, 413, 415, 422}),
        ("GET", "/clips/{clip_id}/audio", {200, 206, 304, 401, 404, 410, 416, 422}),
        ("POST", "/robots/{robot_id}/snapshots:capture", {202, 401, 403, 404, 409, 422, 429, 503}),
        ("POST", "/labels", {201, 401, 403, 404, 409, 422}),
        ("PUT", "/labels/{label_id}", {200, 401, 403, 404, 422}),
        ("GET", "/labels/next", {200, 401, 404, 422}),
        ("POST", "/runs", {201, 401, 403, 404, 409, 422, 503}),
        ("DELETE", "/robots/{robot_id}", {204, 401, 403, 404, 409, 422}),
        ("POST", "/auth/login", {200, 401, 422, 429, 503}),
        ("GET", "/robots", {200, 401}),
    ],
)
def test_each_operation_documents_the_codes_it_answers(operations, method, path, expected) -> None:
    assert codes(operations, method, path) == expected


def test_every_signed_in_operation_documents_401_and_every_write_403(operations) -> None:
    public = {"/api/v1/auth/login", "/api/v1/auth/token", "/api/v1/health", "/api/v1/runs/presets"}
    for (method, path), operation in operations.items():
        if path in public:
            continue
        assert "401" in operation["responses"], (method, path)
        if method != "GET":
            assert "403" in operation["responses"], (method, path)


def test_every_422_is_documented_with_the_body_the_api_sends(operations) -> None:
    for (method, path), operation in operations.items():
        if "422" in operation["responses"]:
            schema = operation["responses"]["422"]["content"]["application/json"]["schema"]
            assert schema == {"$ref": "#/components/schemas/Refusal"}, (method, path)


def test_a_refusal_in_words_matches_the_documented_422(member) -> None:
    """A 422 a service raises (a sentence) and one FastAPI raises (one entry per field) both fit `Refusal`."""
    from backend.schemas import Refusal

    in_words = member.client.post("/api/v1/clips", files={"file": ("a.wav", b"", "audio/wav")})
    malformed = member.client.post("/api/v1/labels", json={"snapshot_id": "x"})
    for response in (in_words, malformed):
        assert response.status_code == 422
        Refusal.model_validate(response.json())
    assert isinstance(in_words.json()["detail"], str) and isinstance(malformed.json()["detail"], list)
