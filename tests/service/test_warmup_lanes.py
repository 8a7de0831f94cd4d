"""The warm-up runs a stream start on every stream-setup thread and a job on every work thread before the server
is ready, so that the first ``start`` (or request) does not create its thread and pay its first torch calls."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from tests.service.conftest import bvh, walk
from tests.service.server import Server
from tests.service.wsclient import Ws, start_message

pytestmark = pytest.mark.slow  # warms every lane of a server of its own


@pytest.fixture(scope="module")
def server(bundle_dir):
    srv = Server(bundle_dir, command=[sys.executable, "-m", "rsmt_cli.main", "serve", "--host", "127.0.0.1",
                                      "--port", "{port}"],
                 env={"RSMT_LOG_LEVEL": "info", "RSMT_LOG_FORMAT": "json", "RSMT_REQUEST_THREADS": "2"})
    srv.start()
    yield srv
    srv.stop()


def _warmed_up(server: Server) -> list[dict]:
    records = []
    for line in Path(server.log.name).read_text().splitlines():
        try:
            record = json.loads(line)
        except ValueError:
            continue
        if isinstance(record, dict) and record.get("msg") == "warmed up":
            records.append(record)
    return records


def test_every_stream_setup_and_work_thread_is_warmed_before_ready(server):
    records = _warmed_up(server)
    assert len(records) == 1, records  # one model
    assert records[0]["stream_start_ms"] > 0, records[0]
    assert records[0]["work_threads_ms"] > 0, records[0]  # RSMT_REQUEST_THREADS=2: both work threads too


def test_streams_still_start_after_the_warm_up(server):
    with Ws(server.ws) as ws:
        ws.send(start_message("hero", 12, style=bvh(walk(30))))
        out = ws.run({"hero"}, timeout=60)
    assert len(out["hero"]["frames"]) == 12 and out["hero"]["end"]["reason"] == "arrived"
