"""One API key's WebSocket ``ping`` flood on a real server, in a process of its own: ``python -m tests.service.ws_flood``.

Raw-socket connections that never read: each sends ``ping`` messages in batches of ``--batch`` as fast as the
server takes them, and when the server ends it (or refuses the handshake) a new one is opened at once, until
``--seconds`` have passed. Prints ``ready`` once started, then one JSON line: messages sent, connections opened
and refused, and the close code each ended connection found among what the server had sent it. Flooding from a
process of its own keeps the flood's work from competing for the GIL with the measuring client's.
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import socket
import struct
import time

from tests.service.raw_reads import read_until


def frame(text: bytes) -> bytes:
    """A masked client text frame (an all-zero mask: the payload goes as it is)."""
    assert len(text) < 126
    return bytes([0x81, 0x80 | len(text)]) + b"\0\0\0\0" + text


def open_raw(port: int, key: str) -> tuple[socket.socket, bytes]:
    """A raw WebSocket connection of ``key``, handshake done; what came after the 101's head."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=10)
    nonce = base64.b64encode(os.urandom(16)).decode()
    sock.sendall(f"GET /v1/stream?token={key} HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n"
                 f"Connection: Upgrade\r\nSec-WebSocket-Key: {nonce}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode())
    head, _, rest = read_until(sock, b"\r\n\r\n").partition(b"\r\n\r\n")
    if not head.startswith(b"HTTP/1.1 101"):
        sock.close()
        raise ConnectionRefusedError(head.split(b"\r\n", 1)[0].decode(errors="replace"))
    return sock, rest


def close_code(data: bytes) -> int | None:
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


def flood(port: int, key: str, seconds: float, batch_size: int) -> dict:
    batch = memoryview(frame(b'{"type":"ping","id":1}') * batch_size)
    sent = opened = refused = 0
    codes: list[int | None] = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            sock, rest = open_raw(port, key)
        except OSError:  # refused (429: the key's budget is spent) or reset: try again at once
            refused += 1
            continue
        opened += 1
        sock.settimeout(0.2)
        pos = 0
        try:
            while time.monotonic() < deadline:
                try:
                    pos += sock.send(batch[pos:])  # what a timeout leaves unsent goes next: frames stay whole
                except TimeoutError:  # the server reads no more for now
                    continue
                if pos == len(batch):
                    sent, pos = sent + batch_size, 0
        except OSError:  # the server ended the connection
            pass
        codes.append(close_code(_drain(sock, rest)))
        sock.close()
    return {"sent": sent, "opened": opened, "refused": refused, "codes": codes}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--port", type=int, required=True)
    p.add_argument("--key", required=True)
    p.add_argument("--seconds", type=float, default=5.0)
    p.add_argument("--batch", type=int, default=2000)
    args = p.parse_args()
    print("ready", flush=True)
    print(json.dumps(flood(args.port, args.key, args.seconds, args.batch)), flush=True)


if __name__ == "__main__":
    main()
