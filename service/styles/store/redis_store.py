"""Registered styles in Redis: shared by every replica, kept across restarts.

Per model (name and version), under ``rsmt:styles:<model>:<version>:``:

* ``clip:<id>``: the registered clip (:mod:`service.styles.store.codec`), content-addressed: one copy
  whichever keys registered it; ``meta:<id>``: its id and length as JSON (for listings);
* ``names:<owner>``: the name that owner gave each of its ids (content is shared below the keys, names are
  not: no key sees the name another chose); the clip and its meta are written on every registration, so that
  registering a clip another key has costs what registering a new one does;
* ``refs:<id>``: the owners (API key digests) that registered it; the clip goes when the last one lets go;
* ``own:<owner>``: that owner's ids, scored by last use (Redis's clock), so its least recently used go
  first over the per-key cap; ``owners``: every owner with styles (for admin listings);
* ``sizes:<owner>``: the clips of each of that owner's styles of several clips (``motions``): a style of n
  clips counts n against the per-key cap, as in the memory book (a style of one clip has no entry).

Each operation is one Lua script, so concurrent replicas never see half an update. With a TTL every key of
a style is given that TTL again whenever it is registered or used. Codes are never stored: each replica
encodes a stored clip the first time it is used there and keeps the code in its engine's bounded cache.

When Redis cannot be reached, every call raises :class:`ServiceError` ``style_store_unavailable`` (503,
``Retry-After``); the client's pool reconnects on the next call, so the service recovers by itself.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any, TypeVar
from urllib.parse import urlsplit

import redis
import torch
from redis.backoff import ExponentialBackoff
from redis.exceptions import RedisError
from redis.retry import Retry

from model.inference.errors import EngineError
from model.inference.style_sets import encode_style_set
from model.motion.clip import Clip
from service.caller import Caller
from service.errors import ServiceError
from service.styles.store.base import StyleEntry, StyleMeta
from service.styles.store.codec import CodecError, StoredClip, decode_clip, encode_clip

if TYPE_CHECKING:
    from model.inference.engine import EncodedStyle, Engine

log = logging.getLogger(__name__)
T = TypeVar("T")
RETRY_AFTER_S = 1

# A use's score in an owner's set: Redis's clock in milliseconds, but always above the set's latest, so
# two uses within one millisecond keep their order (milliseconds: Lua hands numbers to Redis with 14
# significant digits).
_STAMP = """
local function stamp(own)
  local t = redis.call('TIME')
  local now = tonumber(t[1]) * 1000 + math.floor(tonumber(t[2]) / 1000)
  local top = redis.call('ZRANGE', own, -1, -1, 'WITHSCORES')
  if top[2] and tonumber(top[2]) >= now then now = tonumber(top[2]) + 1 end
  return now
end
"""

# ARGV: prefix, owner, id, clip, meta, cap, ttl, name, clips  ->  {had, evicted}
_ADD = _STAMP + """
local p, owner, sid = ARGV[1], ARGV[2], ARGV[3]
local cap, ttl, n = tonumber(ARGV[6]), tonumber(ARGV[7]), tonumber(ARGV[9])
local own, refs, clip, meta = p .. 'own:' .. owner, p .. 'refs:' .. sid, p .. 'clip:' .. sid, p .. 'meta:' .. sid
local names, sizes = p .. 'names:' .. owner, p .. 'sizes:' .. owner
local exists = redis.call('EXISTS', meta) == 1 and redis.call('EXISTS', clip) == 1
local had = exists and redis.call('ZSCORE', own, sid) ~= false
redis.call('SET', clip, ARGV[4])  -- the same bytes whoever registered it: written every time (no timing tell)
redis.call('SET', meta, ARGV[5])
redis.call('HSET', names, sid, ARGV[8])
redis.call('ZADD', own, stamp(own), sid)
redis.call('SADD', refs, owner)
redis.call('SADD', p .. 'owners', owner)
if n > 1 then redis.call('HSET', sizes, sid, n) else redis.call('HDEL', sizes, sid) end
local held = 0
for _, s in ipairs(redis.call('ZRANGE', own, 0, -1)) do held = held + (tonumber(redis.call('HGET', sizes, s)) or 1) end
local evicted = 0
while held > cap and redis.call('ZCARD', own) > 1 do
  local victim = redis.call('ZPOPMIN', own)[1]
  local vrefs = p .. 'refs:' .. victim
  held = held - (tonumber(redis.call('HGET', sizes, victim)) or 1)
  redis.call('HDEL', names, victim)
  redis.call('HDEL', sizes, victim)
  redis.call('SREM', vrefs, owner)
  if redis.call('SCARD', vrefs) == 0 then
    redis.call('DEL', vrefs, p .. 'clip:' .. victim, p .. 'meta:' .. victim)
  end
  evicted = evicted + 1
