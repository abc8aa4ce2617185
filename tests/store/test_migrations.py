"""Alembic's migrations build exactly the schema the models describe: on a fresh database upgraded to
head, autogenerate finds nothing to add, drop or retype (a model changed without a migration, or a
migration that does not match its model, fails here).

Server defaults are not compared: migrations 0002 and 0003 give the NOT NULL columns they add to
existing tables a server default, for the rows already there; the models fill those columns on
every insert and do not declare it.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory

from lidarfuzz.store.models import Base
from lidarfuzz.store.store import MIGRATIONS, Store


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
        context = MigrationContext.configure(connection, opts={"compare_type": True})
        assert context.get_current_revision() == ScriptDirectory(str(MIGRATIONS)).get_current_head()
        differences = compare_metadata(context, Base.metadata)
    assert differences == [], "\n".join(map(str, differences))
