"""No timing tell for inline style clips across keys (issue 64, item 5): a transition whose inline ``style``
clip key B already registered costs key A as much server time (``timing_ms.parse``, where the clip is
encoded) as one with a clip nobody has sent; the median of a bounded number of interleaved pairs, compared
within one run."""

from __future__ import annotations

import statistics
from collections.abc import Iterator

import httpx
import pytest

from tests.service.conftest import bvh, transition_body, walk
from tests.service.server import Server

pytestmark = [pytest.mark.slow, pytest.mark.alone]  # timed transitions against a server of its own

KEY_A, KEY_B = "inline-key-a-0123456789abcdef", "inline-key-b-0123456789abcdef"
PAIRS = 14


@pytest.fixture(scope="module")
def server(bundle_dir) -> Iterator[Server]:
    srv = Server(bundle_dir, env={"RSMT_API_KEYS": f"{KEY_A},{KEY_B}"}).start()
    yield srv
    srv.stop()


def _parse_ms(client: httpx.Client, style: dict) -> float:
    r = client.post("/v1/transition", json=transition_body(10, style=style), headers={"X-API-Key": KEY_A})
    assert r.status_code == 200, r.text
    return float(r.json()["timing_ms"]["parse"])


def test_an_inline_clip_another_key_registered_is_not_faster(server):
    shared_ms: list[float] = []
    fresh_ms: list[float] = []
    with httpx.Client(base_url=server.url, timeout=60) as client:
        _parse_ms(client, bvh(walk(240, start_yaw_deg=-50.0)))  # the first request warms what every request uses
        for i in range(PAIRS):
            shared, fresh = bvh(walk(240, start_yaw_deg=3.0 + i)), bvh(walk(240, start_yaw_deg=133.0 + i))
            r = client.post("/v1/styles", json={"motion": shared, "name": f"b{i}"}, headers={"X-API-Key": KEY_B})
            assert r.status_code == 201, r.text
            order = ((shared, shared_ms), (fresh, fresh_ms)) if i % 2 else ((fresh, fresh_ms), (shared, shared_ms))
            for motion, times in order:
                times.append(_parse_ms(client, motion))
    shared_med, fresh_med = statistics.median(shared_ms), statistics.median(fresh_ms)
    print(f"timing_ms.parse with an inline clip another key registered: median {shared_med:.2f} ms; with one "
          f"nobody has: {fresh_med:.2f} ms (ratio {shared_med / fresh_med:.2f}, {PAIRS} pairs)")
    assert shared_med > 0.85 * fresh_med
