"""One connection pipelining ``GET /v1/health/live`` and never reading, in a process of its own:
``python -m tests.service.pipeline_flood --port PORT --seconds S``.

Sends the requests in batches of 1,000 as fast as the server takes them (what a send timeout leaves unsent
goes next, so the requests stay whole) for ``--seconds``; prints ``ready`` once started, then one JSON line:
requests sent, and the error that ended the connection early, if one did. Flooding from a process of its own
keeps the flood's work from competing for the GIL with the measuring client's.
"""

from __future__ import annotations

import argparse
import json
import socket
import time

REQUEST = b"GET /v1/health/live HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"


def flood(port: int, seconds: float) -> dict:
    out: dict = {}
    sent, pos = 0, 0
    batch = memoryview(REQUEST * 1000)
    deadline = time.monotonic() + seconds
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.settimeout(0.2)
        while time.monotonic() < deadline:
            try:
                pos += sock.send(batch[pos:])
            except TimeoutError:  # the server reads no more for now
                continue
            except OSError as exc:
                out["error"] = repr(exc)
                break
            if pos == len(batch):
                sent, pos = sent + 1000, 0
    out["sent"] = sent
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--port", type=int, required=True)
    p.add_argument("--seconds", type=float, default=5.0)
    args = p.parse_args()
    print("ready", flush=True)
    print(json.dumps(flood(args.port, args.seconds)), flush=True)


if __name__ == "__main__":
    main()
