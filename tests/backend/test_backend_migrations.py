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
