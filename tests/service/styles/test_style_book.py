"""The per-owner style book (service/styles/book.py) on real encoded styles: per-owner LRU, the whole-book
entry and byte bounds evicting from the biggest owner, and what an admin caller sees."""

from __future__ import annotations

import dataclasses

import pytest

from model.data.synthetic import synthetic_walk
from model.inference.bundle import Bundle
from model.inference.engine import EncodedStyle, Engine
from service.caller import Caller
from service.styles.book import StyleBook

A, B, ADMIN = Caller("a"), Caller("b"), Caller("admin", admin=True)


@pytest.fixture(scope="module")
def encoded(bundle_dir) -> EncodedStyle:
    return Engine(Bundle.load(bundle_dir)).encode_style(synthetic_walk(30), "walk")[0]


def style(base: EncodedStyle, i: int, nbytes: int = 10) -> EncodedStyle:
    """The encoded style filed under another id and size (the book reads nothing else)."""
    return dataclasses.replace(base, style_id=f"sty_{i:024d}", nbytes=nbytes)


def ids(book: StyleBook, caller: Caller) -> list[str]:
    return [s.style_id for s in book.styles_of(caller)]


def test_per_owner_lru(encoded):
    book = StyleBook(per_owner=2, max_entries=100, max_bytes=10_000)
    s0, s1, s2 = (style(encoded, i) for i in range(3))
    assert book.add("a", s0) is False and book.add("a", s1) is False
    assert book.get(A, s0.style_id) is s0  # used: s1 is now the least recent
    book.add("a", s2)
    assert ids(book, A) == [s0.style_id, s2.style_id]
    assert book.add("b", s1) is False and book.add("b", s1) is True
    assert book.get(A, s1.style_id) is None and book.get(B, s1.style_id) is s1 and book.evictions == 1


def test_whole_bound_evicts_the_biggest_owner(encoded):
    book = StyleBook(per_owner=10, max_entries=4, max_bytes=10_000)
    book.add("b", style(encoded, 0))
    for i in range(1, 4):
        book.add("a", style(encoded, i))
    book.add("b", style(encoded, 9))  # five entries: A (three) loses its oldest
    assert ids(book, B) == [style(encoded, 0).style_id, style(encoded, 9).style_id]
    assert ids(book, A) == [style(encoded, 2).style_id, style(encoded, 3).style_id]
    assert len(book) == 4


def test_byte_bound_evicts_the_owner_holding_most_bytes(encoded):
    book = StyleBook(per_owner=10, max_entries=100, max_bytes=100)
    book.add("b", style(encoded, 0, nbytes=30))
    book.add("a", style(encoded, 1, nbytes=40))
    book.add("a", style(encoded, 2, nbytes=40))  # 110 bytes: A holds 80
    assert ids(book, A) == [style(encoded, 2).style_id] and ids(book, B) == [style(encoded, 0).style_id]
    assert book.bytes == 70


def test_admin_sees_and_deletes_everyones(encoded):
    book = StyleBook(per_owner=10, max_entries=100, max_bytes=10_000)
    shared, only_b = style(encoded, 0), style(encoded, 1)
    book.add("a", shared)
    book.add("b", shared)
    book.add("b", only_b)
    assert sorted(ids(book, ADMIN)) == sorted([shared.style_id, only_b.style_id])  # one entry per id
    assert book.peek(ADMIN, only_b.style_id) is only_b and book.peek(A, only_b.style_id) is None
    assert book.delete(A, only_b.style_id) is False
    assert book.delete(ADMIN, shared.style_id) is True
    assert ids(book, A) == [] and ids(book, B) == [only_b.style_id]


def test_per_owner_cap_counts_the_clips_of_a_style(encoded):
    book = StyleBook(per_owner=4, max_entries=100, max_bytes=10_000)
    single = [style(encoded, i) for i in range(3)]
    three = dataclasses.replace(style(encoded, 9), clips=3)
    for s in single:
        book.add("a", s)
    book.add("a", three)  # 3 + 3 clips > 4: the two oldest one-clip styles go
    assert ids(book, A) == [single[2].style_id, three.style_id] and book.evictions == 2
    five = dataclasses.replace(style(encoded, 10), clips=5)
    book.add("a", five)  # over the cap alone: the newest stays, alone
    assert ids(book, A) == [five.style_id]
