"""The one engine and session factory. SQLite (WAL, foreign keys on) by default; PostgreSQL via psycopg 3."""

from collections.abc import Iterator
from functools import lru_cache
from pathlib import Path

from sqlalchemy import Engine, create_engine, event, make_url
from sqlalchemy.orm import Session, sessionmaker

from backend.settings import get_settings
from core.paths import private_file


def _configure_sqlite(dbapi_connection, _record) -> None:  # type: ignore[no-untyped-def]
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.execute("PRAGMA synchronous=NORMAL")
    cursor.execute("PRAGMA busy_timeout=10000")
    cursor.close()


def make_engine(url: str) -> Engine:
    if url.startswith("sqlite"):
        if (database := make_url(url).database) and database != ":memory:":
            private_file(Path(database))  # SQLite would create it 0644; its -wal and -shm files copy its mode
        # As many connections as the server has request threads (anyio's default limiter: 40).
        engine = create_engine(url, connect_args={"check_same_thread": False, "timeout": 10}, pool_size=40)
        event.listen(engine, "connect", _configure_sqlite)
        return engine
    return create_engine(url, pool_size=20, max_overflow=20, pool_pre_ping=True)


@lru_cache
def get_engine() -> Engine:
    return make_engine(get_settings().sqlalchemy_url)


@lru_cache
def get_session_factory() -> sessionmaker[Session]:
    return sessionmaker(bind=get_engine(), expire_on_commit=False)


def session_scope() -> Iterator[Session]:
    """One session per request (the FastAPI dependency); closed afterwards."""
    with get_session_factory()() as session:
        yield session