end
if ttl > 0 then
  for _, k in ipairs({clip, meta, refs, own, names}) do redis.call('EXPIRE', k, ttl) end
  if redis.call('EXISTS', sizes) == 1 then redis.call('EXPIRE', sizes, ttl) end
end
return {had and 1 or 0, evicted}
"""

# A style's name for ``owner``; for an admin looking at another owner's, that owner's name (the first found).
_NAME = """
local function name_of(p, owner, sid)
  local n = redis.call('HGET', p .. 'names:' .. owner, sid)
  if n then return n end
  for _, o in ipairs(redis.call('SMEMBERS', p .. 'refs:' .. sid)) do
    n = redis.call('HGET', p .. 'names:' .. o, sid)
    if n then return n end
  end
  return false
end
"""

# ARGV: prefix, owner, id, admin (0/1), touch (0/1), want clip (0/1), ttl  ->  false | {meta, clip or false, name}
_GET = _STAMP + _NAME + """
local p, owner, sid, admin, touch, want = ARGV[1], ARGV[2], ARGV[3], ARGV[4], ARGV[5], ARGV[6]
local ttl = tonumber(ARGV[7])
local own, clip, meta = p .. 'own:' .. owner, p .. 'clip:' .. sid, p .. 'meta:' .. sid
local mine = redis.call('ZSCORE', own, sid) ~= false
if not mine and admin ~= '1' then return false end
local m = redis.call('GET', meta)
if not m then
  if mine then
    redis.call('ZREM', own, sid)
    redis.call('HDEL', p .. 'sizes:' .. owner, sid)
  end
  return false
end
if touch == '1' then
  if mine then
    redis.call('ZADD', own, 'XX', stamp(own), sid)
    if ttl > 0 then
      redis.call('EXPIRE', own, ttl)
      redis.call('EXPIRE', p .. 'names:' .. owner, ttl)
      if redis.call('EXISTS', p .. 'sizes:' .. owner) == 1 then redis.call('EXPIRE', p .. 'sizes:' .. owner, ttl) end
    end
  end
  if ttl > 0 then
    for _, k in ipairs({clip, meta, p .. 'refs:' .. sid}) do redis.call('EXPIRE', k, ttl) end
  end
end
local c = false
if want == '1' then c = redis.call('GET', clip) end
local n = false
if mine then n = redis.call('HGET', p .. 'names:' .. owner, sid) else n = name_of(p, owner, sid) end
return {m, c, n}
"""

# ARGV: prefix, owner, admin (0/1)  ->  {meta, name, meta, name, ...} least recently used first, one per id
_LIST = """
local p, owner, admin = ARGV[1], ARGV[2], ARGV[3]
local owners = {owner}
if admin == '1' then
  local all = redis.call('SMEMBERS', p .. 'owners')
  table.sort(all)
  for _, o in ipairs(all) do if o ~= owner then table.insert(owners, o) end end
