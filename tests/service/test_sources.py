"""RSMT_SOURCE through a real server: a bundle with a motion database served by matching and by the hybrid, what
GET /v1/model says, and a server that cannot start says why."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from tests.model.nets.walk_database import walk_bundle
from tests.service.conftest import transition_body
from tests.service.server import Server


@pytest.fixture(scope="module")
def database_bundle(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return walk_bundle().save(tmp_path_factory.mktemp("db") / "rsmt")


@pytest.mark.parametrize("source", ["matching", "hybrid"])
def test_a_database_bundle_is_served_by_its_source(database_bundle: Path, source: str) -> None:
    server = Server(database_bundle, env={"RSMT_SOURCE": source}).start()
    try:
        assert httpx.get(server.url + "/v1/model", timeout=10.0).json()["source"] == source
        reply = httpx.post(server.url + "/v1/transition", json=transition_body(frames=30), timeout=60.0)
        assert reply.status_code == 200, reply.text
        assert len(reply.json()["frames"]) == 30
    finally:
        server.stop()


def test_a_source_the_bundle_cannot_serve_stops_the_server_with_the_fix(bundle_dir: Path) -> None:
    server = Server(bundle_dir, env={"RSMT_SOURCE": "matching"})
    with pytest.raises(RuntimeError, match="rsmt bundle database"):
        server.start(timeout_s=60.0)
    server.stop()
