"""Answers are gzip-compressed for clients that accept it (Starlette's GZipMiddleware): a finding's
pair of point clouds crosses the wire at well under half its size and decompresses to the very bytes
sent uncompressed; small answers and event streams go as they are."""

from __future__ import annotations

import gzip

from fastapi.testclient import TestClient


def test_a_findings_pair_goes_compressed_and_decompresses_to_the_same_bytes(finished: tuple[TestClient, int]) -> None:
    client, task_id = finished
    finding = client.get(f"/api/tasks/{task_id}/findings").json()["items"][0]["id"]
    plain = client.get(f"/api/findings/{finding}/frames", headers={"Accept-Encoding": "identity"})
    assert plain.status_code == 200 and "content-encoding" not in plain.headers
    # the raw body as it crossed the wire (httpx would decode it)
    with client.stream("GET", f"/api/findings/{finding}/frames", headers={"Accept-Encoding": "gzip"}) as reply:
        assert reply.headers["content-encoding"] == "gzip"
        wire = b"".join(reply.iter_raw())
    assert gzip.decompress(wire) == plain.content
    # float32 coordinates of ~2 x 120k points: gzip level 1 keeps about 40 % (measured 3.6 of 8.9 MB)
    assert len(wire) < 0.5 * len(plain.content)


def test_small_answers_and_event_streams_are_not_compressed(finished: tuple[TestClient, int]) -> None:
    client, task_id = finished
    health = client.get("/api/health", headers={"Accept-Encoding": "gzip"})
    assert "content-encoding" not in health.headers  # under the 1 kB minimum
    with client.stream("GET", f"/api/tasks/{task_id}/events", headers={"Accept-Encoding": "gzip"}) as events:
        assert events.headers["content-type"].startswith("text/event-stream")
        assert "content-encoding" not in events.headers


def test_the_front_end_bundle_goes_compressed(finished: tuple[TestClient, int]) -> None:
    client, _ = finished
    plain = client.get("/static/app.js", headers={"Accept-Encoding": "identity"})
    with client.stream("GET", "/static/app.js", headers={"Accept-Encoding": "gzip"}) as reply:
        assert reply.status_code == 200 and reply.headers["content-encoding"] == "gzip"
        wire = b"".join(reply.iter_raw())  # a large file streams: no Content-Length
    assert gzip.decompress(wire) == plain.content
    assert len(wire) < 0.6 * len(plain.content)  # minified JavaScript: about a third
