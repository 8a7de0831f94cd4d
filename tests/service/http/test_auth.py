"""API keys (X-API-Key, Bearer, ?token= on the WebSocket) and the per-key rate limit (429 + Retry-After)."""

from __future__ import annotations

import asyncio

import httpx
import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from service.app import create_app
from service.ratelimit import RateLimiter
from service.settings import Settings
from tests.service.server import Server

KEY_A, KEY_B, KEY_C = "key-a-0123456789abcdef", "key-b-0123456789abcdef", "key-c-0123456789abcdef"


@pytest.fixture(scope="module")
def server(bundle_dir):
    srv = Server(bundle_dir, env={"RSMT_API_KEYS": f"{KEY_A},{KEY_B},{KEY_C}", "RSMT_RATE_LIMIT_PER_S": "2",
                                  "RSMT_RATE_LIMIT_BURST": "5"}).start()
    yield srv
    srv.stop()


def test_probes_need_no_key(server):
    assert httpx.get(server.url + "/v1/health/live").status_code == 200
    assert httpx.get(server.url + "/v1/health/ready").status_code == 200


@pytest.mark.parametrize("path", ["/metrics", "/docs", "/redoc", "/openapi.json", "/docs/static/swagger-ui.css"])
def test_metrics_and_docs_need_a_key_when_keys_are_on(server, path):
    r = httpx.get(server.url + path)
    assert r.status_code == 401 and r.json()["error"]["code"] == "unauthorized", (path, r.status_code)
    assert r.headers["www-authenticate"] == "Bearer"
    assert httpx.get(server.url + path, headers={"X-API-Key": KEY_A}).status_code == 200, path
    assert httpx.get(server.url + path, headers={"Authorization": f"Bearer {KEY_A}"}).status_code == 200, path


def test_a_setting_opens_metrics_and_docs(bundle_dir):
    async def statuses(settings: Settings) -> list[int]:
        async with httpx.AsyncClient(transport=httpx.ASGITransport(create_app(settings)), base_url="http://t") as c:
            return [(await c.get(path)).status_code for path in ("/metrics", "/docs", "/openapi.json", "/v1/styles")]

    keyed = Settings(models=bundle_dir, api_keys=[KEY_A])
    assert asyncio.run(statuses(keyed.model_copy(update={"open_docs_and_metrics": True}))) == [200, 200, 200, 401]
    assert asyncio.run(statuses(Settings(models=bundle_dir)))[:3] == [200, 200, 200]  # keys off: open


def test_http_keys(server):
    r = httpx.get(server.url + "/v1/model")
    assert r.status_code == 401 and r.json()["error"]["code"] == "unauthorized"
    assert r.headers["www-authenticate"] == "Bearer"
    r = httpx.get(server.url + "/v1/model", headers={"X-API-Key": "wrong-key-0123456789"})
    assert r.status_code == 401 and "unknown API key" in r.json()["error"]["message"]
    assert httpx.get(server.url + "/v1/model", headers={"X-API-Key": KEY_A}).status_code == 200
    assert httpx.get(server.url + "/v1/model", headers={"Authorization": f"Bearer {KEY_A}"}).status_code == 200
    # A query token is for WebSockets only (browsers cannot set their headers).
    assert httpx.get(server.url + f"/v1/model?token={KEY_A}").status_code == 401


def test_websocket_keys(server):
    with pytest.raises(InvalidStatus) as info:
        connect(server.ws, proxy=None, open_timeout=20)
    assert info.value.response.status_code == 401
    assert b"unauthorized" in info.value.response.body
    with connect(server.ws + f"?token={KEY_B}", proxy=None, open_timeout=20) as ws:
        assert '"hello"' in ws.recv(20)
    with connect(server.ws, proxy=None, open_timeout=20, additional_headers={"X-API-Key": KEY_B}) as ws:
        assert '"hello"' in ws.recv(20)


def test_websocket_key_is_checked_before_the_encoding(server):
    with pytest.raises(InvalidStatus) as info:  # no key: the bad encoding is not even looked at
        connect(server.ws + "?encoding=xml", proxy=None, open_timeout=20)
    assert info.value.response.status_code == 401 and b"unauthorized" in info.value.response.body
    with pytest.raises(InvalidStatus) as info:
        connect(server.ws + f"?encoding=xml&token={KEY_B}", proxy=None, open_timeout=20)
    assert info.value.response.status_code == 422 and b"validation_error" in info.value.response.body


def test_rate_limit_per_key(server):
    codes = [httpx.get(server.url + "/v1/model", headers={"X-API-Key": KEY_C}) for _ in range(8)]
    statuses = [r.status_code for r in codes]
    assert statuses[:5] == [200] * 5 and 429 in statuses[5:], statuses
    limited = next(r for r in codes if r.status_code == 429)
    assert limited.json()["error"]["code"] == "rate_limited" and int(limited.headers["retry-after"]) >= 1
    # Another key has its own bucket.
    assert httpx.get(server.url + "/v1/styles", headers={"X-API-Key": KEY_A}).status_code == 200
    assert server.ready() == 200


def test_token_bucket():
    now = [0.0]
    rl = RateLimiter(rate_per_s=2.0, burst=3, clock=lambda: now[0])
    assert [rl.take("k") for _ in range(3)] == [0.0, 0.0, 0.0]
    assert rl.take("k") == pytest.approx(0.5)
    now[0] += 0.5
    assert rl.take("k") == 0.0
    assert rl.take("other") == 0.0
    assert RateLimiter(0.0, 1).take("k") == 0.0  # off
