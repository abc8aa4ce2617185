"""sut_outputs.source: the content digest of the frame an input was made from, indexed with the
fingerprint, so a worker reads every cached output of a frame in one query instead of one per unit

Revision ID: 0009
Revises: 0008
Create Date: 2026-11-24 10:40:00
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0009"
down_revision = "0008"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("sut_outputs") as batch:
        batch.add_column(sa.Column("source", sa.String(length=64), nullable=True))
        batch.create_index("ix_sut_outputs_source", ["fingerprint", "source"])


def downgrade() -> None:
    with op.batch_alter_table("sut_outputs") as batch:
        batch.drop_index("ix_sut_outputs_source")
        batch.drop_column("source")
