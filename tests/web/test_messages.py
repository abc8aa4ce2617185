"""The web app's refusals say what is wrong without the command line's advice (there is no
terminal in a browser); the same errors in a terminal keep it."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from lidarfuzz.store.errors import NotFoundError
from lidarfuzz.store.inventory import get_dataset


def test_a_missing_data_set_is_named_without_cli_advice(client: TestClient) -> None:
    reply = client.delete("/api/datasets/nope")
    assert reply.status_code == 404
    assert reply.json()["detail"] == "no data set called 'nope'"


def test_the_same_error_in_a_terminal_says_what_to_run(client: TestClient, tmp_path: object) -> None:
    from lidarfuzz.store import Store

    store = Store(tmp_path / "ws")  # type: ignore[operator]
    with pytest.raises(NotFoundError) as caught:
        get_dataset(store, "nope")
    store.close()
    assert str(caught.value) == "no data set called 'nope' (lidarfuzz datasets list)"
    assert caught.value.plain == "no data set called 'nope'"
