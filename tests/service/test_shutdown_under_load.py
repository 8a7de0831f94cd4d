"""SIGTERM to a real ``rsmt serve`` with 64 transitions queued (each slowed to hold the one work thread for a
while: ``tests/service/slow_engine.py``): every request gets JSON, 200 or 503 ``shutting_down`` (never
uvicorn's plain-text 500 of a cancelled request), and the process exits within the documented bound,
``RSMT_SHUTDOWN_DRAIN_S`` + ``RSMT_SHUTDOWN_GRACE_S`` (docs/service.md)."""

from __future__ import annotations

import signal
import time

import pytest

from tests.service.burst import Burst, metric, wait_for
from tests.service.conftest import transition_body
from tests.service.slow_engine import slow_server

pytestmark = [pytest.mark.slow, pytest.mark.alone]  # SIGTERM under a full queue

REQUESTS = 64
DELAY_S = 0.3  # 64 queued hold the one thread ~19 s: far beyond the drain and the grace
DRAIN_S, GRACE_S = 0.5, 5.0


def test_sigterm_with_64_queued_answers_json_and_exits_in_time(bundle_dir):
    srv = slow_server(bundle_dir, DELAY_S, REQUESTS,
                      {"RSMT_SHUTDOWN_DRAIN_S": str(DRAIN_S), "RSMT_SHUTDOWN_GRACE_S": str(GRACE_S)})
    srv.start()
    proc = srv.proc
    assert proc is not None
    try:
        burst = Burst(srv.url, transition_body(frames=10), REQUESTS)
        # Most of them are waiting for the work thread (at worst, carry on after a while).
        wait_for(lambda: metric(srv.url, "rsmt_work_queue_waiting") >= REQUESTS // 2, 10)
        time.sleep(0.3)
        sent = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=DRAIN_S + GRACE_S + 10)
        exit_s = time.monotonic() - sent
        answers = burst.join(30)
    finally:
        srv.stop()
    assert code in (0, -signal.SIGTERM), (code, srv.logs())
    not_json = [(a.status, a.content_type, a.body[:80], a.error) for a in answers
                if a.json() is None or not a.content_type.startswith("application/json")]
    assert not not_json, not_json
    statuses = sorted({(a.status, (a.json() or {}).get("error", {}).get("code")) for a in answers})
    assert set(statuses) <= {(200, None), (503, "shutting_down")}, statuses
    assert (503, "shutting_down") in statuses  # the queue was still long at SIGTERM
    assert exit_s < DRAIN_S + GRACE_S, exit_s
    assert "Exception in ASGI application" not in srv.logs()
