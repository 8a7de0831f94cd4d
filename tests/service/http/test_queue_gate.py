"""A request for model work that a full queue would refuse is refused before its body is read (issue 24, row 4:
"answered at once"), against a real ``rsmt serve`` whose transitions hold the one work thread
(``tests/service/slow_engine.py``): one running and one waiting fill a queue bound of 1.

The refused client has sent its headers and only the first KB of an 850 KB body: it gets 503 ``overloaded``
with ``Retry-After`` without sending the rest, and once it has sent the rest the same connection serves its
next request (the unread body is discarded, not answered with a reset)."""

from __future__ import annotations

import json
import socket

import pytest

from tests.service.burst import Burst, metric, post, wait_for
from tests.service.conftest import transition_body
from tests.service.raw_reads import read_until
from tests.service.slow_engine import slow_server

pytestmark = pytest.mark.slow  # fills the work queue of a slowed server

DELAY_S = 5.0  # each transition holds the work thread this long: the queue stays full for at least that
FRAMES = 10
BODY_BYTES = 850_000


@pytest.fixture(scope="module")
def server(bundle_dir):
    srv = slow_server(bundle_dir, DELAY_S, 1)
    srv.start()
    yield srv
    srv.stop()


def _padded_body() -> bytes:
    """A transition request padded to BODY_BYTES with an extra field (never parsed: it is refused first)."""
    body = json.dumps(transition_body(frames=FRAMES)).encode()
    return body[:-1] + b', "pad": "' + b"x" * (BODY_BYTES - len(body) - 11) + b'"}'


def _read_response(s: socket.socket) -> tuple[bytes, dict[str, str], bytes]:
    """Status line, headers (lower-case names) and body (by Content-Length) of one response."""
    data = read_until(s, b"\r\n\r\n", 65536)  # a server still waiting for the body never answers: the socket times out
    head, _, rest = data.partition(b"\r\n\r\n")
    status, *lines = head.decode("latin-1").split("\r\n")
    headers = {k.strip().lower(): v.strip() for k, _, v in (line.partition(":") for line in lines)}
    length = int(headers.get("content-length", "0"))
    while len(rest) < length:
        chunk = s.recv(65536)
        if not chunk:
            break
        rest += chunk
    return status.encode(), headers, rest[:length]


def test_a_full_queue_refuses_before_the_body_is_read(server):
    body = _padded_body()
    assert len(body) == BODY_BYTES
    running = Burst(server.url, transition_body(frames=FRAMES), 2)  # one runs, one waits: the queue is full
    assert wait_for(lambda: metric(server.url, "rsmt_work_queue_waiting") >= 1, 30)
    rejected = metric(server.url, "rsmt_work_queue_jobs_total", outcome="rejected")
    with socket.create_connection(("127.0.0.1", server.port), timeout=20) as s:
        s.sendall(b"POST /v1/transition HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                  b"Content-Length: %d\r\n\r\n" % len(body) + body[:1000])
        status, headers, answer = _read_response(s)
        assert status.startswith(b"HTTP/1.1 503 "), (status, answer[:300])
        assert headers["content-type"].startswith("application/json")
        assert json.loads(answer)["error"]["code"] == "overloaded", answer
        assert int(headers["retry-after"]) >= 1
        assert headers.get("connection", "keep-alive") != "close"
        # The rest of the body is discarded as it arrives; the connection then serves the next request.
        s.sendall(body[1000:] + b"GET /v1/health/live HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        status, _, answer = _read_response(s)
        assert status.startswith(b"HTTP/1.1 200 "), (status, answer[:300])
    assert metric(server.url, "rsmt_work_queue_jobs_total", outcome="rejected") == rejected + 1
    # The refusal is labelled with its route in the request metric, like the queue's own refusals.
    assert metric(server.url, "rsmt_http_request_duration_seconds_count", route="/v1/transition", status="503") >= 1
    assert [a.status for a in running.join()] == [200, 200]


def test_clients_stalling_in_their_bodies_do_not_fill_the_queue(server):
    """Requests still sending their bodies hold no place: as many stalled bodies as the queue holds (one running,
    one waiting), and a whole request is still served."""
    body = _padded_body()
    stalled = [socket.create_connection(("127.0.0.1", server.port), timeout=20) for _ in range(2)]
    try:
        for s in stalled:
            s.sendall(b"POST /v1/transition HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                      b"Content-Length: %d\r\n\r\n" % len(body) + body[:1000])
        answer = post(server.url, transition_body(frames=FRAMES), timeout_s=60)
        assert answer.status == 200, (answer.status, answer.body[:300])
    finally:
        for s in stalled:
            s.close()


def test_other_routes_pass_while_the_queue_is_full(server):
    running = Burst(server.url, transition_body(frames=FRAMES), 2)
    assert wait_for(lambda: metric(server.url, "rsmt_work_queue_waiting") >= 1, 30)
    with socket.create_connection(("127.0.0.1", server.port), timeout=20) as s:
        s.sendall(b"GET /v1/model HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        status, _, answer = _read_response(s)
    assert status.startswith(b"HTTP/1.1 200 "), (status, answer[:300])
    assert [a.status for a in running.join()] == [200, 200]
