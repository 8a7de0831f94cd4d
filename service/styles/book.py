"""Who owns which registered style: one LRU book per API key, within the model's global bound.

The engine's own cache (:attr:`Engine.styles`) stays a shared, content-addressed encoding memo that no
client sees; the styles a client can list, fetch, delete and use by id are the ones in its own book.
A style id is a content hash, so two keys registering the same clip get the same id: ownership is
keyed by ``(owner, style id)`` and each key has its own entry (and its own eviction).

Bounds: each owner keeps at most ``per_owner`` clips' worth of styles (a style of n clips counts n; its least
recently used ones go first, and its newest style stays even when it alone is over), and
the book as a whole at most ``max_entries`` entries and ``max_bytes`` bytes; over the whole-book
bound, the owner holding the most (entries, or bytes) loses its least recently used entry, so a flood
from one key evicts that key's styles before anyone else's.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import TYPE_CHECKING

from service.caller import Caller

if TYPE_CHECKING:
    from model.inference.engine import EncodedStyle


class StyleBook:
    """Thread-safe per-owner LRU books of encoded styles (registration runs on worker threads)."""

    def __init__(self, per_owner: int, max_entries: int, max_bytes: int) -> None:
        self.per_owner, self.max_entries, self.max_bytes = per_owner, max_entries, max_bytes
        self._books: dict[str, OrderedDict[str, EncodedStyle]] = {}
        self._bytes: dict[str, int] = {}
        self._lock = threading.Lock()
        self.evictions = 0

    def add(self, owner: str, style: EncodedStyle) -> bool:
        """File ``style`` under ``owner`` (most recently used); True when the owner already had it."""
        with self._lock:
            book = self._books.setdefault(owner, OrderedDict())
            had = style.style_id in book
            if had:
                self._bytes[owner] -= book.pop(style.style_id).nbytes
            book[style.style_id] = style
            self._bytes[owner] = self._bytes.get(owner, 0) + style.nbytes
            while len(book) > 1 and sum(s.clips for s in book.values()) > self.per_owner:
                self._evict(owner)
            self._bound()
            return had

    def get(self, caller: Caller, style_id: str) -> EncodedStyle | None:
        """The caller's style (marked as used); an admin also finds any owner's."""
        return self._find(caller, style_id, touch=True)

    def peek(self, caller: Caller, style_id: str) -> EncodedStyle | None:
        """Like :meth:`get` without touching recency."""
        return self._find(caller, style_id, touch=False)

    def _find(self, caller: Caller, style_id: str, touch: bool) -> EncodedStyle | None:
        with self._lock:
            for owner in self._owners(caller):
                book = self._books.get(owner)
                if book is not None and style_id in book:
                    if touch:
                        book.move_to_end(style_id)
                    return book[style_id]
            return None

    def styles_of(self, caller: Caller) -> list[EncodedStyle]:
        """The caller's styles, least recently used first (an admin's: everyone's, one entry per id)."""
        with self._lock:
            seen: dict[str, EncodedStyle] = {}
            for owner in self._owners(caller):
                for sid, style in self._books.get(owner, OrderedDict()).items():
                    seen.setdefault(sid, style)
            return list(seen.values())

    def delete(self, caller: Caller, style_id: str) -> bool:
        """Forget the caller's entry (an admin's: every owner's); True when there was one."""
        with self._lock:
            found = False
            for owner in self._owners(caller):
                book = self._books.get(owner)
                if book is not None and style_id in book:
                    self._bytes[owner] -= book.pop(style_id).nbytes
                    self._drop_if_empty(owner)
                    found = True
            return found

    def __len__(self) -> int:
        with self._lock:
            return sum(len(b) for b in self._books.values())

    @property
    def bytes(self) -> int:
        with self._lock:
            return sum(self._bytes.values())

    # ------------------------------------------------------------------ internals (lock held)
    def _owners(self, caller: Caller) -> list[str]:
        if not caller.admin:
            return [caller.owner]
        return [caller.owner, *sorted(o for o in self._books if o != caller.owner)]

    def _evict(self, owner: str) -> None:
        _, style = self._books[owner].popitem(last=False)
        self._bytes[owner] -= style.nbytes
        self.evictions += 1
        self._drop_if_empty(owner)

    def _drop_if_empty(self, owner: str) -> None:
        if not self._books[owner]:
            del self._books[owner]
            del self._bytes[owner]

    def _bound(self) -> None:
        while True:
            total = sum(len(b) for b in self._books.values())
            if total > self.max_entries:
                self._evict(max(self._books, key=lambda o: (len(self._books[o]), self._bytes[o])))
            elif total > 1 and sum(self._bytes.values()) > self.max_bytes:
                self._evict(max(self._books, key=lambda o: (self._bytes[o], len(self._books[o]))))
            else:
                return
