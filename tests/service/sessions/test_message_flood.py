"""One key's WebSocket message flood (issue 64, item 2) against a real server with keys on, beside another
key's real-time stream: ``ping`` messages in batches of 2,000 on raw sockets that never read, reconnecting
whenever the server ends the connection (tests/service/ws_flood.py, in a process of its own). Each connection
is closed with 1008 once past its message budget, before its messages are read, and the other key's stream
keeps at least 80% of its frames (it got 10 frames in 10 s); a client within its budgets is served as before."""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import pytest

from tests.service.probes import GapProbe, p99, run_flood
from tests.service.server import Server
from tests.service.wsclient import Ws

pytestmark = [pytest.mark.slow, pytest.mark.alone]  # a 5 s flood beside a stream

KEY_A, KEY_B, KEY_C = "flood-key-a-0123456789abcdef", "flood-key-b-0123456789abcdef", "flood-key-c-0123456789abcdef"
FLOOD_S = 5.0
BATCH = 2000


@pytest.fixture(scope="module")
def server(bundle_dir) -> Iterator[Server]:
    srv = Server(bundle_dir, env={"RSMT_API_KEYS": f"{KEY_A},{KEY_B},{KEY_C}"}).start()
    yield srv
    srv.stop()


def _closes_1008(server: Server) -> float:
    text = httpx.get(server.url + "/metrics", headers={"X-API-Key": KEY_B}, timeout=10).text
    return sum(float(line.rsplit(" ", 1)[1]) for line in text.splitlines()
               if line.startswith("rsmt_ws_closes_total") and 'code="1008"' in line)


def test_a_non_reading_ping_flood_is_closed_and_leaves_the_other_key_its_frames(server):
    assert server.proc is not None
    pid = server.proc.pid
    closes_before = _closes_1008(server)
    with GapProbe(server.ws, characters=4, query=f"token={KEY_B}") as probe:
        run = run_flood(pid, probe, "tests.service.ws_flood", ["--port", str(server.port), "--key", KEY_A,
                                                               "--seconds", str(FLOOD_S), "--batch", str(BATCH)], FLOOD_S)
    out = run.out
    closes = _closes_1008(server) - closes_before
    print(f"ping flood of one key for {FLOOD_S:g} s: {out['sent']} messages sent on {out['opened']} connections "
          f"({out['refused']} handshakes refused), close codes {sorted(set(out['codes']), key=str)}, {closes:g} "
          f"closed with 1008; {run.extra_cpu_s:.2f} s of extra server CPU in {run.seconds:.2f} s; the other key's "
          f"stream {run.flood_fps:.0f} frames/s (before: {run.quiet_fps:.0f}), p99 gap {p99(run.gaps):.1f} ms")
    assert not probe.errors, probe.errors
    assert run.flood_fps >= 0.8 * run.quiet_fps, f"the other key's stream got {run.flood_fps / run.quiet_fps:.0%} of its frames"
    assert out["opened"] >= 1 and closes >= 1
    assert 1008 in out["codes"], out["codes"]  # the flooder got a 1008 close frame


def test_a_client_within_its_budgets_is_served(server):
    """A burst of 300 pings (within the connection's burst of 400) is answered in full; the connection stays."""
    with Ws(server.ws, query=f"token={KEY_C}") as ws:
        for i in range(300):
            ws.send({"type": "ping", "id": i})
        pongs = [ws.recv(timeout=20) for _ in range(300)]
        assert [m.get("id") for m in pongs] == list(range(300))
        assert ws.ping("after") == []
