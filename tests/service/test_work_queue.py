"""The bounded work queue in front of a model's work threads, against a real ``rsmt serve`` whose whole
transitions are slowed by a sleep (``tests/service/slow_engine.py``): one work thread, at most 4 waiting.

A full queue answers 503 ``overloaded`` with ``Retry-After`` at once; a request whose client has gone is
dropped before it runs; a WebSocket ``start`` does not wait behind the HTTP queue."""

from __future__ import annotations

import time

import pytest

from tests.service.burst import Burst, metric, post, wait_for
from tests.service.conftest import bvh, transition_body, walk
from tests.service.slow_engine import slow_server
from tests.service.wsclient import Ws, start_message

pytestmark = pytest.mark.slow  # fills the work queue of a slowed server (bounds in its sleeps: it may share the machine)

DELAY_S = 1.5  # each transition holds the one work thread this long
LIMIT = 4
FRAMES = 10


@pytest.fixture(scope="module")
def server(bundle_dir):
    srv = slow_server(bundle_dir, DELAY_S, LIMIT)
    srv.start()
    yield srv
    srv.stop()


def _idle(server) -> None:
    """Wait until nothing runs or waits (the previous test's requests are done)."""
    assert wait_for(lambda: metric(server.url, "rsmt_work_queue_waiting") == 0, 30)
    time.sleep(DELAY_S + 0.5)


def test_a_full_queue_answers_503_overloaded_at_once(server):
    _idle(server)
    burst = Burst(server.url, transition_body(frames=FRAMES), 12)
    answers = burst.join()
    ok = [a for a in answers if a.status == 200]
    refused = [a for a in answers if a.status == 503]
    assert len(ok) + len(refused) == 12, [(a.status, a.body[:200], a.error) for a in answers]
    # One runs and LIMIT wait; the rest are refused (a request sent late may find room, never more).
    assert LIMIT + 1 >= len(ok) >= 2 and len(refused) >= 12 - (LIMIT + 1) - 2
    for a in refused:
        assert a.content_type.startswith("application/json")
        body = a.json()
        assert body is not None and body["error"]["code"] == "overloaded", a.body
        assert a.retry_after is not None and int(a.retry_after) >= 1
        assert a.seconds < DELAY_S, a.seconds  # at once: before even one queued job could have run
    for a in ok:
        body = a.json()
        assert body is not None and len(body["frames"]) == FRAMES, a.body
    assert max(a.seconds for a in ok) >= DELAY_S * (len(ok) - 1)  # the accepted ones did wait their turn
    assert metric(server.url, "rsmt_work_queue_jobs_total", outcome="rejected") >= len(refused)


def test_a_request_whose_client_left_is_not_run(server):
    _idle(server)
    runs = metric(server.url, "rsmt_work_queue_jobs_total", outcome="run")
    frames = metric(server.url, "rsmt_transition_frames_total")
    first = Burst(server.url, transition_body(frames=FRAMES), 2)  # hold the work thread for 2 * DELAY_S
    wait_for(lambda: metric(server.url, "rsmt_work_queue_waiting") >= 1, 5)
    # Three clients give up long before the thread is free; their requests would each hold it DELAY_S.
    gave_up = Burst(server.url, transition_body(frames=FRAMES), 3, timeout_s=0.3).join()
    assert all(a.status is None for a in gave_up), [(a.status, a.body[:100]) for a in gave_up]
    after = post(server.url, transition_body(frames=FRAMES), timeout_s=60)
    assert [a.status for a in first.join()] == [200, 200]
    assert after.status == 200, after.body
    assert wait_for(lambda: metric(server.url, "rsmt_work_queue_waiting") == 0, 30)
    time.sleep(DELAY_S + 0.5)  # time for an abandoned request to have run, were it run
    seen = {k: metric(server.url, "rsmt_work_queue_jobs_total", outcome=k) for k in ("run", "abandoned")}
    # Only the first two and the last were generated.
    assert metric(server.url, "rsmt_transition_frames_total") == frames + 3 * FRAMES, seen
    assert seen["run"] == runs + 3 and seen["abandoned"] >= 3, seen
    # It waited for the first two at most (2 * DELAY_S), not for the three abandoned ones as well (3 * DELAY_S).
    answer = after.json()
    assert answer is not None, after.body
    queued_ms = answer["timing_ms"]["queue"]
    assert queued_ms < 4 * DELAY_S * 1e3, queued_ms


def test_a_stream_start_does_not_wait_behind_http_work(server):
    _idle(server)
    burst = Burst(server.url, transition_body(frames=FRAMES), LIMIT + 1)  # one running, LIMIT waiting
    wait_for(lambda: metric(server.url, "rsmt_work_queue_waiting") >= LIMIT, 3)
    with Ws(server.ws) as ws:
        sent = time.monotonic()
        ws.send(start_message("hero", 20, style=bvh(walk(30))))
        first = ws.recv(timeout=30)
        started_after = time.monotonic() - sent
        assert first["type"] == "started", first
        out = ws.run({"hero"}, timeout=30)
    assert len(out["hero"]["frames"]) == 20 and out["hero"]["end"]["reason"] == "arrived"
    # The HTTP queue holds (LIMIT + 1) * DELAY_S = 7.5 s of work; the start was served beside it.
    assert started_after < DELAY_S, started_after
    assert all(a.status == 200 for a in burst.join())
