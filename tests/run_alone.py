"""Tests that measure time run alone when the suite runs on several workers (pytest-xdist, the README's ``-n 2``).

A test marked ``alone`` compares rates, latencies or shares of the machine against a baseline it takes itself; a
test on another worker beside it would move its figures. So every test holds a lock on a file that the run's
workers share: ``alone`` tests exclusively, the others shared, and a turnstile before it keeps a waiting ``alone``
test from being starved by the shared holders. ``alone`` tests that follow each other on a worker keep the hold from
one to the next (otherwise another worker's test would slip in between and the next one would wait for it). In one
process (no ``-n``) nothing runs beside a test and no lock is taken."""

from __future__ import annotations

import fcntl
import tempfile
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import IO

import pytest


def lock_folder(config: pytest.Config) -> Path | None:
    """The folder of this run's locks, shared by its workers; None outside pytest-xdist's workers."""
    workerinput = getattr(config, "workerinput", None)
    if workerinput is None:
        return None
    return Path(tempfile.gettempdir()) / f"rsmt-tests-{workerinput['testrunuid']}"


@contextmanager
def held(folder: Path, alone: bool) -> Iterator[None]:
    """The room held shared (``alone`` False) or exclusively, entered through the turnstile."""
    folder.mkdir(exist_ok=True)
    with open(folder / "turnstile", "a") as gate, open(folder / "room", "a") as room:
        _lock(gate, fcntl.LOCK_EX)
        try:
            _lock(room, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        finally:
            _lock(gate, fcntl.LOCK_UN)
        try:
            yield
        finally:
            _lock(room, fcntl.LOCK_UN)


def _lock(f: IO[str], how: int) -> None:
    fcntl.flock(f.fileno(), how)


def is_alone(item: pytest.Item | None) -> bool:
    return item is not None and item.get_closest_marker("alone") is not None


class _Room:
    """The exclusive hold of this worker, kept from one ``alone`` test to the next when they follow each other, so
    that no other worker's test slips in between (each would make the next ``alone`` test wait for it)."""

    hold: ExitStack | None = None

    @classmethod
    def release(cls) -> None:
        if cls.hold is not None:
            cls.hold.close()
            cls.hold = None


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    folder = lock_folder(item.config)
    if folder is None:
        yield
        return
    if not is_alone(item):
        with held(folder, alone=False):
            yield
        return
    if _Room.hold is None:
        hold = ExitStack()
        hold.enter_context(held(folder, alone=True))
        _Room.hold = hold
    try:
        yield
    finally:
        if not is_alone(nextitem):
            _Room.release()


def pytest_sessionfinish(session: pytest.Session) -> None:
    _Room.release()
