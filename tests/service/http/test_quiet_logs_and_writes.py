"""Smaller items of issue 53 (item 8) against a real `rsmt serve`: refused WebSocket handshakes are not logged as
errors, a BVH with moving non-root bones gives one warning per document (not one per bone), and a client that
pipelines requests and never reads its answers is cut off after the write timeout."""

from __future__ import annotations

import re
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from websockets.exceptions import InvalidStatus

from tests.service.conftest import bvh, walk
from tests.service.server import Server
from tests.service.wsclient import Ws

pytestmark = pytest.mark.slow  # waits out a write timeout

KEY = "quiet-logs-key-0123456789abcdef"
WRITE_S = 2.0
SERVE = ["rsmt", "serve", "--host", "127.0.0.1", "--port", "{port}"]


@pytest.fixture(scope="module")
def server(bundle_dir) -> Iterator[Server]:
    srv = Server(bundle_dir, env={"RSMT_API_KEYS": KEY, "RSMT_LOG_LEVEL": "info", "RSMT_LOG_FORMAT": "text",
                                  "RSMT_WRITE_TIMEOUT_S": str(WRITE_S), "RSMT_OPEN_DOCS_AND_METRICS": "true"},
                 command=SERVE).start()
    yield srv
    srv.stop()


def _logs(server: Server) -> str:
    server.log.flush()
    return Path(server.log.name).read_text()


def test_refused_handshakes_are_not_errors(server):
    before = len(_logs(server).splitlines())
    for query in ("", "token=not-the-key-0123456789", "encoding=json"):
        with pytest.raises(InvalidStatus):
            Ws(server.ws, query=query)
    with Ws(server.ws, query=f"token={KEY}") as ws:  # an accepted one, for comparison
        assert ws.ping("ok") == []
    time.sleep(0.5)
    lines = _logs(server).splitlines()[before:]
    assert not [line for line in lines if " ERROR " in line or "without completing handshake" in line], lines
    # At info, still told: our rewording of uvicorn's message (up to 0.54), or uvicorn's own info line (0.55 on).
    told = [line for line in lines if " INFO " in line and ("handshake refused" in line or "connection rejected (" in line)]
    assert len(told) == 3, lines


def _moving_bones_bvh(frames: int = 40) -> str:
    """A valid take whose every non-root joint has position channels that move (a rig with stretchy bones)."""
    lines = bvh(walk(frames))["bvh"].splitlines()
    offsets: list[list[float]] = []
    out: list[str] = []
    for i, line in enumerate(lines):
        if line.strip() == "CHANNELS 3 Zrotation Xrotation Yrotation":
            offsets.append([float(v) for v in lines[i - 1].split()[1:4]])
            line = line.replace("CHANNELS 3", "CHANNELS 6 Xposition Yposition Zposition")
        out.append(line)
    motion_at = next(i for i, line in enumerate(out) if line.startswith("Frame Time:")) + 1
    for t in range(motion_at, len(out)):
        values = out[t].split()
        row = values[:6]
        for j, (x, y, z) in enumerate(offsets):
            row += [f"{x + 0.5 * (t - motion_at):.4f}", f"{y:.4f}", f"{z:.4f}", *values[6 + 3 * j:9 + 3 * j]]
        out[t] = " ".join(row)
    return "\n".join(out) + "\n"


def test_moving_non_root_bones_warn_once_per_document(server):
    text = _moving_bones_bvh()
    before = len(_logs(server).splitlines())
    r = httpx.post(server.url + "/v1/styles", json={"name": "stretchy", "motion": {"bvh": text}},
                   headers={"X-API-Key": KEY}, timeout=30)
    assert r.status_code == 201, r.text
    time.sleep(0.5)
    lines = _logs(server).splitlines()[before:]
    warned = [line for line in lines if "non-root joints move" in line or "moves by up to" in line]
    assert len(warned) == 1, warned
    assert re.search(r"\b\d+ position channel\(s\)", warned[0]), warned


def test_a_client_that_pipelines_and_never_reads_is_cut_off(server):
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", server.port))
    requests = b"GET /openapi.json HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n" * 400

    def send() -> None:
        try:
            sock.settimeout(WRITE_S + 20)
            sock.sendall(requests)
        except OSError:
            pass

    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    time.sleep(WRITE_S + 4.0)  # the server's writes block on us, then the timeout runs out
    # Cut off: what the kernel had already received is readable, then the reset. Still open: the server goes
    # on answering (400 answers of 30 KB) as soon as this starts reading.
    sock.settimeout(5.0)
    received, cut_off = 0, False
    try:
        while received < 1 << 20:
            chunk = sock.recv(1 << 16)
            if not chunk:
                cut_off = True
                break
            received += len(chunk)
    except ConnectionResetError:
        cut_off = True
    except TimeoutError:
        pass
    finally:
        sock.close()
        sender.join(25)
    assert cut_off, "the connection was still open past the write timeout"
    assert httpx.get(server.url + "/v1/health/live", timeout=10).status_code == 200
    assert "Traceback" not in _logs(server)  # the requests cut off end quietly
