"""Slow and hostile connections against a real `rsmt serve` (service/http/connection_guard.py): partial headers,
half-sent bodies and stalled WebSocket handshakes are closed within their timeouts, and connections past the
per-address cap are closed at once while other addresses are still served.

Timing checks use wide margins: a connection must be closed no earlier than its timeout (less a little for
clock granularity) and no later than the timeout plus CLOSE_MARGIN_S."""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Iterator

import httpx
import pytest
from websockets.sync.client import connect

from tests.service.server import Server

pytestmark = pytest.mark.slow  # waits out header and body timeouts (wide margins: it may share the machine)

HEADER_S, BODY_S, HANDSHAKE_S, CAP = 6.0, 1.0, 1.0, 8
CLOSE_MARGIN_S = 3.0
LIMITS = {"RSMT_HEADER_TIMEOUT_S": str(HEADER_S), "RSMT_BODY_TIMEOUT_S": str(BODY_S),
          "RSMT_WS_HANDSHAKE_TIMEOUT_S": str(HANDSHAKE_S), "RSMT_MAX_CONNECTIONS_PER_ADDRESS": str(CAP)}
SERVE = ["rsmt", "serve", "--host", "127.0.0.1", "--port", "{port}"]
ATTACKER = "127.0.0.2"  # Linux routes all of 127/8 over loopback: a second client address on one machine


@pytest.fixture(scope="module")
def server(bundle_dir) -> Iterator[Server]:
    srv = Server(bundle_dir, env=LIMITS, command=SERVE).start()
    yield srv
    srv.stop()


def _open(server: Server, source: str = "127.0.0.1") -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.bind((source, 0))
    sock.connect(("127.0.0.1", server.port))
    return sock


def _wait_closed(sock: socket.socket, limit_s: float) -> tuple[float, bytes]:
    """Seconds until the server closed ``sock`` (inf if it had not within ``limit_s``) and what it sent first."""
    start = time.monotonic()
    received = b""
    while (left := limit_s - (time.monotonic() - start)) > 0:
        sock.settimeout(left)
        try:
            chunk = sock.recv(4096)
        except TimeoutError:
            break
        except ConnectionResetError:
            return time.monotonic() - start, received
        if not chunk:
            return time.monotonic() - start, received
        received += chunk
    return float("inf"), received


def _ready(server: Server, source: str) -> int:
    """``GET /v1/health/ready`` from ``source``: the status, or 0 when no answer came."""
    transport = httpx.HTTPTransport(local_address=source)
    try:
        with httpx.Client(base_url=server.url, transport=transport, timeout=10.0) as client:
            return client.get("/v1/health/ready").status_code
    except httpx.HTTPError:
        return 0