end
local out, seen = {}, {}
for _, o in ipairs(owners) do
  local own = p .. 'own:' .. o
  for _, sid in ipairs(redis.call('ZRANGE', own, 0, -1)) do
    if not seen[sid] then
      local m = redis.call('GET', p .. 'meta:' .. sid)
      if m then
        seen[sid] = true
        table.insert(out, m)
        table.insert(out, redis.call('HGET', p .. 'names:' .. o, sid) or '')
      else
        redis.call('ZREM', own, sid)
        redis.call('HDEL', p .. 'sizes:' .. o, sid)
      end
    end
  end
end
return out
"""

# ARGV: prefix, owner, id, admin (0/1)  ->  1 when there was an entry
_DELETE = """
local p, owner, sid, admin = ARGV[1], ARGV[2], ARGV[3], ARGV[4]
local refs, clip, meta = p .. 'refs:' .. sid, p .. 'clip:' .. sid, p .. 'meta:' .. sid
local live = redis.call('EXISTS', meta) == 1
local owners = {owner}
if admin == '1' then owners = redis.call('SMEMBERS', refs) end
local found = 0
for _, o in ipairs(owners) do
  local own = p .. 'own:' .. o
  if redis.call('ZREM', own, sid) == 1 and live then found = 1 end
  redis.call('HDEL', p .. 'names:' .. o, sid)
  redis.call('HDEL', p .. 'sizes:' .. o, sid)
  redis.call('SREM', refs, o)
  if redis.call('ZCARD', own) == 0 then redis.call('SREM', p .. 'owners', o) end
