"""The per-key rate limit counts every WebSocket client message as a request (start/cancel pairs no longer
bypass it); a message over the limit gets an ``error`` ``rate_limited`` with ``retry_after_s``, the
connection stays open."""

from __future__ import annotations

import httpx
import pytest

from tests.service.server import Server
from tests.service.wsclient import Ws

pytestmark = pytest.mark.slow  # spends rate limits against a server of its own

BURST = 6


@pytest.fixture(scope="module")
def server(bundle_dir):
    srv = Server(bundle_dir, env={"RSMT_RATE_LIMIT_PER_S": "0.2", "RSMT_RATE_LIMIT_BURST": str(BURST)})
    srv.start()
    yield srv
    srv.stop()


def test_ws_messages_spend_the_rate_limit(server):
    with Ws(server.ws) as ws:  # the handshake is one request of the bucket
        for i in range(12):  # alternate cancels and pings: each costs one request
            if i % 2:
                ws.send({"type": "ping", "id": i, "request_id": i})
            else:
                ws.send({"type": "cancel", "character": f"c{i}", "request_id": i})
        answers = [ws.recv(timeout=20) for _ in range(12)]
        # Each answer names its message: by the request_id it echoes, else (a pong) by its id.
        by_id: dict[int, dict] = {(a["request_id"] if "request_id" in a else a["id"]): a for a in answers}
        assert sorted(by_id) == list(range(12))
        limited = [i for i in range(12) if by_id[i].get("code") == "rate_limited"]
        served = [i for i in range(12) if i not in limited]
        # BURST tokens: the handshake and the first BURST - 1 messages; the rest are refused (a token may
        # refill during the test at 0.2/s, never more than one or two).
        assert BURST - 1 <= len(served) <= BURST + 1, answers
        assert served == list(range(len(served)))
        for i in served:
            assert by_id[i]["type"] == ("pong" if i % 2 else "error") and by_id[i].get("code") != "rate_limited"
        for i in limited:
            a = by_id[i]
            assert a["type"] == "error" and a["retry_after_s"] >= 1 and "rate limit" in a["message"], a
            assert a.get("character") == (None if i % 2 else f"c{i}")
        # Still open, and the same bucket as the HTTP requests of this address.
        r = httpx.get(server.url + "/v1/model", timeout=10)
        assert r.status_code == 429 and r.json()["error"]["code"] == "rate_limited"
