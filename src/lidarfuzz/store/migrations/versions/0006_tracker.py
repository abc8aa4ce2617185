"""the run tracker: a task's tags, notes and headline metrics (mAP, ΔmAP, violations, failures, for
sorting the list without reading every summary), and when each subtask started and finished

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-23 22:20:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("tasks", schema=None) as batch_op:
        batch_op.add_column(sa.Column("tags", sa.JSON(), nullable=False, server_default="[]"))
        batch_op.add_column(sa.Column("notes", sa.Text(), nullable=False, server_default=""))
        batch_op.add_column(sa.Column("headline", sa.JSON(), nullable=True))
    with op.batch_alter_table("subtasks", schema=None) as batch_op:
        batch_op.add_column(sa.Column("started_at", sa.DateTime(timezone=True), nullable=True))
        batch_op.add_column(sa.Column("finished_at", sa.DateTime(timezone=True), nullable=True))


def downgrade() -> None:
    # ALTER TABLE ... DROP COLUMN in place: a copy-and-rename batch would drop ``tasks``, and SQLite's
    # foreign keys would cascade that to every subtask, result and finding
    with op.batch_alter_table("subtasks", schema=None, recreate="never") as batch_op:
        batch_op.drop_column("finished_at")
        batch_op.drop_column("started_at")
    with op.batch_alter_table("tasks", schema=None, recreate="never") as batch_op:
        batch_op.drop_column("headline")
        batch_op.drop_column("notes")
        batch_op.drop_column("tags")
