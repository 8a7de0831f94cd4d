"""``rsmt loadtest --slow-clients``: hold many slow connections against a service and measure what it does.

    rsmt loadtest --url http://127.0.0.1:8000 --slow-clients --partial-headers 20000 --half-bodies 5000

Opens ``--partial-headers`` connections that send part of a request's headers and ``--half-bodies`` that send
complete headers with a ``Content-Length`` and part of the body, then stall; all from ``--attacker-addresses``
consecutive source addresses starting at ``--attacker-from`` (127.0.0.2: Linux routes all of 127/8 over
loopback), spread over ``--processes`` processes (one process holds at most ``ulimit -n`` sockets). Meanwhile
a client at ``--probe-from`` (127.0.0.1) asks ``GET /v1/health/ready`` on a new connection every
``--probe-every-s`` and the server's open file descriptors and memory are read from ``/metrics``. Reports, as
JSON: per kind, how many connected, were closed with a 408 (the read timeouts: seconds from the connect and
from the last byte sent to the close, p50/p99/max), were closed unanswered (the per-address cap: seconds from
the connect, as this process saw it) or were still open after ``--hold-s``; and the probes' latency before the attack,
while every slow connection was open, and over the whole attack. Nothing here asserts a figure.
"""

from __future__ import annotations

import argparse
import asyncio
import ipaddress
import json
import socket
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit

PARTIAL_HEADERS = b"GET /v1/health/ready HTTP/1.1\r\nHost: rsmt\r\nUser-Agent: slow-client\r\nX-Slow: "
HALF_BODY = (b"POST /v1/transition HTTP/1.1\r\nHost: rsmt\r\nContent-Type: application/json\r\n"
             b"Content-Length: 4096\r\n\r\n{\"frames\": 40, \"context\": ")
PROBE = b"GET /v1/health/ready HTTP/1.1\r\nHost: rsmt\r\nConnection: close\r\n\r\n"
_IP_BIND_ADDRESS_NO_PORT = getattr(socket, "IP_BIND_ADDRESS_NO_PORT", 24)  # Linux: pick the port at connect


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("slow clients (--slow-clients; --url or --spawn)")
    g.add_argument("--slow-clients", action="store_true",
                   help="hold partial-header and half-sent-body connections and time /v1/health/ready meanwhile")
    g.add_argument("--partial-headers", type=int, default=1000, metavar="N", help="connections sending part of their headers")
    g.add_argument("--half-bodies", type=int, default=250, metavar="M", help="connections sending half a body")
    g.add_argument("--attacker-from", default="127.0.0.2", metavar="ADDR", help="first source address of the slow clients")
    g.add_argument("--attacker-addresses", type=int, default=1, metavar="K",
                   help="source addresses used, consecutive from --attacker-from, connections spread evenly (default 1)")
    g.add_argument("--probe-from", default="127.0.0.1", metavar="ADDR", help="source address of the health probes")
    g.add_argument("--probe-every-s", type=float, default=0.1, metavar="S", help="a health probe every S seconds")
    g.add_argument("--processes", type=int, default=4, help="processes opening the slow connections (default 4)")
    g.add_argument("--hold-s", type=float, default=90.0, metavar="S",
                   help="wait this long after sending for the server to close each connection (default 90)")


@dataclass(frozen=True)
class _Share:
    """What one worker process opens: ``(kind, source address)`` per connection."""

    host: str
    port: int
    conns: list[tuple[str, str]]
    hold_s: float
    connect_concurrency: int = 256


def _open_socket(source: str) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setblocking(False)
    sock.setsockopt(socket.IPPROTO_IP, _IP_BIND_ADDRESS_NO_PORT, 1)
    sock.bind((source, 0))
    return sock


