"""typed JSON columns: a subtask's plan and resumable state apart from its results, a task's kind
options in one place, no NaN in any JSON column

Subtasks held their inputs (the relation specs to check, a search's state) inside ``results``;
they move to ``plan`` and ``state``. A task's options held the relation choice already stored in
``tasks.relations`` (dropped) and a search's config as ``search`` (now ``kind_options``). A pending
task's summary is JSON ``null``, not ``{}``. No table is rebuilt: on SQLite that would drop it, and
dropping ``tasks`` cascades to every subtask. A frame result gets ``output``: what a system that does
not answer in boxes returned (a steering angle, a controller's commands), in its kind's own
contract. NaN and ±Inf written by earlier versions (SQLite kept them as bare ``NaN`` tokens no JSON
reader accepts) become ``null``.

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-23 15:00:00
"""

from __future__ import annotations

import math
from typing import Any

import sqlalchemy as sa
from alembic import op

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None

JSON_COLUMNS = {
    "datasets": ("options",),
    "models": ("options",),
    "tasks": ("operators", "relations", "summary", "options"),
    "subtasks": ("operator", "results"),
    "frame_results": ("params", "failure", "relations"),
    "findings": ("detail", "replay"),
}


def _safe(value: Any) -> Any:
    if isinstance(value, float):
        return None if math.isnan(value) or math.isinf(value) else value
    if isinstance(value, dict):
        return {k: _safe(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_safe(v) for v in value]
    return value


SQL_NULL = {"failure", "state"}  # None is SQL NULL there; elsewhere JSON null (a task's summary before it is done)


def _table(name: str, *columns: str) -> sa.TableClause:
    return sa.table(name, sa.column("id", sa.Integer),
                    *(sa.column(c, sa.JSON(none_as_null=c in SQL_NULL)) for c in columns))


def upgrade() -> None:
    with op.batch_alter_table("subtasks", schema=None) as batch_op:
        batch_op.add_column(sa.Column("plan", sa.JSON(), nullable=False, server_default="{}"))
        batch_op.add_column(sa.Column("state", sa.JSON(), nullable=True))
    with op.batch_alter_table("frame_results", schema=None) as batch_op:
        batch_op.add_column(sa.Column("output", sa.JSON(), nullable=True))

    connection = op.get_bind()
    for name, columns in JSON_COLUMNS.items():
        table = _table(name, *columns)
        for row in connection.execute(sa.select(table)).mappings().all():
            values = {c: _safe(row[c]) for c in columns}
            if values != {c: row[c] for c in columns} or name in ("tasks", "subtasks"):
                if name == "subtasks":
                    results = dict(values["results"] or {})
                    plan = {"relation_specs": results.pop("relation_specs", [])}
                    state = results.pop("state", None)
                    full = _table(name, *columns, "plan", "state")
                    values.update(results=results, plan=plan, state=state)
                    connection.execute(sa.update(full).where(full.c.id == row["id"]).values(**values))
                    continue
                if name == "tasks":
                    options = dict(values["options"] or {})
                    options.pop("relations", None)
                    search = options.pop("search", None)
                    if search is not None:
                        options["kind_options"] = search
                    values["options"] = options
                    values["summary"] = values["summary"] or None
                connection.execute(sa.update(table).where(table.c.id == row["id"]).values(**values))


def downgrade() -> None:
    connection = op.get_bind()
    tasks = _table("tasks", "options", "summary", "relations")
    for row in connection.execute(sa.select(tasks)).mappings().all():
        options = dict(row["options"] or {})
        if "kind_options" in options:
            options["search"] = options.pop("kind_options")
        relations = row["relations"] or []
        options["relations"] = "auto" if relations == ["auto"] else relations
        connection.execute(sa.update(tasks).where(tasks.c.id == row["id"]).values(
            options=options, summary=row["summary"] or {}))
    subtasks = _table("subtasks", "results", "plan", "state")
    for row in connection.execute(sa.select(subtasks)).mappings().all():
        results = dict(row["results"] or {})
        results["relation_specs"] = (row["plan"] or {}).get("relation_specs", [])
        if row["state"] is not None:
            results["state"] = row["state"]
        connection.execute(sa.update(subtasks).where(subtasks.c.id == row["id"]).values(results=results))
    with op.batch_alter_table("frame_results", schema=None) as batch_op:
        batch_op.drop_column("output")
    with op.batch_alter_table("subtasks", schema=None) as batch_op:
        batch_op.drop_column("state")
        batch_op.drop_column("plan")
