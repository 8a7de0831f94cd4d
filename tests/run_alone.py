"""Tests that measure time run alone when the suite runs on several workers (pytest-xdist, the README's ``-n 2``).

A test marked ``alone`` compares rates, latencies or shares of the machine against a baseline it takes itself; a
test on another worker beside it would move its figures. So every test holds a lock on a file that the run's
workers share: ``alone`` tests exclusively, the others shared, and a turnstile before it keeps a waiting ``alone``
test from being starved by the shared holders. In one process (no ``-n``) nothing runs beside a test and no lock
is taken."""

from __future__ import annotations

import fcntl
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
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


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    folder = lock_folder(item.config)
    if folder is None:
        yield
        return
    with held(folder, item.get_closest_marker("alone") is not None):
        yield
