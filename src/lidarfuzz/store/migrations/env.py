"""Alembic environment: migrations run on the connection the store hands over."""

from __future__ import annotations

from alembic import context

from lidarfuzz.store.models import Base

connection = context.config.attributes.get("connection")
if connection is None:
    raise RuntimeError("lidarfuzz migrations run through lidarfuzz.store.Store.migrate(), which passes a connection")
context.configure(connection=connection, target_metadata=Base.metadata, render_as_batch=True)
with context.begin_transaction():
    context.run_migrations()
