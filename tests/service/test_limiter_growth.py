"""The failed-login limiter against a real `rsmt serve` (issue 53, item 2): requests without a key from ever
new addresses (forwarded by a trusted proxy, as an IPv6 /64's worth of addresses would arrive) are answered
as fast with 20,000 addresses tracked as with none, and what it tracks stays under its cap.

The requests are pipelined on a few keep-alive connections so that the server, not the test's client, sets
the pace; the rates are compared within one run (their ratio), never against a fixed figure."""

from __future__ import annotations

import re
import socket
import time
from collections.abc import Iterator

import pytest

from service.ratelimit import RateLimiter
from tests.service.server import Server

pytestmark = [pytest.mark.slow, pytest.mark.alone]  # 20,000 failed logins from new addresses

KEY = "limiter-growth-key-0123456789"
SERVE = ["rsmt", "serve", "--host", "127.0.0.1", "--port", "{port}"]
# The pipelined-request budget (RSMT_PIPELINED_REQUESTS_PER_S, 100/s by default) would set the pace instead of
# the limiter: off here, where the cost of tracking addresses is what is measured.
ENV = {"RSMT_API_KEYS": KEY, "RSMT_FORWARDED_ALLOW_IPS": "127.0.0.1", "RSMT_PIPELINED_REQUESTS_PER_S": "0"}
BATCH = 200  # pipelined requests per write


@pytest.fixture(scope="module")
def server(bundle_dir) -> Iterator[Server]:
    srv = Server(bundle_dir, env=ENV, command=SERVE).start()
    yield srv
    srv.stop()


def _address(n: int) -> str:
    return f"10.{(n >> 16) & 255}.{(n >> 8) & 255}.{n & 255}"


def _keyless(port: int, first: int, count: int) -> tuple[float, dict[bytes, int]]:
    """``count`` keyless requests, each from a new forwarded address ``first``, ``first + 1``, ...; returns
    requests per second and the count of each status."""
    statuses: dict[bytes, int] = {}
    started = time.perf_counter()
    with socket.create_connection(("127.0.0.1", port), timeout=30) as sock:
        for base in range(first, first + count, BATCH):
            n = min(BATCH, first + count - base)
            sock.sendall(b"".join(b"GET /v1/model HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Forwarded-For: %s\r\n\r\n"
                                  % _address(base + i).encode() for i in range(n)))
            data, seen = b"", 0
            while seen < n:
                chunk = sock.recv(1 << 16)
                assert chunk, "the server closed the connection"
                data += chunk
                seen = data.count(b"HTTP/1.1 ")
            for code in re.findall(rb"HTTP/1\.1 (\d{3}) ", data):
                statuses[code] = statuses.get(code, 0) + 1
    return count / (time.perf_counter() - started), statuses


def test_failed_logins_from_new_addresses_cost_the_same_at_20000_tracked(server):
    _keyless(server.port, 1_000_000, 400)  # warm the connection path
    empty, s0 = _keyless(server.port, 0, 2_000)
    _keyless(server.port, 2_000, 18_000)  # now 20,000 addresses are tracked
    full, s1 = _keyless(server.port, 20_000, 2_000)
    print(f"keyless requests from new addresses: {empty:.0f}/s with 0-2,000 tracked, {full:.0f}/s with "
          f"20,000-22,000 tracked (ratio {full / empty:.2f})")
    assert s0 == {b"401": 2_000} and s1 == {b"401": 2_000}, (s0, s1)
    assert full > 0.6 * empty


def test_the_tracked_addresses_stay_under_the_cap():
    now = [0.0]
    limiter = RateLimiter(1.0, 5, clock=lambda: now[0], max_keys=1_000)
    for n in range(5_000):
        now[0] += 1e-4  # none has refilled: each is still tracked when the cap is reached
        assert limiter.take(_address(n)) == 0.0
        assert len(limiter) <= 1_000
    # The most recent ones are those kept: the newest address still meets its own limit.
    for _ in range(4):
        limiter.take(_address(4_999))
    assert limiter.take(_address(4_999)) > 0
