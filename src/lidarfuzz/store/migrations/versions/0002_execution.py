"""execution: task options, errors and heartbeats; subtask names and operator indices; the mutants'
ground truth per frame result; the SUT output cache

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-22 16:00:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("tasks", schema=None) as batch_op:
        batch_op.add_column(sa.Column("options", sa.JSON(), nullable=False, server_default="{}"))
        batch_op.add_column(sa.Column("error", sa.Text(), nullable=False, server_default=""))
        batch_op.add_column(sa.Column("worker", sa.String(length=200), nullable=False, server_default=""))
        batch_op.add_column(sa.Column("heartbeat_at", sa.DateTime(timezone=True), nullable=True))
    with op.batch_alter_table("subtasks", schema=None) as batch_op:
        batch_op.add_column(sa.Column("name", sa.String(length=100), nullable=False, server_default=""))
        batch_op.add_column(sa.Column("op_index", sa.Integer(), nullable=False, server_default="0"))
    with op.batch_alter_table("frame_results", schema=None) as batch_op:
        batch_op.add_column(sa.Column("gt_boxes", sa.LargeBinary(), nullable=True))
        batch_op.add_column(sa.Column("gt_labels", sa.JSON(), nullable=False, server_default="[]"))
        batch_op.add_column(sa.Column("cached", sa.Boolean(), nullable=False, server_default=sa.false()))
    with op.batch_alter_table("findings", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_findings_kind"), ["kind"], unique=False)
    op.create_table(
        "sut_outputs",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("fingerprint", sa.String(length=64), nullable=False),
        sa.Column("digest", sa.String(length=64), nullable=False),
        sa.Column("boxes", sa.LargeBinary(), nullable=False),
        sa.Column("labels", sa.JSON(), nullable=False),
        sa.Column("seconds", sa.Float(), nullable=False),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("fingerprint", "digest"),
    )


def downgrade() -> None:
    op.drop_table("sut_outputs")
    with op.batch_alter_table("findings", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_findings_kind"))
    with op.batch_alter_table("frame_results", schema=None) as batch_op:
        batch_op.drop_column("cached")
        batch_op.drop_column("gt_labels")
        batch_op.drop_column("gt_boxes")
    with op.batch_alter_table("subtasks", schema=None) as batch_op:
        batch_op.drop_column("op_index")
        batch_op.drop_column("name")
    with op.batch_alter_table("tasks", schema=None) as batch_op:
        batch_op.drop_column("heartbeat_at")
        batch_op.drop_column("worker")
        batch_op.drop_column("error")
        batch_op.drop_column("options")
