"""Reading a raw socket up to a marker (the end of an HTTP answer's status line or head), for the tests and load
scripts that speak HTTP by hand."""

from __future__ import annotations

import socket


def read_until(sock: socket.socket, marker: bytes, limit: int | None = None) -> bytes:
    """What ``sock`` sends until ``marker`` has arrived, the peer closes or (with ``limit``) that many bytes are held;
    the socket's timeout and errors reach the caller."""
    data = b""
    while marker not in data and (limit is None or len(data) < limit):
        chunk = sock.recv(4096)
        if not chunk:
            break
        data += chunk
    return data
