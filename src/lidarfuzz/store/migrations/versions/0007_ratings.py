"""ratings: people's verdicts (same, similar, different) on original/mutant pairs, the thesis's first
experiment (Table 6-7)

Revision ID: 0007
Revises: 0006
Create Date: 2026-11-23 22:30:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "ratings",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("task_id", sa.Integer(), nullable=False),
        sa.Column("frame_result_id", sa.Integer(), nullable=False),
        sa.Column("rater", sa.String(length=100), nullable=False),
        sa.Column("verdict", sa.String(length=16), nullable=False),
        sa.Column("first_rated_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("rated_at", sa.DateTime(timezone=True), nullable=False),
        sa.CheckConstraint("verdict IN ('same', 'similar', 'different')", name="ck_rating_verdict"),
        sa.ForeignKeyConstraint(["frame_result_id"], ["frame_results.id"], ondelete="CASCADE"),
        sa.ForeignKeyConstraint(["task_id"], ["tasks.id"], ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("frame_result_id", "rater"),
    )
    op.create_index("ix_ratings_task_id", "ratings", ["task_id"])
    op.create_index("ix_ratings_frame_result_id", "ratings", ["frame_result_id"])


def downgrade() -> None:
    op.drop_index("ix_ratings_frame_result_id", table_name="ratings")
    op.drop_index("ix_ratings_task_id", table_name="ratings")
    op.drop_table("ratings")