end
if redis.call('SCARD', refs) == 0 then redis.call('DEL', refs, clip, meta) end
return found
"""


def safe_address(url: str) -> str:
    """``host:port/db`` of a Redis URL, without any password, for messages and logs."""
    parts = urlsplit(url)
    return f"{parts.hostname or 'localhost'}:{parts.port or 6379}{parts.path or '/0'}"


def connect(url: str, timeout_s: float) -> redis.Redis:
    """A client with short timeouts and one quick retry (a pooled connection that died with a Redis restart
    is replaced at once); nothing is sent until the first call, so the service starts with Redis down."""
    return redis.Redis.from_url(url, socket_connect_timeout=timeout_s, socket_timeout=timeout_s,
                                retry=Retry(ExponentialBackoff(cap=0.2, base=0.05), 1),
                                health_check_interval=30, client_name="rsmt")


class RedisStyleStore:
    """One model's registered styles in Redis (see the module doc); thread-safe (redis-py's pool)."""

    def __init__(self, client: redis.Redis, model: str, engine: Engine, per_owner: int, ttl_s: int = 0,
                 address: str = "redis") -> None:
        self.client, self.model, self.engine = client, model, engine
        self.per_owner, self.ttl, self.address = per_owner, int(ttl_s), address
        self.prefix = f"rsmt:styles:{model}:{engine.version}:"
        self.evictions = 0
        self._add, self._get = client.register_script(_ADD), client.register_script(_GET)
        self._list, self._delete = client.register_script(_LIST), client.register_script(_DELETE)

    # ------------------------------------------------------------------ the StyleStore questions
    def add(self, owner: str, style: EncodedStyle, clips: Sequence[Clip]) -> bool:
        # The shared copy carries no key's name (the id stands in): names live per owner.
        first = clips[0]
        stored = StoredClip(style.style_id, style.style_id, float(first.fps), tuple(first.skeleton.names), self.model,
                            torch.cat([c.rotations.detach().float() for c in clips]).numpy(),
                            torch.cat([c.root_positions.detach().float() for c in clips]).numpy(),
                            tuple(c.num_frames for c in clips) if len(clips) > 1 else ())
        meta = _meta_json(stored.meta())
        had, evicted = self._call(self._add, self.prefix, owner, style.style_id, encode_clip(stored), meta,
                                  self.per_owner, self.ttl, style.name, stored.clips)
        self.evictions += int(evicted)
        return bool(had)

    def get(self, caller: Caller, style_id: str) -> EncodedStyle | None:
        cached = self.engine.styles.peek(style_id)
        found = self._fetch(caller, style_id, touch=True, want_clip=cached is None)
        if found is None:
            return None
        if cached is not None:
            again = self.engine.styles.get(style_id)  # counts the hit; None if evicted since the peek
            if again is not None:
                return replace(again, name=found[0].name)  # the engine's code, this caller's name
            found = self._fetch(caller, style_id, touch=False, want_clip=True)
            if found is None:
                return None
        encoded = self._encode(style_id, found[1])
        return None if encoded is None else replace(encoded, name=found[0].name)

    def peek(self, caller: Caller, style_id: str) -> StyleEntry | None:
        found = self._fetch(caller, style_id, touch=False, want_clip=False)
        return None if found is None else found[0]

    def styles_of(self, caller: Caller) -> Sequence[StyleEntry]:
        flat = self._call(self._list, self.prefix, caller.owner, int(caller.admin))
        return [_meta(m, n) for m, n in zip(flat[::2], flat[1::2], strict=True)]

    def delete(self, caller: Caller, style_id: str) -> bool:
        return bool(self._call(self._delete, self.prefix, caller.owner, style_id, int(caller.admin)))

    # ------------------------------------------------------------------ internals
    def _fetch(self, caller: Caller, style_id: str, touch: bool, want_clip: bool) -> tuple[StyleMeta, bytes | None] | None:
        found = self._call(self._get, self.prefix, caller.owner, style_id, int(caller.admin), int(touch),
                           int(want_clip), self.ttl)
        if not found:
            return None
        meta, clip, name = (*found, None)[:3]
        return _meta(meta, name), (clip or None)

    def _encode(self, style_id: str, data: bytes | None) -> EncodedStyle | None:
        """Encode a stored clip with this replica's engine (which caches the code); None if it is unusable."""
        if data is None:
            return None
        try:
            stored = decode_clip(data)
        except CodecError as exc:
            log.warning("stored style %s is unreadable, ignored: %s", style_id, exc)
            return None
        skeleton = self.engine.skeleton
        if stored.joints != tuple(skeleton.names):
            log.warning("stored style %s is on another rig than model %s, ignored", style_id, self.model)
            return None
        clips = [Clip(skeleton, torch.from_numpy(rot), torch.from_numpy(root), stored.fps, stored.name)
                 for rot, root in stored.parts()]
        try:
            style, _ = encode_style_set(self.engine, clips, stored.name)
        except EngineError as exc:  # clips this model does not read (another model's limits)
            log.warning("stored style %s cannot be encoded by model %s, ignored: %s", style_id, self.model, exc)
            return None
        if style.style_id != style_id:
            log.warning("stored style %s encodes to %s on this replica (another model version?)", style_id, style.style_id)
        return style

    def _call(self, script: Callable[..., Any], *args: Any) -> Any:
        try:
            return script(args=list(args))
        except RedisError as exc:
            raise ServiceError(
                "style_store_unavailable",
                f"the style store (Redis at {self.address}) cannot be reached: {type(exc).__name__}: {exc}; registered "
                f"styles are unavailable until it is back (requests with an inline style still work); retry in a few "
                f"seconds", headers={"Retry-After": str(RETRY_AFTER_S)}) from exc


def _meta_json(meta: dict[str, Any]) -> bytes:
    return json.dumps(meta, separators=(",", ":")).encode()


def _meta(raw: bytes, name: bytes | str | None = None) -> StyleMeta:
    """A listing's entry: the stored meta with the owner's name (a style stored before names were kept
    per owner has its name in the meta)."""
    m = json.loads(raw)
    if isinstance(name, bytes):
        name = name.decode()
    return StyleMeta(str(m["style_id"]), name or str(m.get("name") or m["style_id"]), int(m["frames"]),
                     int(m.get("clips", 1)))
