"""A hung Redis (issue 53, item 5) against a real server with ``RSMT_STYLE_STORE=redis://``: with redis-server
paused (SIGSTOP: connections are accepted, nothing is answered), ``style_id`` requests answer 503
``style_store_unavailable`` within about the store timeout (1 s), and transitions with an inline style, which
never touch the store, keep their rate while those requests keep coming. Redis is resumed at the end."""

from __future__ import annotations

import signal
import statistics
import threading
import time
from collections.abc import Iterator

import httpx
import pytest

from tests.service.conftest import transition_body
from tests.service.processes import RedisProcess
from tests.service.server import Server

pytestmark = [pytest.mark.slow, pytest.mark.alone]  # a real redis-server, paused and resumed

SECONDS = 4.0
STYLE_ID_CLIENTS = 3


@pytest.fixture(scope="module")
def redis() -> Iterator[RedisProcess]:
    srv = RedisProcess().start()
    yield srv
    srv.cleanup()


@pytest.fixture(scope="module")
def server(bundle_dir, redis) -> Iterator[Server]:
    srv = Server(bundle_dir, env={"RSMT_STYLE_STORE": redis.url, "RSMT_STYLE_STORE_TIMEOUT_S": "1"}).start()
    yield srv
    srv.stop()


def _inline_rate(server: Server, seconds: float) -> float:
    done, started = 0, time.monotonic()
    with httpx.Client(base_url=server.url, timeout=30) as client:
        while time.monotonic() - started < seconds:
            r = client.post("/v1/transition", json=transition_body(20))
            assert r.status_code == 200, r.text
            done += 1
    return done / (time.monotonic() - started)


def test_a_paused_redis_stalls_only_the_requests_that_need_it(server, redis):
    with httpx.Client(base_url=server.url, timeout=30) as client:
        r = client.post("/v1/styles", json={"name": "walk", "motion": transition_body()["style"]})
        assert r.status_code == 201, r.text
        sid = r.json()["style_id"]
        assert client.post("/v1/transition", json=transition_body(20, style_id=sid)).status_code == 200
    before = _inline_rate(server, SECONDS)
    answers: list[tuple[int, str, float]] = []
    stop = threading.Event()

    def style_id_requests() -> None:
        with httpx.Client(base_url=server.url, timeout=30) as client:
            while not stop.is_set():
                started = time.monotonic()
                r = client.post("/v1/transition", json=transition_body(20, style_id=sid))
                code = r.json().get("error", {}).get("code", "") if r.status_code != 200 else ""
                answers.append((r.status_code, code, time.monotonic() - started))

    assert redis.proc is not None
    redis.proc.send_signal(signal.SIGSTOP)
    try:
        time.sleep(0.2)
        threads = [threading.Thread(target=style_id_requests, daemon=True) for _ in range(STYLE_ID_CLIENTS)]
        for t in threads:
            t.start()
        time.sleep(0.5)
        during = _inline_rate(server, SECONDS)
        stop.set()
        for t in threads:
            t.join(30)
    finally:
        redis.proc.send_signal(signal.SIGCONT)
    late = max(s for _, _, s in answers)
    typical = statistics.median(s for _, _, s in answers)
    print(f"inline transitions: {before:.1f}/s before, {during:.1f}/s with Redis paused and {STYLE_ID_CLIENTS} "
          f"clients sending style_id requests ({len(answers)} answered 503, median {typical:.2f} s, slowest "
          f"{late:.2f} s)")
    assert answers and all((status, code) == (503, "style_store_unavailable") for status, code, _ in answers), answers
    # The store timeout (1 s) plus the request's own handling, which on a loaded 2-core test machine is a few
    # tenths of a second (an inline transition there takes most of a second).
    assert typical < 1.5 and late < 2.0, answers
    assert during > 0.6 * before
    with httpx.Client(base_url=server.url, timeout=30) as client:  # Redis is back: so are the styles
        deadline = time.monotonic() + 10
        while client.post("/v1/transition", json=transition_body(20, style_id=sid)).status_code != 200:
            assert time.monotonic() < deadline, "the style store did not come back"
            time.sleep(0.2)
