"""The migration chain builds the schema the models describe on an empty database, and takes it down."""

import pytest
from conftest import create_postgres_database, migrate
from sqlalchemy import create_engine, inspect

TABLES = {
    "households",
    "users",
    "auth_sessions",
    "login_failures",
    "robots",
    "clips",
    "snapshots",
    "labels",
    "label_events",
    "runs",
    "model_versions",
    "embeddings",
}


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def empty_database(request: pytest.FixtureRequest, tmp_path) -> str:  # type: ignore[no-untyped-def]
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'empty.db'}"
    return create_postgres_database(request.getfixturevalue("postgres_server"), "varbot_migrations")


def test_upgrade_from_empty_matches_the_models_and_downgrade_empties_it(empty_database: str) -> None:
    from alembic.autogenerate import compare_metadata
    from alembic.migration import MigrationContext

    from backend.models import Base

    migrate(empty_database)
    engine = create_engine(empty_database)
    try:
        assert set(inspect(engine).get_table_names()) >= TABLES
        with engine.connect() as connection:
            differences = compare_metadata(MigrationContext.configure(connection), Base.metadata)
        assert differences == [], f"models and migrations disagree: {differences}"
        migrate(empty_database, "base", down=True)
        assert set(inspect(engine).get_table_names()) <= {"alembic_version"}
        migrate(empty_database)  # and up again
        assert set(inspect(engine).get_table_names()) >= TABLES
    finally:
        engine.dispose()


A_SIGNED_IN_MEMBER = (
    "INSERT INTO households (id, name, created_at) VALUES (1, 'home', '2026-12-01')",
    "INSERT INTO users (id, household_id, username, display_name, password_hash, role, is_active, "
    "created_at) VALUES (1, 1, 'alice', 'Alice', 'x', 'admin', true, '2026-12-01')",
    "INSERT INTO auth_sessions (user_id, token_hash, csrf_token, kind, created_at, expires_at) "
    "VALUES (1, 'h', 'c', 'cookie', '2026-12-01', '2026-12-15')",
)


def test_0003_keeps_the_sessions_it_finds_and_gives_them_back_on_downgrade(empty_database: str) -> None:
    from sqlalchemy import text

    migrate(empty_database, "0002")
    engine = create_engine(empty_database)
    try:
        with engine.begin() as connection:
            for statement in A_SIGNED_IN_MEMBER:
                connection.execute(text(statement))
        migrate(empty_database, "0003")
        with engine.connect() as connection:
            found = connection.execute(
                text("SELECT token_hash, user_agent, client_address FROM auth_sessions")
            )
            assert found.all() == [("h", None, None)]
            assert connection.execute(text("SELECT count(*) FROM login_failures")).scalar() == 0
        migrate(empty_database, "0002", down=True)
        assert "login_failures" not in inspect(engine).get_table_names()
        columns = {column["name"] for column in inspect(engine).get_columns("auth_sessions")}
        assert columns.isdisjoint({"user_agent", "client_address"})
        with engine.connect() as connection:
            assert connection.execute(text("SELECT token_hash FROM auth_sessions")).scalars().all() == ["h"]
    finally:
        engine.dispose()
