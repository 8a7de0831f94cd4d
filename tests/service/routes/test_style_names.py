"""Per-key style names and no timing tell for shared content (issue 53, item 4), with the memory store and with
Redis: a clip that key B registered under a private name, registered by key A under its own name, shows A only
A's name (in the 201, in GET and in the list), and registering a clip another key already has takes as long as
registering one nobody has (the median time of a bounded number of pairs, compared within one run)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Iterator

import httpx
import pytest

from tests.service.conftest import bvh, walk
from tests.service.server import Server, server_with_style_store

pytestmark = [pytest.mark.slow, pytest.mark.alone]  # Redis and timed registrations

KEY_A, KEY_B = "names-key-a-0123456789abcdef", "names-key-b-0123456789abcdef"
SECRET = "B-private-name-4242"
PAIRS = 12


@pytest.fixture(scope="module", params=["memory", "redis"])
def server(request, bundle_dir) -> Iterator[Server]:
    with server_with_style_store(request.param, bundle_dir, {"RSMT_API_KEYS": f"{KEY_A},{KEY_B}"}) as srv:
        yield srv


def _register(server: Server, key: str, motion: dict, name: str) -> tuple[httpx.Response, float]:
    started = time.perf_counter()
    r = httpx.post(server.url + "/v1/styles", json={"motion": motion, "name": name}, headers={"X-API-Key": key},
                   timeout=60)
    return r, time.perf_counter() - started


def test_one_key_never_sees_another_keys_name(server):
    shared = bvh(walk(90, start_yaw_deg=17.0))
    b, _ = _register(server, KEY_B, shared, SECRET)
    assert b.status_code == 201 and b.json()["name"] == SECRET, b.text
    a, _ = _register(server, KEY_A, shared, "A-name")
    assert a.status_code == 201, a.text
    sid = a.json()["style_id"]
    assert sid == b.json()["style_id"]  # the same content: one id, deduplicated below the keys
    assert a.json()["name"] == "A-name" and a.json()["cached"] is False, a.text
    got = httpx.get(f"{server.url}/v1/styles/{sid}", headers={"X-API-Key": KEY_A}, timeout=30)
    listed = httpx.get(server.url + "/v1/styles", headers={"X-API-Key": KEY_A}, timeout=30)
    assert got.json()["name"] == "A-name", got.text
    assert [s["name"] for s in listed.json()["styles"] if s["style_id"] == sid] == ["A-name"], listed.text
    for r in (a, got, listed):
        assert SECRET not in r.text
    # B keeps its own name; A registering it again keeps A's.
    again, _ = _register(server, KEY_A, shared, "A-name")
    assert again.json()["cached"] is True and again.json()["name"] == "A-name", again.text
    mine = httpx.get(f"{server.url}/v1/styles/{sid}", headers={"X-API-Key": KEY_B}, timeout=30)
    assert mine.json()["name"] == SECRET, mine.text


def test_registering_a_clip_another_key_has_is_not_faster(server):
    shared_s: list[float] = []
    fresh_s: list[float] = []
    for i in range(PAIRS):
        shared, fresh = bvh(walk(240, start_yaw_deg=1.0 + i)), bvh(walk(240, start_yaw_deg=101.0 + i))
        assert _register(server, KEY_B, shared, f"b{i}")[0].status_code == 201
        for motion, times in ((shared, shared_s), (fresh, fresh_s)) if i % 2 else ((fresh, fresh_s), (shared, shared_s)):
            r, seconds = _register(server, KEY_A, motion, f"a{i}")
            assert r.status_code == 201 and r.json()["cached"] is False, r.text
            times.append(seconds)
    shared_ms, fresh_ms = statistics.median(shared_s) * 1e3, statistics.median(fresh_s) * 1e3
    print(f"registering a clip another key has: median {shared_ms:.1f} ms; one nobody has: {fresh_ms:.1f} ms "
          f"(ratio {shared_ms / fresh_ms:.2f}, {PAIRS} pairs)")
    assert shared_ms > 0.85 * fresh_ms
