"""Sessions a member can recognise (browser and address) and the sign-in throttle's database fallback.

`auth_sessions` gains `user_agent` and `client_address`, shown by GET /auth/sessions so that a member can
tell their sessions apart and end the ones they do not know. `login_failures` holds recent wrong passwords
per account and per client address while Redis cannot be reached (Redis holds them otherwise).

Revision ID: 0003
Revises: 0002
Create Date: 2026-12-01 23:20:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

SESSION_COLUMNS = (("user_agent", 200), ("client_address", 64))


def upgrade() -> None:
    for name, length in SESSION_COLUMNS:
        op.add_column("auth_sessions", sa.Column(name, sa.String(length=length), nullable=True))
    op.create_table(
        "login_failures",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("key", sa.String(length=80), nullable=False),
        sa.Column("at", sa.Float(), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_login_failures")),
    )
    op.create_index("ix_login_failures_key_at", "login_failures", ["key", "at"])


def downgrade() -> None:
    op.drop_index("ix_login_failures_key_at", table_name="login_failures")
    op.drop_table("login_failures")
    for name, _ in SESSION_COLUMNS:
        # SQLite ≥ 3.35 drops a column in place; a batch copy of auth_sessions is not needed.
        op.execute(f"ALTER TABLE auth_sessions DROP COLUMN {name}")
