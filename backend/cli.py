"""`varbot admin`, `varbot db`, `varbot blobs` and `varbot api`. Heavy imports happen inside the commands."""

from pathlib import Path
from typing import Annotated

import typer

from core.paths import REPO_ROOT

admin_app = typer.Typer(help="Households and their admins.", no_args_is_help=True)
db_app = typer.Typer(help="The database schema (Alembic migrations).", no_args_is_help=True)
blobs_app = typer.Typer(help="The blob store (clips, images, checkpoints).", no_args_is_help=True)


def register_backend_commands(app: typer.Typer) -> None:
    app.add_typer(admin_app, name="admin")
    app.add_typer(db_app, name="db")
    app.add_typer(blobs_app, name="blobs")
    app.command(name="api")(api)


def alembic_config(url: str | None = None):  # type: ignore[no-untyped-def]
    from alembic.config import Config

    config = Config(str(REPO_ROOT / "alembic.ini"))
    config.set_main_option("script_location", str(Path(REPO_ROOT / "migrations")))
    if url:
        config.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    return config


@db_app.command()
def upgrade(revision: str = "head") -> None:
    """Apply migrations (creates the SQLite file under the data directory when needed)."""
    from alembic import command

    from backend.settings import get_settings

    command.upgrade(alembic_config(get_settings().sqlalchemy_url), revision)
    typer.echo(f"database at {revision}: {_safe_url()}")


@db_app.command()
def downgrade(revision: str) -> None:
    """Undo migrations down to REVISION (`base` empties the database)."""
    from alembic import command

    from backend.settings import get_settings

    command.downgrade(alembic_config(get_settings().sqlalchemy_url), revision)
    typer.echo(f"database at {revision}: {_safe_url()}")


@db_app.command()
def current() -> None:
    """Show the database's migration revision."""
    from alembic import command

    from backend.settings import get_settings

    command.current(alembic_config(get_settings().sqlalchemy_url), verbose=False)


def _safe_url() -> str:
    from sqlalchemy.engine import make_url

    from backend.settings import get_settings

    return make_url(get_settings().sqlalchemy_url).render_as_string(hide_password=True)


@admin_app.command("create")
def create_admin(
    username: Annotated[str, typer.Option(help="sign-in name (lower case)")],
    household: Annotated[str, typer.Option(help="household name; created when no household has this name")],
    display_name: Annotated[str | None, typer.Option(help="shown in the app; default: the username")] = None,
    password: Annotated[
        str,
        typer.Option(prompt=True, hide_input=True, confirmation_prompt=True, envvar="VARBOT_ADMIN_PASSWORD"),
    ] = "",
) -> None:
    """Create an admin (the first one of a new household, or another one of an existing household)."""
    from pydantic import ValidationError
    from sqlalchemy import select

    from backend import models
    from backend.db import get_session_factory
    from backend.errors import ApiError
    from backend.schemas import MemberCreate
    from backend.services import accounts

    try:
        body = MemberCreate(
            username=username.strip().lower(),
            display_name=display_name or username,
            password=password,
            role=models.Role.ADMIN,
        )
    except ValidationError as exc:
        raise typer.BadParameter("; ".join(f"{e['loc'][0]}: {e['msg']}" for e in exc.errors())) from exc
    with get_session_factory()() as session:
        home = session.scalar(select(models.Household).where(models.Household.name == household))
        if home is None:
            home = accounts.create_household(session, household)
        try:
            user = accounts.create_user(session, home.id, body)
        except ApiError as exc:
            raise typer.BadParameter(exc.detail) from exc
        session.commit()
        typer.echo(
            f"admin {user.username!r} (id {user.id}) of household {home.name!r} (id {home.id}) created"
        )


@blobs_app.command("sweep")
def sweep(
    grace_seconds: Annotated[
        int, typer.Option(help="leave blobs younger than this (uploads in flight)")
    ] = 3600,
) -> None:
    """Delete blobs that no database row references (left behind by crashes)."""
    from backend.blobs import sweep_orphans
    from backend.db import get_session_factory
    from backend.deps import get_blob_store

    with get_session_factory()() as session:
        removed = sweep_orphans(session, get_blob_store(), grace_seconds)
    typer.echo(f"removed {len(removed)} orphaned blob(s)")


def api(
    host: Annotated[str, typer.Option(help="address to listen on")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="port")] = 8000,
    workers: Annotated[int, typer.Option(help="uvicorn worker processes")] = 1,
    migrate: Annotated[bool, typer.Option(help="apply database migrations first")] = True,
) -> None:
    """Serve the web API with uvicorn (OpenAPI docs at /docs)."""
    import uvicorn

    if migrate:
        upgrade("head")
    uvicorn.run(
        "backend.main:app", host=host, port=port, workers=workers, proxy_headers=True, log_level="info"
    )
