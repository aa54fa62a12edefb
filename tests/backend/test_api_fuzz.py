"""A bounded schemathesis pass over the OpenAPI schema: whatever a client sends, the API never answers 5xx,
every status code it answers is documented for that operation, and every body matches its documented
schema."""

import pytest
import schemathesis
from apitest_helpers import PASSWORD, make_robot, upload_clip, upload_snapshot
from hypothesis import HealthCheck, given, settings
from schemathesis.checks import not_a_server_error, response_schema_conformance, status_code_conformance

CHECKS = [not_a_server_error, status_code_conformance, response_schema_conformance]


@pytest.fixture
def api_schema(wired_app, admin, member):  # type: ignore[no-untyped-def]
    robot = make_robot(admin)  # a little data so that some generated ids exist
    upload_snapshot(admin, robot)
    upload_clip(member)
    return schemathesis.openapi.from_asgi("/api/v1/openapi.json", wired_app)


@pytest.fixture
def bearer(wired_app, admin) -> dict[str, str]:  # type: ignore[no-untyped-def]
    from fastapi.testclient import TestClient

    token = TestClient(wired_app).post("/api/v1/auth/token", data={"username": "alice", "password": PASSWORD})
    return {"Authorization": f"Bearer {token.json()['access_token']}"}


@pytest.mark.slow
@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_no_request_makes_the_api_fail_or_answer_off_its_schema(api_schema, bearer) -> None:  # type: ignore[no-untyped-def]
    # Operations are driven one by one with Hypothesis (schemathesis's own pytest hook predates pytest 9).
    failures: list[str] = []
    statuses: list[int] = []
    for result in api_schema.get_all_operations():
        operation = result.ok()
        if operation.path.endswith(("/runs/events", "/auth/logout")):
            continue  # a stream that stays open by design / would sign the fuzzer out; both tested elsewhere

        @given(case=operation.as_strategy())
        @settings(max_examples=4, deadline=None, suppress_health_check=list(HealthCheck), database=None)
        def exercise(case) -> None:  # type: ignore[no-untyped-def]
            response = case.call(headers=bearer)
            statuses.append(response.status_code)
            case.validate_response(response, checks=CHECKS)

        try:
            exercise()
        except (Exception, BaseExceptionGroup) as exc:  # every failing operation, not just the first
            failures.append(f"{operation.method.upper()} {operation.path}: {exc}")
    assert not failures, "\n\n".join(failures)
    assert len(statuses) > 60 and sum(200 <= code < 300 for code in statuses) > 10, statuses
