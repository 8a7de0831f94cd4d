"""A bounded LRU cache of encoded styles, keyed by a content hash any replica can recompute."""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

import torch

from model.motion.clip import Clip
from model.motion.rotations import quat_canonical

V = TypeVar("V")


def clip_content_hash(clip: Clip, model_version: str) -> str:
    """A hash of a clip's motion, its rig and the model version.

    Rotations are quantised to 1e-4 (sign fixed so ``w >= 0``) and root positions to 0.01 unit, so
    the same clip sent as BVH text or as JSON quaternions gets the same id despite float noise.
    """
    digest = hashlib.sha256()
    digest.update(model_version.encode())
    digest.update("\0".join(clip.skeleton.names).encode())
    digest.update(f"{clip.fps:.6f}".encode())
    rot = torch.round(quat_canonical(clip.rotations.double()) * 1e4).to(torch.int32)
    rot[rot == 0] = 0  # -0 and 0 hash alike
    root = torch.round(clip.root_positions.double() * 100).to(torch.int64)
    digest.update(rot.numpy().tobytes())
    digest.update(root.numpy().tobytes())
    return "sty_" + digest.hexdigest()[:24]


@dataclass
class CacheStats:
    hits: int = 0
    misses: int = 0
    evictions: int = 0


class LRUCache(Generic[V]):
    """Thread-safe LRU bounded by entry count and by total bytes (as reported by ``size_of``)."""

    def __init__(self, max_entries: int = 1024, max_bytes: int = 256 << 20, size_of: Callable[[V], int] | None = None) -> None:
        if max_entries < 1 or max_bytes < 1:
            raise ValueError("cache bounds must be positive")
        self.max_entries, self.max_bytes = max_entries, max_bytes
        self._size_of = size_of or (lambda _: 1)
        self._items: OrderedDict[str, tuple[V, int]] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()
        self.stats = CacheStats()

    def get(self, key: str) -> V | None:
        with self._lock:
            item = self._items.get(key)
            if item is None:
                self.stats.misses += 1
                return None
            self._items.move_to_end(key)
            self.stats.hits += 1
            return item[0]

    def peek(self, key: str) -> V | None:
        """Like :meth:`get` but without touching recency or statistics."""
        with self._lock:
            item = self._items.get(key)
            return None if item is None else item[0]

    def put(self, key: str, value: V) -> None:
        size = int(self._size_of(value))
        with self._lock:
            if key in self._items:
                self._bytes -= self._items.pop(key)[1]
            self._items[key] = (value, size)
            self._bytes += size
            while len(self._items) > self.max_entries or (self._bytes > self.max_bytes and len(self._items) > 1):
                _, (_, old) = self._items.popitem(last=False)
                self._bytes -= old
                self.stats.evictions += 1

    def delete(self, key: str) -> bool:
        with self._lock:
            item = self._items.pop(key, None)
            if item is None:
                return False
            self._bytes -= item[1]
            return True

    def keys(self) -> list[str]:
        with self._lock:
            return list(self._items)

    def __len__(self) -> int:
        return len(self._items)

    @property
    def bytes(self) -> int:
        return self._bytes
