"""Styles, all in one place: what the rest of the service imports of them is named here, and only here.

* **registered styles**: each API key's own (:mod:`~service.styles.book`, the per-owner LRU book), kept in a
  store (:mod:`~service.styles.store`: this process, or Redis shared by replicas) reached on its own lane
  (:mod:`~service.styles.lookups`) so that a slow store never holds a model's threads;
* **built-in styles**: the codes a bundle ships, ``builtin:NAME`` for every key (:mod:`~service.styles.builtin`);
* **the style work** run on a model's threads: look up, encode, register one clip or several, resolve a request's
  style (:mod:`~service.styles.jobs`, :mod:`~service.styles.registration`), and the hints its errors give
  (:mod:`~service.styles.hints`).

The functions take the served model as a :class:`StyleHost` (name, engine, limits, store); nothing here imports
the registry, which stands above (it gives each model its store).
"""

from __future__ import annotations

from service.styles.builtin import builtin_list, builtin_style, is_builtin
from service.styles.hints import builtin_suggestion
from service.styles.host import StyleHost
from service.styles.jobs import Registered, encode_registration, lookup_style, resolve_style, style_info
from service.styles.lookups import file_style, on_lane, registered_style
from service.styles.registration import encode_clips_registration
from service.styles.store import StyleEntry, StyleMeta, StyleStore, style_store_factory
from service.styles.store.lane import StoreLane

__all__ = [
    "Registered", "StoreLane", "StyleEntry", "StyleHost", "StyleMeta", "StyleStore", "builtin_list", "builtin_style",
    "builtin_suggestion", "encode_clips_registration", "encode_registration", "file_style", "is_builtin",
    "lookup_style", "on_lane", "registered_style", "resolve_style", "style_info", "style_store_factory",
]
