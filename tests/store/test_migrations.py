"""Alembic's migrations build exactly the schema the models describe: on a fresh database upgraded to
head, autogenerate finds nothing to add, drop or retype (a model changed without a migration, or a
migration that does not match its model, fails here).

Server defaults are compared too: migrations 0002–0004 give the NOT NULL columns they add to existing
tables a server default (for the rows already there), and the models declare the same one, so a
table created from the models and one built by the migrations agree.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any

import pytest
import sqlalchemy as sa
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory

from lidarfuzz.store.models import Base
from lidarfuzz.store.store import MIGRATIONS, Store


def literal(default: str) -> str:
    """A server default as written, without the quoting, parentheses and casts the databases add on
    reflection: SQLite gives ``('')`` and ``'{}'``, PostgreSQL ``''::character varying`` and ``'{}'::json``."""
    default = re.sub(r"^\((.*)\)$", r"\1", default, flags=re.DOTALL)
    default = re.sub(r"::[a-z ]+$", "", default)
    quoted = re.fullmatch(r"'(.*)'", default, flags=re.DOTALL)
    return quoted.group(1).replace("''", "'") if quoted else default


def server_defaults_differ(context: MigrationContext, inspected: sa.Column[Any], metadata: sa.Column[Any],
                           inspected_default: str | None, metadata_default: Any, rendered: str | None) -> bool:
    """Alembic's own comparison cannot be used: on SQLite it reads ``('')`` as different from ``''``;
    on PostgreSQL it asks the server ``SELECT '{}'::json = '{}'``, and ``json`` has no ``=``."""
    if inspected_default is None or rendered is None:
        return inspected_default != rendered
    return literal(inspected_default) != literal(rendered)


@pytest.fixture(params=["sqlite", "postgresql"])
def migrated(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Store]:
    if request.param == "sqlite":
        store = Store(tmp_path_factory.mktemp("workspace"))
    else:
        store = Store(request.getfixturevalue("fresh_postgres_url"))
    try:
        yield store
    finally:
        store.close()


def test_autogenerate_finds_no_difference_between_migrations_and_models(migrated: Store) -> None:
    with migrated.engine.connect() as connection:
        context = MigrationContext.configure(connection, opts={"compare_type": True,
                                                                 "compare_server_default": server_defaults_differ})
        assert context.get_current_revision() == ScriptDirectory(str(MIGRATIONS)).get_current_head()
        differences = compare_metadata(context, Base.metadata)
    assert differences == [], "\n".join(map(str, differences))
