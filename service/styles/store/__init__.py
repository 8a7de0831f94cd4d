"""Where registered styles live: in this process (``memory``, the default) or in Redis, shared by replicas.

``RSMT_STYLE_STORE`` picks the store: ``memory`` keeps each model's styles in a per-owner LRU book in this
process (:class:`service.styles.store.memory.MemoryStyleStore`, lost on restart); ``redis://HOST:PORT/DB``
keeps each registered clip in Redis, content-addressed and owned by its API key
(:class:`service.styles.store.redis_store.RedisStyleStore`), so styles survive restarts and are the same on
every replica. Either way each process keeps its own bounded cache of encoded codes (the engine's), and a
replica that has not encoded a stored clip yet encodes it on first use.

Both stores answer the same questions (:class:`StyleStore`); ownership is the same: a caller sees its own
styles, an admin everyone's (:class:`service.caller.Caller`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from service.styles.store.base import StyleEntry, StyleMeta, StyleStore

if TYPE_CHECKING:
    from model.inference.engine import Engine
    from service.settings import Settings

__all__ = ["StyleEntry", "StyleMeta", "StyleStore", "StoreFactory", "style_store_factory"]


StoreFactory = Callable[[str, "Engine"], StyleStore]


def style_store_factory(settings: Settings) -> StoreFactory:
    """A function giving each loaded model (name, engine) its store, as ``settings.style_store`` says.

    With Redis, one client (one connection pool) serves every model of the process.
    """
    if settings.style_store == "memory":
        from service.styles.store.memory import MemoryStyleStore

        def memory(name: str, engine: Engine) -> StyleStore:
            return MemoryStyleStore(settings.styles_per_owner, settings.style_cache_entries, settings.style_cache_bytes)

        return memory

    from service.styles.store.redis_store import RedisStyleStore, connect, safe_address

    client = connect(settings.style_store, settings.style_store_timeout_s)
    address = safe_address(settings.style_store)

    def redis(name: str, engine: Engine) -> StyleStore:
        return RedisStyleStore(client, name, engine, settings.styles_per_owner, settings.style_store_ttl_s, address)

    return redis
