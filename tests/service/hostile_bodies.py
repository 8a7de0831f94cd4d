"""``python -m tests.service.hostile_bodies``: does a flood of unauthenticated large bodies slow an authenticated
stream? (issue 24, row 3: "14 unauthenticated 850 KB requests a second: an authenticated 8-character stream keeps
its frame-gap p99 within 1.5x of its unloaded figure in the same run").

Starts ``rsmt serve`` (the working directory's code) with API keys on, then alternates, ``--rounds`` times, an
unloaded and a loaded phase of ``--seconds`` each. In both an authenticated WebSocket stream of ``--characters``
characters (one connection, binary frames, realtime pacing, each character starting a new transition when the
last ends: ``rsmt loadtest``'s stream load through the Python client) measures the gap between consecutive frames
of a character. In the loaded phase another process sends ``--rate`` ``POST /v1/transition`` requests a second,
each on its own connection from ``--attacker-address``: an 850 KB JSON body of 80,000 keys, alternately without a
key and with a wrong one. Prints JSON: per phase the gap p50/p99/max, late and dropped frames, the attack's
answers and answer times; per round and overall the loaded/unloaded p99 ratio. Run from the repository root:

    python -m tests.service.hostile_bodies --bundle model/default_bundle --rounds 2 --seconds 20
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import socket
import statistics
import sys
import threading
import time
from pathlib import Path
from typing import Any

from tests.service.raw_reads import read_until

KEY = "hostile-bodies-key-0123456789"
WRONG_KEY = "wrong-key-0123456789abcdef"
BODY_BYTES = 850_000
BODY_KEYS = 80_000


def hostile_body() -> bytes:
    """A JSON object of BODY_KEYS short keys, padded to BODY_BYTES (what a parser would have to build)."""
    head = b"{" + b",".join(b'"%x":0' % i for i in range(BODY_KEYS)) + b',"pad":"'
    return head + b"x" * (BODY_BYTES - len(head) - 2) + b'"}'


def _one_request(port: int, source: str, request: bytes, out: list[tuple[str, float]]) -> None:
    started = time.monotonic()
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=30, source_address=(source, 0)) as s:
            s.sendall(request)
            data = read_until(s, b"\r\n")
        status = data.split(b" ", 2)[1].decode() if data.startswith(b"HTTP/1.1 ") else "no answer"
    except OSError as exc:
        status = type(exc).__name__
    out.append((status, (time.monotonic() - started) * 1e3))


def attack(port: int, source: str, rate: float, seconds: float, result: Any) -> None:
    """Send ``rate`` hostile requests a second for ``seconds``, each from its own thread and connection; put
    the answers' statuses and times (ms) on ``result`` (a multiprocessing queue)."""
    body = hostile_body()
    requests = [b"POST /v1/transition HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n" + key
                + b"Content-Length: %d\r\n\r\n" % len(body) + body
                for key in (b"", b"X-API-Key: " + WRONG_KEY.encode() + b"\r\n")]
    out: list[tuple[str, float]] = []
    threads = []
    began = time.monotonic()
    for i in range(int(rate * seconds)):
        time.sleep(max(0.0, began + i / rate - time.monotonic()))
        t = threading.Thread(target=_one_request, args=(port, source, requests[i % 2], out), daemon=True)
        t.start()
        threads.append(t)
    for t in threads:
        t.join(60)
    result.put({"sent": len(threads), "seconds": round(time.monotonic() - began, 2), "answers": out})


def _percentiles(values: list[float]) -> dict[str, float | int | None]:
    if not values:
        return {"p50": None, "p99": None, "max": None, "n": 0}
    ordered = sorted(values)

    def q(p: float) -> float:
        return round(ordered[min(len(ordered) - 1, round(p * (len(ordered) - 1)))], 2)

    return {"p50": q(0.5), "p99": q(0.99), "max": round(ordered[-1], 2), "n": len(ordered)}


def _attack_summary(report: dict[str, Any]) -> dict[str, Any]:
    statuses: dict[str, int] = {}
    for status, _ in report["answers"]:
        statuses[status] = statuses.get(status, 0) + 1
    return {"sent": report["sent"], "rate_per_s": round(report["sent"] / max(1e-9, report["seconds"]), 2),
            "answers": statuses, "answer_ms": _percentiles([ms for _, ms in report["answers"]])}


def _phase(url: str, port: int, args: argparse.Namespace, loaded: bool) -> dict[str, Any]:
    from rsmt_cli.loadtest_commands import Progress, StreamPlan, stream_load

    plan = StreamPlan(args.characters, args.seconds, args.characters, args.frames)
    attacker = None
    if loaded:
        ctx = multiprocessing.get_context("spawn")
        result = ctx.Queue()
        attacker = ctx.Process(target=attack, args=(port, args.attacker_address, args.rate, args.seconds, result))
        attacker.start()
    load_before = os.getloadavg()[0]
    figures = stream_load(url, KEY, plan, None, Progress(0))
    out: dict[str, Any] = {"loaded": loaded, "load_average_1min": [load_before, os.getloadavg()[0]]}
    out |= {k: figures[k] for k in ("gap_ms", "latency_ms", "late_frames", "dropped_frames", "frames_received",
                                   "error_count", "errors")}
    if attacker is not None:
        out["attack"] = _attack_summary(result.get(timeout=120))
        attacker.join(30)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--bundle", type=Path, default=Path("model/default_bundle"))
    p.add_argument("--rounds", type=int, default=2, help="unloaded + loaded phase pairs (default 2)")
    p.add_argument("--seconds", type=float, default=20.0, help="each phase's length (default 20)")
    p.add_argument("--characters", type=int, default=8)
    p.add_argument("--frames", type=int, default=60, help="frames per streamed transition (default 60)")
    p.add_argument("--rate", type=float, default=14.0, help="hostile requests a second (default 14)")
    p.add_argument("--attacker-address", default="127.0.0.2", help="the hostile requests' source address")
    p.add_argument("--server-env", action="append", default=[], metavar="NAME=VALUE",
                   help="a setting of the server, e.g. RSMT_AUTH_FAILURE_BURST=1000000 to answer every one 401 "
                        "rather than 429 once the address has failed too often")
    args = p.parse_args()

    from tests.service.server import Server

    serve = [sys.executable, "-c", "import sys; from rsmt_cli.main import main; sys.exit(main())", "serve"]
    srv = Server(args.bundle, command=[*serve, "--host", "127.0.0.1", "--port", "{port}"],
                 env={"RSMT_API_KEYS": KEY, "RSMT_LOG_LEVEL": "warning",
                      **dict(item.split("=", 1) for item in args.server_env)})
    srv.start(timeout_s=300)
    phases = []
    try:
        for _ in range(args.rounds):
            for loaded in (False, True):
                phases.append(_phase(srv.url, srv.port, args, loaded))
                print(json.dumps(phases[-1]), file=sys.stderr, flush=True)
    finally:
        srv.stop()
    p99 = {loaded: [ph["gap_ms"]["p99"] for ph in phases if ph["loaded"] is loaded] for loaded in (False, True)}
    ratios = [round(b / a, 2) for a, b in zip(p99[False], p99[True], strict=True)]
    print(json.dumps({"settings": vars(args) | {"bundle": str(args.bundle)}, "cpus": os.cpu_count(),
                      "phases": phases, "p99_ratio_per_round": ratios,
                      "p99_ratio_of_medians": round(statistics.median(p99[True]) / statistics.median(p99[False]), 2)},
                     indent=1))


if __name__ == "__main__":
    main()