def test_partial_headers_are_answered_408_and_closed_after_the_header_timeout(server):
    with _open(server) as sock:  # headers sent slowly, but within the bound, are served
        for part in (b"GET /v1/health/ready HTTP/1.1\r\n", b"Host: 127.0.0.1\r\n", b"Connection: close\r\n\r\n"):
            sock.sendall(part)
            time.sleep(0.5)
        _, answer = _wait_closed(sock, 10.0)
    assert answer.startswith(b"HTTP/1.1 200 "), answer
    with _open(server) as sock:
        sock.sendall(b"GET /v1/health/ready HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
        elapsed, answer = _wait_closed(sock, HEADER_S + CLOSE_MARGIN_S)
    assert HEADER_S - 0.5 <= elapsed <= HEADER_S + CLOSE_MARGIN_S, elapsed
    assert answer.startswith(b"HTTP/1.1 408 "), answer


def test_a_connection_that_sends_nothing_is_closed_after_the_header_timeout(server):
    with _open(server) as sock:
        elapsed, answer = _wait_closed(sock, HEADER_S + CLOSE_MARGIN_S)
    assert HEADER_S - 0.5 <= elapsed <= HEADER_S + CLOSE_MARGIN_S, elapsed
    assert answer == b""  # nothing was asked, so nothing is answered


def test_a_half_sent_body_is_closed_after_the_body_timeout(server):
    with _open(server) as sock:
        sock.sendall(b"POST /v1/transition HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                     b"Content-Length: 1000\r\n\r\n{\"frames\": 40, ")
        elapsed, answer = _wait_closed(sock, BODY_S + CLOSE_MARGIN_S)
    assert BODY_S - 0.5 <= elapsed <= BODY_S + CLOSE_MARGIN_S, elapsed
    assert answer.startswith(b"HTTP/1.1 408 "), answer


def test_a_body_dripped_in_time_per_chunk_but_not_in_total_is_closed(server):
    """The body timeout is a total from the end of the headers: a byte every 0.3 s does not extend it."""
    with _open(server) as sock:
        sock.sendall(b"POST /v1/transition HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                     b"Content-Length: 1000\r\n\r\n")
        start = time.monotonic()
        closed_at = float("inf")
        for _ in range(int((BODY_S + CLOSE_MARGIN_S) / 0.3)):
            try:
                sock.sendall(b" ")
            except OSError:  # reset: the server has closed it
                closed_at = time.monotonic() - start
                break
            time.sleep(0.3)
        if closed_at == float("inf"):
            elapsed, _ = _wait_closed(sock, 1.0)
            closed_at = time.monotonic() - start if elapsed != float("inf") else closed_at
    assert closed_at <= BODY_S + CLOSE_MARGIN_S + 1.0, closed_at


def test_a_stalled_websocket_handshake_is_closed_after_the_handshake_timeout(server):
    """The upgrade request stalls after its Upgrade header: closed on the handshake bound (1 s), well before
    the header bound (6 s) that an ordinary request gets."""
    with _open(server) as sock:
        sock.sendall(b"GET /v1/stream HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                     b"Sec-WebSocket-Version: 13\r\n")
        elapsed, _ = _wait_closed(sock, HANDSHAKE_S + CLOSE_MARGIN_S)
    assert HANDSHAKE_S - 0.5 <= elapsed <= HANDSHAKE_S + CLOSE_MARGIN_S < HEADER_S, elapsed
    with connect(server.ws, open_timeout=10) as ws:  # an open WebSocket is not bound by the handshake timeout
        assert json.loads(ws.recv(timeout=10))["type"] == "hello"
        time.sleep(HANDSHAKE_S + 1.0)
        ws.send(json.dumps({"type": "nonsense"}))
        assert json.loads(ws.recv(timeout=10))["type"] == "error"


def test_connections_over_the_per_address_cap_are_closed_at_once_and_others_are_served(server):
    held = [_open(server, ATTACKER) for _ in range(CAP)]
    try:
        time.sleep(0.3)  # every one accepted and counted
        with _open(server, ATTACKER) as extra:
            elapsed, answer = _wait_closed(extra, CLOSE_MARGIN_S)
        assert elapsed <= CLOSE_MARGIN_S and answer == b"", (elapsed, answer)
        assert _ready(server, "127.0.0.1") == 200
        assert _ready(server, "127.0.0.3") == 200
        assert _ready(server, ATTACKER) == 0  # still over the cap
    finally:
        for sock in held:
            sock.close()
    # Closed connections give their places back (a WebSocket too, once it ends).
    deadline = time.monotonic() + 5.0
    while _ready(server, ATTACKER) != 200 and time.monotonic() < deadline:
        time.sleep(0.2)
    assert _ready(server, ATTACKER) == 200


def test_websockets_count_under_the_cap_and_release_their_place(server):
    sockets = [_open(server, ATTACKER) for _ in range(CAP - 1)]
    try:
        with connect(server.ws, open_timeout=10, source_address=(ATTACKER, 0)) as ws:  # the last place
            assert json.loads(ws.recv(timeout=10))["type"] == "hello"
            assert _ready(server, ATTACKER) == 0
        deadline = time.monotonic() + 5.0
        while _ready(server, ATTACKER) != 200 and time.monotonic() < deadline:
            time.sleep(0.2)
        assert _ready(server, ATTACKER) == 200
    finally:
        for sock in sockets:
            sock.close()


def test_plain_uvicorn_takes_the_guard_as_its_http_protocol(bundle_dir):
    command = ["uvicorn", "--factory", "service.app:create_app", "--host", "127.0.0.1", "--port", "{port}",
               "--no-proxy-headers", "--http", "service.http.connection_guard:GuardedHttpToolsProtocol"]
    srv = Server(bundle_dir, env={**LIMITS, "RSMT_HEADER_TIMEOUT_S": "1"}, command=command).start()
    try:
        with _open(srv) as sock:
            sock.sendall(b"GET /v1/health/ready HTTP/1.1\r\n")
            elapsed, answer = _wait_closed(sock, 1.0 + CLOSE_MARGIN_S)
    finally:
        srv.stop()
    assert 0.5 <= elapsed <= 1.0 + CLOSE_MARGIN_S, elapsed
    assert answer.startswith(b"HTTP/1.1 408 "), answer


def test_the_cap_counts_ipv6_clients_by_their_64_and_mapped_ipv4_as_ipv4():
    from service.http.connection_guard import address_key

    assert address_key("203.0.113.7") == "203.0.113.7"
    assert address_key("2001:db8:1:2:aaaa::1") == address_key("2001:db8:1:2:ffff::9") == "2001:db8:1:2::/64"
    assert address_key("2001:db8:1:3::1") != address_key("2001:db8:1:2::1")
    assert address_key("::ffff:203.0.113.7") == "203.0.113.7"


def test_trusted_proxies_are_not_capped_and_other_addresses_still_are(bundle_dir):
    """A configured proxy (RSMT_FORWARDED_ALLOW_IPS) carries many clients: its connections are not counted."""
    srv = Server(bundle_dir, env={**LIMITS, "RSMT_FORWARDED_ALLOW_IPS": ATTACKER}, command=SERVE).start()
    held = []
    try:
        held = [_open(srv, ATTACKER) for _ in range(CAP + 4)] + [_open(srv, "127.0.0.3") for _ in range(CAP)]
        time.sleep(0.3)
        proxy_status = _ready(srv, ATTACKER)
        with _open(srv, "127.0.0.3") as extra:
            elapsed, _ = _wait_closed(extra, CLOSE_MARGIN_S)
    finally:
        for sock in held:
            sock.close()
        srv.stop()
    assert proxy_status == 200
    assert elapsed <= CLOSE_MARGIN_S, elapsed


def test_the_cap_skips_configured_proxies_by_address_network_or_star():
    from service.http.connection_guard import ConnectionLimits

    limits = ConnectionLimits(uncapped=("10.0.0.0/8", "192.0.2.1", "proxy.local"))
    assert not limits.capped("10.1.2.3") and not limits.capped("192.0.2.1") and not limits.capped("proxy.local")
    assert limits.capped("192.0.2.2") and limits.capped("2001:db8::1")
    assert not ConnectionLimits(uncapped=("*",)).capped("203.0.113.7")
    assert not ConnectionLimits(max_connections_per_address=0).capped("203.0.113.7")
