"""Label counts kept on snapshots and clips by triggers, and the index GET /labels/next walks.

`GET /labels/next` asks about the most-answered images first and balances commands by how often each clip
was answered. Counting labels per request grew with the labels table; the counts now live on the rows,
kept exact by triggers on `labels` (inserts, deletes — cascades included — and moves between pairs).

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-23 04:20:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0002"
down_revision: str | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

COUNTED = (("snapshots", "snapshot_id"), ("clips", "clip_id"))


def _change(sign: str, row: str) -> str:
    return "".join(
        f"UPDATE {table} SET label_count = label_count {sign} 1 WHERE id = {row}.{column}; "
        for table, column in COUNTED
    )


def upgrade() -> None:
    for table, column in COUNTED:
        op.add_column(table, sa.Column("label_count", sa.Integer(), nullable=False, server_default="0"))
        op.execute(
            f"UPDATE {table} SET label_count = "
            f"(SELECT count(*) FROM labels WHERE labels.{column} = {table}.id)"
        )
    op.create_index("ix_snapshots_asking_order", "snapshots", ["household_id", "label_count", "id"])
    if op.get_bind().dialect.name == "postgresql":
        op.execute(
            "CREATE FUNCTION labels_keep_counts() RETURNS trigger LANGUAGE plpgsql AS $$ BEGIN "
            f"IF TG_OP IN ('INSERT', 'UPDATE') THEN {_change('+', 'NEW')} END IF; "
            f"IF TG_OP IN ('DELETE', 'UPDATE') THEN {_change('-', 'OLD')} END IF; "
            "RETURN NULL; END $$"
        )
        op.execute(
            "CREATE TRIGGER labels_keep_counts AFTER INSERT OR DELETE OR UPDATE OF snapshot_id, clip_id "
            "ON labels FOR EACH ROW EXECUTE FUNCTION labels_keep_counts()"
        )
    else:
        op.execute(
            f"CREATE TRIGGER labels_count_insert AFTER INSERT ON labels BEGIN {_change('+', 'NEW')}END"
        )
        op.execute(
            f"CREATE TRIGGER labels_count_delete AFTER DELETE ON labels BEGIN {_change('-', 'OLD')}END"
        )
        op.execute(
            "CREATE TRIGGER labels_count_move AFTER UPDATE OF snapshot_id, clip_id ON labels "
            f"BEGIN {_change('-', 'OLD')}{_change('+', 'NEW')}END"
        )


def downgrade() -> None:
    if op.get_bind().dialect.name == "postgresql":
        op.execute("DROP TRIGGER labels_keep_counts ON labels")
        op.execute("DROP FUNCTION labels_keep_counts()")
    else:
        for trigger in ("labels_count_insert", "labels_count_delete", "labels_count_move"):
            op.execute(f"DROP TRIGGER {trigger}")
    op.drop_index("ix_snapshots_asking_order", table_name="snapshots")
    for table, _ in COUNTED:
        # SQLite ≥ 3.35 drops a column in place; a batch copy of the table would cascade-delete its labels.
        op.execute(f"ALTER TABLE {table} DROP COLUMN label_count")
