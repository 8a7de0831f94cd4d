"""Requests without a valid key are refused before their body is read (issue 24, row 3), and a flood of them
from one address gets 429 with Retry-After after ``RSMT_AUTH_FAILURE_BURST`` failures."""

from __future__ import annotations

import socket

import httpx
import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from tests.service.raw_reads import read_until
from tests.service.server import Server

pytestmark = pytest.mark.slow  # floods a server with refused requests

KEY = "key-body-0123456789abcdef"
BURST = 5


@pytest.fixture(scope="module")
def server(bundle_dir):
    srv = Server(bundle_dir, env={"RSMT_API_KEYS": KEY}).start()
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def flood_server(bundle_dir):
    # Refilled at one failure per 1000 s: no token comes back while the test runs.
    srv = Server(bundle_dir, env={"RSMT_API_KEYS": KEY, "RSMT_AUTH_FAILURE_BURST": str(BURST),
                                  "RSMT_AUTH_FAILURE_RATE_PER_S": "0.001"}).start()
    yield srv
    srv.stop()


def _head_of_answer(port: int, key_header: bytes, path: bytes = b"/v1/transition") -> bytes:
    """Send the headers of an 850 KB POST and only its first KB, then read the answer (never sending the rest)."""
    with socket.create_connection(("127.0.0.1", port), timeout=15) as s:
        s.sendall(b"POST " + path + b" HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n" + key_header
                  + b"Content-Length: 850000\r\n\r\n" + b'{"context": {"bvh": "' + b"x" * 1000)
        return read_until(s, b"\r\n\r\n", 65536)  # a server waiting for the rest of the body times this out: the test fails


@pytest.mark.parametrize("key_header", [b"X-API-Key: wrong-key-0123456789abcdef\r\n", b""], ids=["wrong", "missing"])
@pytest.mark.parametrize("path", [b"/v1/transition", b"/v1/styles"])
def test_refused_before_the_body_is_read(server, key_header, path):
    answer = _head_of_answer(server.port, key_header, path)
    assert answer.startswith(b"HTTP/1.1 401 "), answer[:200]
    assert b"www-authenticate: bearer" in answer.lower()


def test_a_valid_key_still_reads_the_body(server):
    r = httpx.post(server.url + "/v1/styles", json={"name": "x", "motion": {"bvh": "not a bvh"}}, headers={"X-API-Key": KEY})
    assert r.status_code == 422 and r.json()["error"]["code"] == "bad_motion", r.text


def test_wrong_key_flood_gets_429_after_the_bound(flood_server):
    url, wrong = flood_server.url, {"X-API-Key": "wrong-key-0123456789abcdef"}
    with httpx.Client(base_url=url, timeout=15) as c:
        statuses = [c.get("/v1/model", headers=wrong).status_code for _ in range(BURST)]
        assert statuses == [401] * BURST
        for _ in range(3):
            r = c.post("/v1/transition", headers=wrong, json={})
            assert r.status_code == 429 and r.json()["error"]["code"] == "rate_limited", r.text
            assert int(r.headers["retry-after"]) >= 1
        assert c.get("/v1/model").status_code == 429  # a missing key counts as a failure too
    with pytest.raises(InvalidStatus) as refused:  # and so does a WebSocket handshake's
        connect(flood_server.ws + "?token=wrong-key-0123456789abcdef", proxy=None, open_timeout=15)
    assert refused.value.response.status_code == 429
    with httpx.Client(base_url=url, timeout=15) as c:
        # The address is limited for failures only: the probes stay open and a valid key is served.
        assert c.get("/v1/health/ready").status_code == 200
        assert c.get("/v1/model", headers={"X-API-Key": KEY}).status_code == 200
