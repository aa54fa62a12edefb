"""Health and docs."""


def test_health_reports_database_and_broker_reachable(admin) -> None:
    for path in ("/api/v1/health", "/health"):
        response = admin.client.get(path)
        assert response.status_code == 200
        assert response.json() == {"status": "ok", "database": "ok", "broker": "ok"}


def test_health_says_503_when_the_broker_is_down(admin, broker_down) -> None:
    response = admin.client.get("/health")
    assert response.status_code == 503
    assert response.json()["broker"].startswith("unreachable")


def test_openapi_docs_are_served(admin) -> None:
    assert admin.client.get("/docs").status_code == 200
    schema = admin.client.get("/api/v1/openapi.json").json()
    assert "/api/v1/labels/next" in schema["paths"]
