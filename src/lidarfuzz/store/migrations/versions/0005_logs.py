"""logs, segments and coverage records: Neves et al.'s meta-model (field-test and generated logs,
their partitions into segments, and what a log or a segment covered for a system version)

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-23 17:00:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "logs",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=200), nullable=False),
        sa.Column("kind", sa.Enum("field_test", "generated", name="log_kind", native_enum=False, length=16),
                  nullable=False),
        sa.Column("dataset_id", sa.Integer(), nullable=True),
        sa.Column("path", sa.Text(), nullable=False),
        sa.Column("format", sa.String(length=40), nullable=False),
        sa.Column("frame_count", sa.Integer(), nullable=False),
        sa.Column("parent_id", sa.Integer(), nullable=True),
        sa.Column("heuristic", sa.String(length=40), nullable=False),
        sa.Column("strategy", sa.String(length=100), nullable=False),
        sa.Column("generation", sa.JSON(), nullable=True),
        sa.Column("added_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(["dataset_id"], ["datasets.id"], ondelete="SET NULL"),
        sa.ForeignKeyConstraint(["parent_id"], ["logs.id"], ondelete="RESTRICT"),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("name"),
    )
    op.create_index(op.f("ix_logs_parent_id"), "logs", ["parent_id"], unique=False)
    op.create_table(
        "log_segments",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("log_id", sa.Integer(), nullable=False),
        sa.Column("size", sa.Integer(), nullable=False),
        sa.Column("index", sa.Integer(), nullable=False),
        sa.Column("first_frame", sa.Integer(), nullable=False),
        sa.Column("last_frame", sa.Integer(), nullable=False),
        sa.Column("first_frame_id", sa.String(length=200), nullable=False),
        sa.Column("last_frame_id", sa.String(length=200), nullable=False),
        sa.ForeignKeyConstraint(["log_id"], ["logs.id"], ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("log_id", "size", "index"),
    )
    op.create_index(op.f("ix_log_segments_log_id"), "log_segments", ["log_id"], unique=False)
    op.create_table(
        "coverage_records",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("log_id", sa.Integer(), nullable=True),
        sa.Column("segment_id", sa.Integer(), nullable=True),
        sa.Column("fingerprint", sa.String(length=64), nullable=False),
        sa.Column("criterion", sa.String(length=16), nullable=False),
        sa.Column("target", sa.String(length=500), nullable=False),
        sa.Column("covered", sa.JSON(), nullable=False),
        sa.Column("covered_count", sa.Integer(), nullable=False),
        sa.Column("total_count", sa.Integer(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.CheckConstraint("(log_id IS NULL) <> (segment_id IS NULL)", name="ck_coverage_log_or_segment"),
        sa.ForeignKeyConstraint(["log_id"], ["logs.id"], ondelete="CASCADE"),
        sa.ForeignKeyConstraint(["segment_id"], ["log_segments.id"], ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("id"),
    )
    op.create_index(op.f("ix_coverage_records_log_id"), "coverage_records", ["log_id"], unique=False)
    op.create_index(op.f("ix_coverage_records_segment_id"), "coverage_records", ["segment_id"], unique=False)


def downgrade() -> None:
    op.drop_index(op.f("ix_coverage_records_segment_id"), table_name="coverage_records")
    op.drop_index(op.f("ix_coverage_records_log_id"), table_name="coverage_records")
    op.drop_table("coverage_records")
    op.drop_index(op.f("ix_log_segments_log_id"), table_name="log_segments")
    op.drop_table("log_segments")
    op.drop_index(op.f("ix_logs_parent_id"), table_name="logs")
    op.drop_table("logs")
