"""The style stores (service/styles/store): the clip codec, and the Redis store against a real redis-server:
ownership as in the memory book, the per-key cap, TTL, encoding on another replica's engine, and a Redis
outage answered with ``style_store_unavailable`` until Redis is back (no restart of the service side)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest
import torch

from model.data.synthetic import synthetic_walk
from model.inference.bundle import Bundle
from model.inference.engine import Engine
from model.inference.style_sets import encode_style_set
from service.caller import Caller
from service.errors import ServiceError
from service.settings import Settings
from service.styles.store import style_store_factory
from service.styles.store.codec import CodecError, StoredClip, decode_clip, encode_clip
from service.styles.store.memory import MemoryStyleStore
from service.styles.store.redis_store import RedisStyleStore, connect, safe_address
from tests.service.processes import RedisProcess

A, B, ADMIN = Caller("a"), Caller("b"), Caller("admin", admin=True)


def test_codec_round_trip_and_refusals():
    rng = np.random.default_rng(0)
    clip = StoredClip("sty_x", "proud", 30.0, ("hips", "spine"), "rsmt", rng.normal(size=(5, 2, 4)).astype(np.float32),
                      rng.normal(size=(5, 3)).astype(np.float32))
    data = encode_clip(clip)
    assert data.startswith(b"RSMTSTY1") and len(data) < 400  # header + 5 * (2 * 4 + 3) float32
    back = decode_clip(data)
    assert (back.style_id, back.name, back.fps, back.joints, back.model, back.frames) == ("sty_x", "proud", 30.0,
                                                                                        ("hips", "spine"), "rsmt", 5)
    assert np.array_equal(back.rotations, clip.rotations) and np.array_equal(back.root_positions, clip.root_positions)
    for bad in (b"", b"pickle" + data, data[:-4], data[:12]):
        with pytest.raises(CodecError):
            decode_clip(bad)


def test_codec_round_trip_of_a_style_of_several_clips():
    rng = np.random.default_rng(1)
    rot, root = rng.normal(size=(9, 2, 4)).astype(np.float32), rng.normal(size=(9, 3)).astype(np.float32)
    stored = StoredClip("sty_y", "three", 30.0, ("hips", "spine"), "rsmt", rot, root, (2, 3, 4))
    data = encode_clip(stored)
    assert data.startswith(b"RSMTSTY2") and stored.meta() == {"style_id": "sty_y", "name": "three", "frames": 9,
                                                              "clips": 3}
    back = decode_clip(data)
    assert back.clip_frames == (2, 3, 4) and back.clips == 3
    parts = back.parts()
    assert [p[0].shape[0] for p in parts] == [2, 3, 4] and np.array_equal(parts[2][1], root[5:])
    assert decode_clip(encode_clip(StoredClip("s", "n", 30.0, ("hips",), "m", rot[:, :1], root))).parts()[0][0].shape[0] == 9
    with pytest.raises(CodecError):
        encode_clip(StoredClip("sty_y", "three", 30.0, ("hips", "spine"), "rsmt", rot, root, (2, 3, 5)))
    with pytest.raises(CodecError):  # lengths that do not add up, as read
        decode_clip(data.replace(b'"clips":[2,3,4]', b'"clips":[2,3,3]'))


def test_settings_and_factory(monkeypatch):
    assert Settings().style_store == "memory" and Settings().style_store_ttl_s == 0
    for bad in ("mysql://x", "redis", ""):
        with pytest.raises(ValueError):
            Settings(style_store=bad)
    s = Settings(style_store="redis://user:secret@10.0.0.5:6380/2")
    assert safe_address(s.style_store) == "10.0.0.5:6380/2"  # never the password
    no_engine: Any = None  # the memory store never reads the engine
    assert isinstance(style_store_factory(Settings())("m", no_engine), MemoryStyleStore)


@pytest.fixture(scope="module")
def redis_server():
    srv = RedisProcess().start()
    yield srv
    srv.cleanup()


@pytest.fixture(scope="module")
def engines(bundle_dir):
    """Two engines of one bundle: two replicas, each with its own code cache."""
    return Engine(Bundle.load(bundle_dir)), Engine(Bundle.load(bundle_dir))


def clip_of(engine: Engine, frames: int = 30, yaw: float = 0.0):
    return engine.conform(synthetic_walk(frames, start_yaw_deg=yaw))


def register(store: RedisStyleStore, owner: str, clip, name: str = "walk") -> tuple[str, bool]:
    style, _ = store.engine.encode_style(clip, name)
    return style.style_id, store.add(owner, style, [clip])


@pytest.fixture
def stores(redis_server, engines):
    client = connect(redis_server.url, 1.0)
    client.flushdb()
    yield tuple(RedisStyleStore(client, "rsmt", e, per_owner=2, address=safe_address(redis_server.url)) for e in engines)
    client.close()


def test_redis_store_ownership_and_encoding_on_another_replica(stores, engines):
    one, two = stores
    sid, had = register(one, "a", clip_of(engines[0]))
    assert had is False and register(one, "a", clip_of(engines[0]))[1] is True
    engines[1].styles.delete(sid)  # the second replica never encoded it
    got = two.get(A, sid)
    assert got is not None and got.style_id == sid and got.frames == 30
    mine = engines[0].styles.peek(sid)
    assert mine is not None and torch.equal(got.context.keys1, mine.context.keys1)  # the same code
    again = two.get(A, sid)  # from this replica's cache now: the same code, under the caller's name
    assert again is not None and again.context is got.context and again.name == "walk"
    assert two.get(B, sid) is None and two.peek(B, sid) is None and list(two.styles_of(B)) == []
    admin_view = two.get(ADMIN, sid)
    assert admin_view is not None and admin_view.context is got.context and [s.style_id for s in two.styles_of(ADMIN)] == [sid]
    assert two.delete(B, sid) is False and one.peek(A, sid) is not None
    register(one, "b", clip_of(engines[0]))  # same clip, second owner: one stored copy, two entries
    assert one.delete(A, sid) is True and one.get(A, sid) is None and one.get(B, sid) is not None
    assert one.delete(ADMIN, sid) is True and one.peek(B, sid) is None and one.client.keys("*") == []


def test_redis_store_per_key_cap_drops_least_recently_used(stores, engines):
    one, _ = stores
    ids = [register(one, "a", clip_of(engines[0], yaw=10.0 * i))[0] for i in range(2)]
    assert one.get(A, ids[0]) is not None  # used: ids[1] is now the least recent
    ids.append(register(one, "a", clip_of(engines[0], yaw=20.0))[0])
    assert [s.style_id for s in one.styles_of(A)] == [ids[0], ids[2]] and one.evictions == 1
    assert one.peek(A, ids[1]) is None and one.client.exists(one.prefix + "clip:" + ids[1]) == 0  # nobody holds it


def test_redis_store_orders_uses_even_when_the_clock_does_not_move_on(stores, engines):
    # Two uses within one millisecond read the same clock, and a Redis that fails over to a replica
    # whose clock lags reads an earlier one: the later use must still count as the more recent.
    one, _ = stores
    ids = [register(one, "a", clip_of(engines[0], yaw=10.0 * i))[0] for i in range(2)]
    (own,) = one.client.keys(one.prefix + "own:*")
    one.client.zadd(own, {ids[0]: 9_000_000_000_000})  # ids[0] last used "in the future" (ms)
    assert one.get(A, ids[1]) is not None  # used now: the most recent use whatever the clock says
    assert [s.style_id for s in one.styles_of(A)] == [ids[0], ids[1]]
    ids.append(register(one, "a", clip_of(engines[0], yaw=20.0))[0])
    assert [s.style_id for s in one.styles_of(A)] == [ids[1], ids[2]] and one.evictions == 1


def test_redis_store_keeps_a_style_of_several_clips_for_every_replica(stores, engines):
    one, two = stores
    clips = [clip_of(engines[0], frames=30 + 5 * i, yaw=15.0 * i) for i in range(3)]
    style, _ = encode_style_set(engines[0], clips, "three")
    assert style.clips == 3 and one.add("a", style, clips) is False
    meta = one.peek(A, style.style_id)
    assert meta is not None and (meta.frames, meta.clips, meta.name) == (105, 3, "three")
    engines[1].styles.delete(style.style_id)  # the second replica never encoded it
    got = two.get(A, style.style_id)
    assert got is not None and got.style_id == style.style_id and got.clips == 3 and got.frames == 105
    assert all(torch.equal(getattr(got.context, k), getattr(style.context, k)) for k in ("keys1", "values2", "gamma1"))
    # The per-key cap (2) counts clips: this style of three is over it alone, so it stays the one entry, and
    # registering a one-clip style afterwards leaves that one (1 + 3 > 2).
    assert [s.style_id for s in one.styles_of(A)] == [style.style_id]
    single = register(one, "a", clip_of(engines[0], yaw=70.0))[0]
    assert [s.style_id for s in one.styles_of(A)] == [single] and one.evictions == 1
    assert one.client.exists(one.prefix + "clip:" + style.style_id) == 0 and one.client.keys(one.prefix + "sizes:*") == []


def test_redis_store_ttl(redis_server, engines):
    client = connect(redis_server.url, 1.0)
    store = RedisStyleStore(client, "ttl", engines[0], per_owner=4, ttl_s=1)
    sid, _ = register(store, "a", clip_of(engines[0]))
    assert store.peek(A, sid) is not None
    # A synchronous client: the seconds left as an int (redis-py types every answer as "maybe an Awaitable").
    ttl = client.ttl(store.prefix + "clip:" + sid)
    assert isinstance(ttl, int) and 0 < ttl <= 1
    time.sleep(2.1)
    assert store.peek(A, sid) is None and store.get(A, sid) is None and list(store.styles_of(A)) == []
    client.close()


def test_redis_outage_is_503_and_recovers_without_a_restart(redis_server, engines):
    client = connect(redis_server.url, 0.5)
    store = RedisStyleStore(client, "outage", engines[0], per_owner=4, address=safe_address(redis_server.url))
    sid, _ = register(store, "a", clip_of(engines[0]))
    redis_server.stop()
    try:
        with pytest.raises(ServiceError) as err:
            store.get(A, sid)
        assert err.value.code == "style_store_unavailable" and err.value.status == 503
        assert err.value.headers["Retry-After"] == "1" and safe_address(redis_server.url) in err.value.message
        with pytest.raises(ServiceError):
            register(store, "a", clip_of(engines[0], yaw=5.0))
    finally:
        redis_server.start()
    assert store.get(A, sid) is not None  # the same client object: the pool reconnected; the data was kept
    client.close()
