"""The lock that keeps a test marked ``alone`` from running beside another worker's test (tests/run_alone.py)."""

from __future__ import annotations

import threading
from pathlib import Path

from tests.run_alone import held

WAIT_S = 0.3  # long enough for a thread to take a free lock on any machine; bounded either way


def _enter(folder: Path, alone: bool, entered: threading.Event) -> threading.Thread:
    def run() -> None:
        with held(folder, alone):
            entered.set()

    thread = threading.Thread(target=run)
    thread.start()
    return thread


def test_an_alone_test_holds_every_other_test_off_until_it_ends(tmp_path):
    entered = threading.Event()
    with held(tmp_path, alone=True):
        thread = _enter(tmp_path, False, entered)
        assert not entered.wait(WAIT_S)
    assert entered.wait(10)
    thread.join(10)


def test_an_alone_test_waits_for_the_tests_running_and_others_run_together(tmp_path):
    together, alone = threading.Event(), threading.Event()
    with held(tmp_path, alone=False):
        shared = _enter(tmp_path, False, together)
        assert together.wait(10)  # two ordinary tests at once
        shared.join(10)
        waiting = _enter(tmp_path, True, alone)
        assert not alone.wait(WAIT_S)
    assert alone.wait(10)
    waiting.join(10)