async def _slow_one(share: _Share, kind: str, source: str, gate: asyncio.Semaphore) -> dict[str, Any]:
    """One slow connection: times (monotonic, comparable across processes on Linux) of connect, send and close."""
    loop = asyncio.get_running_loop()
    rec: dict[str, Any] = {"kind": kind, "connected": None, "sent": None, "closed": None, "answer": b"", "error": None}
    sock = _open_socket(source)
    try:
        async with gate:
            await asyncio.wait_for(loop.sock_connect(sock, (share.host, share.port)), 60.0)
        rec["connected"] = time.monotonic()
        try:
            await loop.sock_sendall(sock, PARTIAL_HEADERS if kind == "partial_headers" else HALF_BODY)
            rec["sent"] = time.monotonic()
            deadline = rec["sent"] + share.hold_s
            while (left := deadline - time.monotonic()) > 0:
                chunk = await asyncio.wait_for(loop.sock_recv(sock, 4096), left)
                if not chunk:
                    break
                rec["answer"] += chunk
            else:
                return rec  # still open after hold_s
        except (ConnectionResetError, BrokenPipeError):
            rec["sent"] = rec["sent"] or rec["connected"]
        except TimeoutError:
            return rec
        rec["closed"] = time.monotonic()
    except (OSError, TimeoutError) as exc:
        rec["error"] = type(exc).__name__ + (f" {exc.errno}" if isinstance(exc, OSError) and exc.errno else "")
    finally:
        sock.close()
    return rec


async def _slow_share(share: _Share) -> list[dict[str, Any]]:
    gate = asyncio.Semaphore(share.connect_concurrency)
    records = await asyncio.gather(*(_slow_one(share, kind, src, gate) for kind, src in share.conns))
    for rec in records:
        rec["got_408"] = rec.pop("answer").startswith(b"HTTP/1.1 408")
    return records


def _worker(share: _Share) -> list[dict[str, Any]]:
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
    try:  # uvloop (uvicorn[standard] brings it) opens and watches sockets at several times asyncio's rate
        import uvloop

        return uvloop.run(_slow_share(share))
    except ImportError:
        return asyncio.run(_slow_share(share))


async def _probe(host: str, port: int, source: str, timeout_s: float = 10.0) -> float | None:
    """Seconds for ``GET /v1/health/ready`` on a new connection from ``source``; None if not 200 in time."""
    loop = asyncio.get_running_loop()
    sock = _open_socket(source)
    start = time.monotonic()
    try:
        async def exchange() -> bytes:
            await loop.sock_connect(sock, (host, port))
            await loop.sock_sendall(sock, PROBE)
            data = b""
            while chunk := await loop.sock_recv(sock, 4096):
                data += chunk
            return data

        data = await asyncio.wait_for(exchange(), timeout_s)
    except (OSError, TimeoutError):
        return None
    finally:
        sock.close()
    return time.monotonic() - start if data.startswith(b"HTTP/1.1 200") else None


async def _server_sample(host: str, port: int, api_key: str | None) -> tuple[float, float] | None:
    """The server's open file descriptors and resident memory (MiB), from /metrics."""
    import httpx

    headers = {"X-API-Key": api_key} if api_key else {}
    try:
        async with httpx.AsyncClient(timeout=10.0) as client:
            text = (await client.get(f"http://{host}:{port}/metrics", headers=headers)).text
    except httpx.HTTPError:
        return None
    values = {line.split()[0]: float(line.split()[1]) for line in text.splitlines()
              if line.startswith(("process_open_fds ", "process_resident_memory_bytes "))}
    if "process_open_fds" not in values:
        return None
    return values["process_open_fds"], values.get("process_resident_memory_bytes", 0.0) / 2**20


def _sources(first: str, count: int) -> list[str]:
    start = ipaddress.IPv4Address(first)
    return [str(start + i) for i in range(count)]


