"""Several replicas, one style store: a real local topology.

``redis-server``, three ``rsmt serve`` replicas on 127.0.0.1 with ``RSMT_STYLE_STORE`` pointing at it, and
``haproxy`` in front (leastconn for HTTP, the WebSocket path pinned by source address), all started and
stopped by PID. A style registered through the load balancer is usable on every replica, survives a
replica's restart, a Redis outage is a clear 503 that heals by itself, and a stream whose replica is killed
mid-stream resumes on another one with every frame of every character delivered (the Python client's
failover). The small random-weight bundle of the other service tests keeps it fast.
"""

from __future__ import annotations

import re
import time
from concurrent.futures import ThreadPoolExecutor

import httpx
import pytest

from tests.service.conftest import bvh, context_clip, target_clip, transition_body, walk
from tests.service.processes import HaproxyProcess, RedisProcess, need
from tests.service.server import Server

pytestmark = pytest.mark.slow
KEY = "replica-test-key-0123456789"
START_S = 240.0  # three replicas warming up at once on a small, busy machine


class Topology:
    def __init__(self, redis: RedisProcess, replicas: list[Server], lb: HaproxyProcess) -> None:
        self.redis, self.replicas, self.lb = redis, replicas, lb


@pytest.fixture(scope="module")
def topology(bundle_dir):
    need("redis-server"), need("haproxy")
    redis = RedisProcess().start()
    env = {"RSMT_STYLE_STORE": redis.url, "RSMT_STYLE_STORE_TIMEOUT_S": "0.5", "RSMT_API_KEYS": KEY,
           "RSMT_WARMUP_MAX_BATCH": "2"}
    replicas = [Server(bundle_dir, env=env, command=["rsmt", "serve", "--host", "127.0.0.1", "--port", "{port}"])
                for _ in range(3)]
    lb = None
    try:
        with ThreadPoolExecutor(3) as pool:
            list(pool.map(lambda s: s.start(START_S), replicas))
        lb = HaproxyProcess([r.port for r in replicas]).start()
        time.sleep(1.0)  # two passing checks (300 ms apart) before HAProxy sends anything
        yield Topology(redis, replicas, lb)
    finally:
        if lb is not None:
            lb.cleanup()
        for r in replicas:
            r.stop()
        redis.cleanup()


def headers() -> dict[str, str]:
    return {"X-API-Key": KEY}


def register_through(url: str, yaw: float = 0.0) -> str:
    body = {"name": f"walk{yaw:g}", "motion": bvh(walk(30, start_yaw_deg=yaw))}
    r = httpx.post(url + "/v1/styles", json=body, headers=headers(), timeout=30)
    assert r.status_code == 201, r.text
    return r.json()["style_id"]


def transition(url: str, style_id: str) -> httpx.Response:
    return httpx.post(url + "/v1/transition", json=transition_body(20, style_id=style_id, deterministic=True),
                      headers=headers(), timeout=60)


def test_style_registered_through_the_lb_is_usable_on_every_replica(topology):
    sid = register_through(topology.lb.url)
    frames = []
    for r in topology.replicas:  # each replica directly: the ones that did not register it encode it on first use
        assert httpx.get(f"{r.url}/v1/styles/{sid}", headers=headers(), timeout=10).json()["style_id"] == sid
        res = transition(r.url, sid)
        assert res.status_code == 200, res.text
        frames.append(res.json()["frames"])
    assert frames[0] == frames[1] == frames[2]  # the same code everywhere: the same frames
    listed = httpx.get(topology.lb.url + "/v1/styles", headers=headers(), timeout=10).json()["styles"]
    assert sid in [s["style_id"] for s in listed]
    other = httpx.get(f"{topology.replicas[2].url}/v1/styles/{sid}",
                      headers={"X-API-Key": "not-the-key-but-long-enough"}, timeout=10)
    assert other.status_code == 401  # and the store is still per key (tests/service/test_style_store.py)


def test_styles_survive_a_replica_restart(topology):
    sid = register_through(topology.replicas[0].url, yaw=30.0)
    replica = topology.replicas[0]
    replica.stop()
    replica.start(START_S)
    res = transition(replica.url, sid)
    assert res.status_code == 200, res.text
    assert res.json()["style_id"] == sid


def test_redis_outage_is_a_clear_503_and_heals_by_itself(topology):
    sid = register_through(topology.lb.url, yaw=60.0)
    direct = topology.replicas[1].url
    topology.redis.stop()
    try:
        res = transition(direct, sid)
        assert res.status_code == 503 and res.headers["retry-after"] == "1"
        err = res.json()["error"]
        assert err["code"] == "style_store_unavailable" and re.search(r"127\.0\.0\.1:\d+/0", err["message"])
        reg = httpx.post(topology.lb.url + "/v1/styles", json={"name": "x", "motion": bvh(walk(30))},
                         headers=headers(), timeout=30)
        assert reg.status_code == 503 and reg.json()["error"]["code"] == "style_store_unavailable"
        inline = httpx.post(direct + "/v1/transition", json=transition_body(20), headers=headers(), timeout=60)
        assert inline.status_code == 200  # an inline style needs no store
        assert httpx.get(direct + "/v1/health/ready", timeout=5).status_code == 200  # still ready: not a restart
    finally:
        topology.redis.start()
    deadline = time.monotonic() + 15
    while (res := transition(direct, sid)).status_code != 200 and time.monotonic() < deadline:
        time.sleep(0.2)
    assert res.status_code == 200, res.text  # the same process, the same style (Redis kept it)


def test_stream_resumes_on_another_replica_when_its_replica_dies(topology):
    pytest.importorskip("rsmt_client")
    from rsmt_client import StreamClient
    from rsmt_client.motion import Poses  # noqa: F401  (the client package under test)

    sid = register_through(topology.lb.url, yaw=90.0)
    frames = 60
    with StreamClient(topology.lb.url, api_key=KEY, encoding="binary", failover=True) as client:
        chars = [client.start(bvh(context_clip()), bvh(target_clip(yaw=15.0 * i)), frames, style_id=sid, seed=i,
                              pace="realtime") for i in range(3)]
        got: dict[str, list] = {c: [] for c in chars}
        ended: set[str] = set()
        killed = None
        deadline = time.monotonic() + 60
        while len(ended) < len(chars) and time.monotonic() < deadline:
            item = client.recv(timeout=30)
            if isinstance(item, dict):
                assert item.get("type") != "error", item
                if item.get("type") == "end":
                    ended.add(item["character"])
                continue
            got[item.character].append(item)
            if killed is None and sum(len(v) for v in got.values()) >= 30:
                killed = live_replica(topology)
                killed.proc.kill()  # the replica dies: no close frame, no drain
        assert killed is not None and client.resumes >= 1
    for c in chars:
        assert [f.seq for f in got[c]] == list(range(frames)), c  # every frame, once, in order
        assert got[c][-1].remaining == 0
    killed.start(START_S)  # leave three replicas for the next test


def live_replica(topology: Topology) -> Server:
    """The replica holding the stream (the one with live characters, from its metrics)."""
    for r in topology.replicas:
        text = httpx.get(r.url + "/metrics", headers=headers(), timeout=5).text
        m = re.search(r"^rsmt_live_streams (\d+)", text, re.M)
        if m and int(m.group(1)) > 0:
            return r
    raise AssertionError("no replica has a live stream")
