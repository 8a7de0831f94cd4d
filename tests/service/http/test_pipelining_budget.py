"""One connection pipelining requests and never reading its answers (issue 64, item 2) against a real
`rsmt serve` with keys on, beside another key's real-time stream: its requests are started at most
``RSMT_PIPELINED_REQUESTS_PER_S`` a second, so it holds neither a core (it held one: 300k answers in 12 s)
nor the other key's frames (tests/service/pipeline_flood.py floods from a process of its own); pipelined
requests are still all answered, in order."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator

import pytest

from tests.service.probes import GapProbe, p99, run_flood
from tests.service.server import Server

pytestmark = [pytest.mark.slow, pytest.mark.alone]  # a 5 s flood beside a stream

KEY = "pipelining-key-0123456789abcdef"
SERVE = ["rsmt", "serve", "--host", "127.0.0.1", "--port", "{port}"]
FLOOD_S = 5.0


@pytest.fixture(scope="module")
def server(bundle_dir) -> Iterator[Server]:
    srv = Server(bundle_dir, env={"RSMT_API_KEYS": KEY}, command=SERVE).start()
    yield srv
    srv.stop()


def test_a_pipelining_connection_that_never_reads_holds_no_core(server):
    assert server.proc is not None
    pid = server.proc.pid
    with GapProbe(server.ws, characters=4, query=f"token={KEY}") as probe:
        run = run_flood(pid, probe, "tests.service.pipeline_flood",
                        ["--port", str(server.port), "--seconds", str(FLOOD_S)], FLOOD_S)
    out = run.out
    print(f"pipelining {out.get('sent', 0)} requests in {FLOOD_S:g} s, never reading: {run.extra_cpu_s:.2f} s of extra "
          f"server CPU in {run.seconds:.2f} s; the other stream {run.flood_fps:.0f} frames/s (before: "
          f"{run.quiet_fps:.0f}), p99 gap {p99(run.gaps):.1f} ms")
    assert not probe.errors, probe.errors
    assert "error" not in out, out  # the connection stayed open all along: the flood lasted
    assert run.extra_cpu_s < 0.25 * run.seconds, f"the pipelining connection took {run.extra_cpu_s:.2f} s of CPU"
    assert run.flood_fps >= 0.8 * run.quiet_fps


def test_pipelined_requests_are_all_answered_in_order(server):
    count = 250
    request = b"".join(b"GET /v1/health/live?n=%d HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n" % i for i in range(count))
    started = time.monotonic()
    with socket.create_connection(("127.0.0.1", server.port), timeout=30) as sock:
        sock.sendall(request + b"GET /v1/health/ready HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
        data = b""
        while chunk := sock.recv(65536):
            data += chunk
    seconds = time.monotonic() - started
    print(f"{count + 1} pipelined requests answered in {seconds:.2f} s")
    assert data.count(b"HTTP/1.1 200 ") == count + 1
    assert data.rstrip().endswith(b'"ready"}') or b"ready" in data.rsplit(b"HTTP/1.1 200 ", 1)[1]
