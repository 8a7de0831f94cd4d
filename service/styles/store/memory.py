"""The default store: each model's styles in this process only (:class:`service.styles.book.StyleBook`).

Styles are lost on restart and each process (each replica, each ``--workers`` worker) has its own;
the per-key cap and the whole-book entry and byte bounds are the book's.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from service.styles.book import StyleBook

if TYPE_CHECKING:
    from collections.abc import Sequence

    from model.inference.engine import EncodedStyle
    from model.motion.clip import Clip


class MemoryStyleStore(StyleBook):
    """A :class:`StyleBook` as a :class:`service.styles.store.StyleStore`: the encoded style is all it keeps."""

    def add(self, owner: str, style: EncodedStyle, clips: Sequence[Clip] = ()) -> bool:
        """File ``style`` under ``owner``; the clips are not needed in memory (the code is kept)."""
        return super().add(owner, style)
