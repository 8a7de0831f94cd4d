"""X-Forwarded-For is trusted only from configured proxy addresses (RSMT_FORWARDED_ALLOW_IPS): by default a
client rotating the header stays one client for the keyless rate limit, under `rsmt serve` and the tests' uvicorn."""

from __future__ import annotations

import httpx
import pytest

from tests.service.server import Server

pytestmark = pytest.mark.slow  # starts rsmt serve and uvicorn processes behind proxy settings

LIMIT = {"RSMT_RATE_LIMIT_PER_S": "0.5", "RSMT_RATE_LIMIT_BURST": "3"}
SERVE = ["rsmt", "serve", "--host", "127.0.0.1", "--port", "{port}"]


def _statuses(server: Server, forwarded: list[str]) -> list[int]:
    with httpx.Client(base_url=server.url, timeout=30.0) as client:
        return [client.get("/v1/model", headers={"X-Forwarded-For": ip}).status_code for ip in forwarded]


ROTATING = [f"203.0.113.{n}" for n in range(1, 9)]


@pytest.mark.parametrize("command", [SERVE, None], ids=["rsmt-serve", "tests-uvicorn"])
def test_rotating_x_forwarded_for_does_not_bypass_the_rate_limit(bundle_dir, command):
    server = Server(bundle_dir, env=LIMIT, command=command).start()
    try:
        statuses = _statuses(server, ROTATING)
    finally:
        server.stop()
    assert statuses[:3] == [200] * 3 and statuses[3:] == [429] * 5, statuses


def test_a_configured_proxy_address_is_honoured(bundle_dir):
    server = Server(bundle_dir, env={**LIMIT, "RSMT_FORWARDED_ALLOW_IPS": "127.0.0.1"}, command=SERVE).start()
    try:
        rotating = _statuses(server, ROTATING)  # each forwarded client has its own bucket
        repeated = _statuses(server, ["198.51.100.7"] * 5)  # one forwarded client still meets the limit
    finally:
        server.stop()
    assert rotating == [200] * 8, rotating
    assert repeated[:3] == [200] * 3 and repeated[3:] == [429] * 2, repeated
