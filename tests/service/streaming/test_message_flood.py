"""One key's WebSocket message flood (issue 64, item 2) against a real server with keys on, beside another
key's real-time stream: ``ping`` messages in batches of 2,000 on a raw socket that never reads, reconnecting
whenever the server ends the connection. Each connection is closed with 1008 once past its message budget,
before its messages are read, and the other key's stream keeps at least 80% of its frames (it got 10 frames
in 10 s); a client within its budgets is served as before."""

from __future__ import annotations

import base64
import os
import socket
import struct
import threading
import time
from collections.abc import Iterator

import httpx
import pytest

from tests.service.probes import GapProbe, cpu_seconds, p99
from tests.service.server import Server
from tests.service.wsclient import Ws

pytestmark = pytest.mark.slow  # a 5 s flood beside a stream

KEY_A, KEY_B, KEY_C = "flood-key-a-0123456789abcdef", "flood-key-b-0123456789abcdef", "flood-key-c-0123456789abcdef"
FLOOD_S = 5.0
BATCH = 2000


@pytest.fixture(scope="module")
def server(bundle_dir) -> Iterator[Server]:
    srv = Server(bundle_dir, env={"RSMT_API_KEYS": f"{KEY_A},{KEY_B},{KEY_C}"}).start()
    yield srv
    srv.stop()


def _frame(text: bytes) -> bytes:
    """A masked client text frame (an all-zero mask: the payload goes as it is)."""
    assert len(text) < 126
    return bytes([0x81, 0x80 | len(text)]) + b"\0\0\0\0" + text


def _open(port: int, key: str) -> tuple[socket.socket, bytes]:
    """A raw WebSocket connection of ``key``, handshake done; what came after the 101's head."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=10)
    nonce = base64.b64encode(os.urandom(16)).decode()
    sock.sendall(f"GET /v1/stream?token={key} HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n"
                 f"Connection: Upgrade\r\nSec-WebSocket-Key: {nonce}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode())
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(4096)
        if not chunk:
            break
        data += chunk
    head, _, rest = data.partition(b"\r\n\r\n")
    if not head.startswith(b"HTTP/1.1 101"):
        sock.close()
        raise ConnectionRefusedError(head.split(b"\r\n", 1)[0].decode(errors="replace"))
    return sock, rest


def _close_code(data: bytes) -> int | None:
    """The code of the close frame among the server's (unmasked) frames in ``data``, if one is there."""
    pos = 0
    while pos + 2 <= len(data):
        opcode, size = data[pos] & 0x0F, data[pos + 1] & 0x7F
        pos += 2
        if size == 126:
            size, pos = struct.unpack_from("!H", data, pos)[0], pos + 2
        elif size == 127:
            size, pos = struct.unpack_from("!Q", data, pos)[0], pos + 8
        if opcode == 0x8 and pos + 2 <= len(data):
            return int(struct.unpack_from("!H", data, pos)[0])
        pos += size
    return None


def _drain(sock: socket.socket, data: bytes) -> bytes:
    sock.settimeout(2.0)
    try:
        while chunk := sock.recv(65536):
            data += chunk
    except OSError:
        pass
    return data


def _flood(port: int, seconds: float, out: dict) -> None:
    """Ping batches for ``seconds`` on connections of KEY_A that never read, a new one whenever the server ends
    one; ``out``: messages sent, connections opened and refused, and the close codes the ended ones got."""
    batch = _frame(b'{"type":"ping","id":1}') * BATCH
    sent = opened = refused = 0
    codes: list[int | None] = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            sock, rest = _open(port, KEY_A)
        except (ConnectionRefusedError, OSError):  # 429: the key's budget is spent; try again at once
            refused += 1
            continue
        opened += 1
        sock.settimeout(0.2)
        try:
            while time.monotonic() < deadline:
                try:
                    sock.sendall(batch)
                    sent += BATCH
                except TimeoutError:  # the server reads no more for now
                    continue
        except OSError:  # the server ended the connection
            pass
        codes.append(_close_code(_drain(sock, rest)))
        sock.close()
    out.update(sent=sent, opened=opened, refused=refused, codes=codes)


def _closes_1008(server: Server) -> float:
    text = httpx.get(server.url + "/metrics", headers={"X-API-Key": KEY_B}, timeout=10).text
    return sum(float(line.rsplit(" ", 1)[1]) for line in text.splitlines()
               if line.startswith("rsmt_ws_closes_total") and 'code="1008"' in line)


def test_a_non_reading_ping_flood_is_closed_and_leaves_the_other_key_its_frames(server):
    assert server.proc is not None
    pid = server.proc.pid
    closes_before = _closes_1008(server)
    with GapProbe(server.ws, characters=4, query=f"token={KEY_B}") as probe:
        time.sleep(1.0)  # the stream settles
        quiet_from, quiet_cpu = time.monotonic(), cpu_seconds(pid)
        time.sleep(3.0)
        since, flood_cpu = time.monotonic(), cpu_seconds(pid)
        quiet_rate = (flood_cpu - quiet_cpu) / (since - quiet_from)
        out: dict = {}
        flood = threading.Thread(target=_flood, args=(server.port, FLOOD_S, out))
        flood.start()
        flood.join(FLOOD_S + 30)
        until = time.monotonic()
        extra = cpu_seconds(pid) - flood_cpu - quiet_rate * (until - since)
        quiet_fps = probe.frames_in(quiet_from, since) / (since - quiet_from)
        flood_fps = probe.frames_in(since, until) / (until - since)
        gaps = probe.gaps_ms(since, until)
    closes = _closes_1008(server) - closes_before
    print(f"ping flood of one key for {FLOOD_S:g} s: {out['sent']} messages sent on {out['opened']} connections "
          f"({out['refused']} handshakes refused), close codes {sorted(set(out['codes']), key=str)}, {closes:g} "
          f"closed with 1008; {extra:.2f} s of extra server CPU in {until - since:.2f} s; the other key's stream "
          f"{flood_fps:.0f} frames/s (before: {quiet_fps:.0f}), p99 gap {p99(gaps):.1f} ms")
    assert not probe.errors, probe.errors
    assert flood_fps >= 0.8 * quiet_fps, f"the other key's stream got {flood_fps / quiet_fps:.0%} of its frames"
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
