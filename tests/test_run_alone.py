"""The lock that keeps a test marked ``alone`` from running beside another worker's test (tests/run_alone.py)."""

from __future__ import annotations

import threading
from collections.abc import Generator
from pathlib import Path
from typing import cast

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


SUITE = '''
import json, os, time
import pytest

def _run(name, alone):
    start = time.monotonic()
    time.sleep(0.15)
    with open(os.environ["RSMT_ALONE_LOG"], "a") as log:
        log.write(json.dumps([name, alone, start, time.monotonic(), os.environ["PYTEST_XDIST_WORKER"]]) + "\\n")

@pytest.mark.parametrize("i", range(4))
def test_ordinary(i):
    _run(f"ordinary{i}", False)

@pytest.mark.alone
@pytest.mark.parametrize("i", range(4))
def test_alone(i):
    _run(f"alone{i}", True)

@pytest.mark.parametrize("i", range(8))
def test_ordinary_after(i):
    _run(f"after{i}", False)
'''


def test_nothing_runs_beside_the_alone_tests_of_a_two_worker_run(tmp_path):
    """Through a real two-worker run (the README's ``-n 2``), four ``alone`` tests among twelve others: no other test
    runs between the first one's start and the last one's end."""
    import json
    import os
    import subprocess
    import sys

    (tmp_path / "test_suite.py").write_text(SUITE)
    log = tmp_path / "log.jsonl"
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "RSMT_ALONE_LOG": str(log), "PYTHONPATH": str(root)}
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", "2", "-p", "tests.run_alone",
                           "-p", "no:cacheprovider", "-o", "markers=alone: runs alone", "--rootdir", str(tmp_path),
                           str(tmp_path / "test_suite.py")], capture_output=True, text=True, env=env, timeout=120,
                          cwd=tmp_path)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    runs = [json.loads(line) for line in log.read_text().splitlines()]
    assert len(runs) == 16
    alone = [r for r in runs if r[1]]
    first, last = min(r[2] for r in alone), max(r[3] for r in alone)
    beside = [r[0] for r in runs if not r[1] and r[2] < last and r[3] > first]
    assert not beside, f"{beside} ran between {first:.2f} and {last:.2f}: {sorted(runs, key=lambda r: r[2])}"


class _Item:
    def __init__(self, config: object, alone: bool) -> None:
        self.config, self.alone = config, alone

    def get_closest_marker(self, name: str) -> object | None:
        return object() if name == "alone" and self.alone else None


def test_a_row_of_alone_tests_keeps_the_hold_from_one_to_the_next(tmp_path, monkeypatch):
    """The hook keeps the exclusive hold while the next test is ``alone`` too, and lets go after the last one."""
    import tempfile
    from types import SimpleNamespace

    from tests import run_alone

    monkeypatch.setattr(tempfile, "gettempdir", lambda: str(tmp_path))
    config = SimpleNamespace(workerinput={"testrunuid": "row"})
    folder = tmp_path / "rsmt-tests-row"
    first, second, after = _Item(config, True), _Item(config, True), _Item(config, False)

    hook = run_alone.pytest_runtest_protocol
    for item, nextitem in ((first, second), (second, after)):
        step = cast(Generator[None, None, None], hook(item, nextitem))  # type: ignore[arg-type]
        next(step)  # the test runs now
        entered = threading.Event()
        beside = _enter(folder, False, entered)
        assert not entered.wait(WAIT_S), "another worker's test ran beside an alone test"
        step.close()  # the test ended
        if nextitem is second:
            assert not entered.wait(WAIT_S), "the hold was let go between two alone tests"
            pending = (beside, entered)
        else:
            assert entered.wait(10) and pending[1].wait(10), "the hold was kept after the last alone test"
            beside.join(10)
            pending[0].join(10)
    assert run_alone._Room.hold is None