async def _attack(args: argparse.Namespace, host: str, port: int) -> dict[str, Any]:
    from rsmt_cli.load_figures import percentiles

    sources = _sources(args.attacker_from, args.attacker_addresses)
    kinds = ["partial_headers"] * args.partial_headers + ["half_body"] * args.half_bodies
    conns = [(kind, sources[i % len(sources)]) for i, kind in enumerate(kinds)]
    shares = [_Share(host, port, conns[i::args.processes], args.hold_s) for i in range(args.processes)]

    before = [t for t in [await _probe(host, port, args.probe_from) for _ in range(20)] if t is not None]
    probes: list[tuple[float, float | None]] = []
    samples: list[tuple[float, float]] = []
    began = time.monotonic()
    loop = asyncio.get_running_loop()
    with ProcessPoolExecutor(args.processes) as pool:
        work = asyncio.gather(*(loop.run_in_executor(pool, _worker, share) for share in shares))
        tick = 0
        while not work.done():
            probes.append((time.monotonic(), await _probe(host, port, args.probe_from)))
            if tick % 10 == 0 and (sample := await _server_sample(host, port, args.api_key)) is not None:
                samples.append(sample)
            tick += 1
            await asyncio.sleep(args.probe_every_s)
        records = [rec for share_records in await work for rec in share_records]

    # The window in which every slow connection that the server kept was open: from the last connect to the first
    # close by a read timeout (those answer 408; the per-address cap closes without an answer).
    kept_closes = [r["closed"] for r in records if r["closed"] and r["got_408"]]
    last_connect = max((r["connected"] for r in records if r["connected"]), default=began)
    first_close = min(kept_closes, default=time.monotonic())
    held = [t for at, t in probes if last_connect <= at < first_close]

    def latency(ts: list[float | None]) -> dict[str, Any]:
        ok = [t * 1e3 for t in ts if t is not None]
        return {**percentiles(ok, 2), "failed": len(ts) - len(ok)}

    out: dict[str, Any] = {
        "plan": {"partial_headers": args.partial_headers, "half_bodies": args.half_bodies,
                 "attacker_addresses": f"{sources[0]}..{sources[-1]} ({len(sources)})", "processes": args.processes,
                 "probe_from": args.probe_from},
        "seconds": round(time.monotonic() - began, 1),
        "all_connected_after_s": round(last_connect - began, 2),
        "kept_window_s": round(max(0.0, first_close - last_connect), 2),
        "ready_ms": {"before": latency(list(before)),
                     "while_opening": latency([t for at, t in probes if at < last_connect]),
                     "while_all_held": latency(held),
                     "from_first_timeout": latency([t for at, t in probes if at >= max(first_close, last_connect)]),
                     "whole_attack": latency([t for _, t in probes])},
        "server": {"max_open_fds": max((s[0] for s in samples), default=None),
                   "max_rss_mib": round(max((s[1] for s in samples), default=0.0), 1), "samples": len(samples)},
    }
    for kind in ("partial_headers", "half_body"):
        mine = [r for r in records if r["kind"] == kind]
        if not mine:
            continue
        closed = [r for r in mine if r["closed"] is not None]
        timed_out = [r for r in closed if r["got_408"]]
        unanswered = [r for r in closed if not r["got_408"]]
        errors: dict[str, int] = {}
        for r in mine:
            if r["error"]:
                errors[r["error"]] = errors.get(r["error"], 0) + 1
        out[kind] = {"opened": len(mine), "connected": sum(r["connected"] is not None for r in mine),
                     "closed_with_408": len(timed_out),
                     "close_after_connect_s": percentiles([r["closed"] - r["connected"] for r in timed_out], 2),
                     "close_after_send_s": percentiles([r["closed"] - r["sent"] for r in timed_out], 2),
                     "closed_unanswered": len(unanswered),
                     "unanswered_close_after_connect_s": percentiles([r["closed"] - r["connected"] for r in unanswered], 2),
                     "still_open_after_hold": sum(r["connected"] is not None and r["closed"] is None and not r["error"]
                                                  for r in mine),
                     "connect_s": percentiles([r["connected"] - began for r in mine if r["connected"]], 2),
                     "errors": errors}
    return out


def slow_client_load(args: argparse.Namespace, url: str) -> dict[str, Any]:
    if args.partial_headers < 0 or args.half_bodies < 0 or args.processes < 1 or args.attacker_addresses < 1:
        raise SystemExit("rsmt loadtest: counts must be >= 0 and --processes, --attacker-addresses >= 1")
    parts = urlsplit(url)
    host, port = parts.hostname or "127.0.0.1", parts.port or 80
    result = asyncio.run(_attack(args, host, port))
    return json.loads(json.dumps(result))  # plain JSON types only
