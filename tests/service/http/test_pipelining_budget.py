"""One connection pipelining requests and never reading its answers (issue 64, item 2) against a real
`rsmt serve` with keys on, beside another key's real-time stream: its requests are started at most
``RSMT_PIPELINED_REQUESTS_PER_S`` a second, so it holds neither a core (it held one: 300k answers in 12 s)
nor the other key's frames (tests/service/pipeline_flood.py floods from a process of its own); pipelined
requests are still all answered, in order."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.service.probes import GapProbe, cpu_seconds, p99
from tests.service.server import Server

pytestmark = pytest.mark.slow  # a 5 s flood beside a stream

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
        time.sleep(1.0)  # the stream settles
        quiet_from, quiet_cpu = time.monotonic(), cpu_seconds(pid)
        time.sleep(3.0)
        quiet_until = time.monotonic()
        quiet_rate = (cpu_seconds(pid) - quiet_cpu) / (quiet_until - quiet_from)
        flood = subprocess.Popen([sys.executable, "-m", "tests.service.pipeline_flood", "--port", str(server.port),
                                  "--seconds", str(FLOOD_S)], stdout=subprocess.PIPE, text=True,
                                 cwd=Path(__file__).resolve().parents[3])
        assert flood.stdout is not None and flood.stdout.readline().strip() == "ready"
        since, flood_cpu = time.monotonic(), cpu_seconds(pid)  # from the flood's start
        out = json.loads(flood.stdout.readline())
        flood.wait(10)
        until = time.monotonic()
        extra = cpu_seconds(pid) - flood_cpu - quiet_rate * (until - since)
        quiet_fps = probe.frames_in(quiet_from, quiet_until) / (quiet_until - quiet_from)
        flood_fps = probe.frames_in(since, since + FLOOD_S) / FLOOD_S
        gaps = probe.gaps_ms(since, since + FLOOD_S)
    print(f"pipelining {out.get('sent', 0)} requests in {FLOOD_S:g} s, never reading: {extra:.2f} s of extra server "
          f"CPU in {until - since:.2f} s; the other stream {flood_fps:.0f} frames/s (before: {quiet_fps:.0f}), p99 gap "
          f"{p99(gaps):.1f} ms")
    assert not probe.errors, probe.errors
    assert "error" not in out, out  # the connection stayed open all along: the flood lasted
    assert extra < 0.25 * (until - since), f"the pipelining connection took {extra:.2f} s of CPU"
    assert flood_fps >= 0.8 * quiet_fps


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
