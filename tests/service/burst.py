"""Helpers of the work-queue tests: parallel ``POST /v1/transition`` requests, each on its own connection,
and the server's Prometheus series."""

from __future__ import annotations

import asyncio
import json
import threading
import time
from dataclasses import dataclass
from typing import Any

import httpx


@dataclass
class Answer:
    status: int | None  # None: no answer (the client gave up, or the connection failed)
    seconds: float  # from sending to the answer (or to giving up)
    body: bytes = b""
    content_type: str = ""
    retry_after: str | None = None
    error: str = ""

    def json(self) -> dict | None:
        """The body as JSON, or None when it is not JSON."""
        try:
            return json.loads(self.body)
        except ValueError:
            return None


def post(url: str, body: dict | bytes, timeout_s: float, client: httpx.Client | None = None) -> Answer:
    """One request on a fresh connection (of ``client``, which this closes); closing the client on a timeout
    closes the connection, as a client that gives up does. ``body``: JSON, or already encoded JSON."""
    client = client if client is not None else httpx.Client(timeout=timeout_s)
    content = body if isinstance(body, bytes) else json.dumps(body).encode()
    with client:
        started = time.monotonic()
        try:
            r = client.post(url + "/v1/transition", content=content, headers={"Content-Type": "application/json"})
        except httpx.HTTPError as exc:
            return Answer(None, time.monotonic() - started, error=repr(exc))
        return Answer(r.status_code, time.monotonic() - started, r.content, r.headers.get("content-type", ""),
                      r.headers.get("retry-after"))


class Burst:
    """``n`` requests sent at once from ``n`` threads; :meth:`join` waits for every answer."""

    def __init__(self, url: str, body: dict, n: int, timeout_s: float = 60.0) -> None:
        self.answers: list[Answer | None] = [None] * n
        encoded = json.dumps(body).encode()  # once, so that the clocks time the server and not the encoding
        # Clients (with their TLS contexts, costly) are made before any request is sent.
        clients = [httpx.Client(timeout=timeout_s) for _ in range(n)]
        self._threads = [threading.Thread(target=self._one, args=(i, url, encoded, timeout_s, clients[i]), daemon=True)
                         for i in range(n)]
        for t in self._threads:
            t.start()

    def _one(self, i: int, url: str, body: bytes, timeout_s: float, client: httpx.Client) -> None:
        self.answers[i] = post(url, body, timeout_s, client)

    def join(self, timeout_s: float = 120.0) -> list[Answer]:
        deadline = time.monotonic() + timeout_s
        for t in self._threads:
            t.join(max(0.0, deadline - time.monotonic()))
        missing = [i for i, a in enumerate(self.answers) if a is None]
        assert not missing, f"{len(missing)} requests never returned"
        return [a for a in self.answers if a is not None]


def metric(url: str, name: str, **labels: str) -> float:
    """The sum of a series' samples matching ``labels`` (0 when absent)."""
    text = httpx.get(url + "/metrics", timeout=10).text
    total = 0.0
    for line in text.splitlines():
        if not line.startswith(name + "{") and not line.startswith(name + " "):
            continue
        series, _, value = line.rpartition(" ")
        if all(f'{k}="{v}"' in series for k, v in labels.items()):
            total += float(value)
    return total


async def _raw_one(reader: asyncio.StreamReader, writer: asyncio.StreamWriter, request: bytes) -> Answer:
    started = time.monotonic()
    try:
        writer.write(request)
        head = await reader.readuntil(b"\r\n\r\n")
        seconds = time.monotonic() - started  # to the answer's headers (its body follows in the same packet)
        lines = head.decode("latin-1").split("\r\n")
        headers = {k.strip().lower(): v.strip() for k, _, v in (line.partition(":") for line in lines[1:] if line)}
        body = await reader.readexactly(int(headers.get("content-length", "0")))
        return Answer(int(lines[0].split()[1]), seconds, body, headers.get("content-type", ""), headers.get("retry-after"))
    except (OSError, asyncio.IncompleteReadError, asyncio.LimitOverrunError) as exc:
        return Answer(None, time.monotonic() - started, error=repr(exc))
    finally:
        writer.close()


async def _raw_burst(port: int, request: bytes, n: int, timeout_s: float) -> list[Answer]:
    conns = [await asyncio.open_connection("127.0.0.1", port, limit=1 << 22) for _ in range(n)]
    return list(await asyncio.wait_for(asyncio.gather(*(_raw_one(r, w, request) for r, w in conns)), timeout_s))


def raw_burst(port: int, body: dict | None, n: int, timeout_s: float = 300.0) -> list[Answer]:
    """``n`` requests from one asyncio thread over raw sockets: every connection is opened first, then every
    request is written at once; each answer is timed from its own write to its headers. Far lighter than
    :class:`Burst`'s thread and httpx client per request, so the times are more the server's own.
    ``body`` None: ``GET /v1/health/live`` instead, the quickest answer the server has (a control)."""
    if body is None:
        request = b"GET /v1/health/live HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
    else:
        encoded = json.dumps(body).encode()
        request = (b"POST /v1/transition HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                   b"Content-Length: %d\r\n\r\n" % len(encoded) + encoded)
    return asyncio.run(_raw_burst(port, request, n, timeout_s))


def histogram(url: str, name: str, **labels: str) -> list[tuple[float, float]]:
    """A histogram's cumulative buckets (upper bound, count) for the series matching ``labels``, summed."""
    text = httpx.get(url + "/metrics", timeout=10).text
    buckets: dict[float, float] = {}
    for line in text.splitlines():
        if not line.startswith(name + "_bucket{"):
            continue
        series, _, value = line.rpartition(" ")
        if all(f'{k}="{v}"' in series for k, v in labels.items()):
            bound = series.split('le="', 1)[1].split('"', 1)[0]
            le = float("inf") if bound == "+Inf" else float(bound)
            buckets[le] = buckets.get(le, 0.0) + float(value)
    return sorted(buckets.items())


def bucket_quantile(buckets: list[tuple[float, float]], q: float) -> float | None:
    """The upper bound of the bucket holding quantile ``q`` (a figure 'at most this'), None without samples."""
    if not buckets or not buckets[-1][1]:
        return None
    wanted = q * buckets[-1][1]
    return next(le for le, count in buckets if count >= wanted)


def in_app(url: str, route: str, status: str) -> dict:
    """Time inside the app of one route's answers with one status (request metric): count, mean, and the
    bucket bounds of p50 and p99 (ms), and how many took at most 50 ms."""
    buckets = histogram(url, "rsmt_http_request_duration_seconds", route=route, status=status)
    total = metric(url, "rsmt_http_request_duration_seconds_sum", route=route, status=status)
    count = buckets[-1][1] if buckets else 0.0
    within_50 = dict(buckets).get(0.05, 0.0)

    def ms(v: float | None) -> float | None:
        return None if v is None else round(v * 1e3, 2)

    return {"count": int(count), "mean_ms": ms(total / count) if count else None,
            "p50_ms_at_most": ms(bucket_quantile(buckets, 0.5)), "p99_ms_at_most": ms(bucket_quantile(buckets, 0.99)),
            "within_50_ms": int(within_50)}


def wait_for(predicate, timeout_s: float, interval_s: float = 0.05) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval_s)
    return predicate()


def _percentile(values: list[float], q: float) -> float | None:
    if not values:
        return None
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


def _times(answers: list[Answer]) -> dict:
    ms = [a.seconds * 1e3 for a in answers if a.status == 200]
    return {"answered": len(ms), "p50": _round(_percentile(ms, 0.5)), "p99": _round(_percentile(ms, 0.99))}


def _round(v: float | None) -> float | None:
    return None if v is None else round(v, 1)


def _summary(answers: list[Answer]) -> dict:
    kinds: dict[str, int] = {}
    for a in answers:
        code = ((a.json() or {}).get("error") or {}).get("code") if a.status != 200 else None
        key = f"{a.status} {code}" if code else str(a.status)
        kinds[key] = kinds.get(key, 0) + 1
    rejected = [a.seconds * 1e3 for a in answers if a.status == 503 and (a.json() or {}).get("error", {}).get("code")
                == "overloaded"]
    served = [a.seconds * 1e3 for a in answers if a.status == 200]
    non_json = sum(1 for a in answers if a.status is not None
                   and (a.json() is None or not a.content_type.startswith("application/json")))
    no_answer: dict[str, int] = {}
    for a in answers:
        if a.status is None:
            kind = a.error.split("(")[0]
            no_answer[kind] = no_answer.get(kind, 0) + 1
    ms = {"rejected_p50": _percentile(rejected, 0.5), "rejected_p99": _percentile(rejected, 0.99),
          "rejected_max": max(rejected, default=None), "served_p50": _percentile(served, 0.5),
          "served_max": max(served, default=None)}
    return {"answers": kinds, "non_json": non_json, "no_answer": no_answer,
            "ms": {k: None if v is None else round(v, 1) for k, v in ms.items()}}


def main() -> None:
    """Measure a burst against a spawned ``rsmt serve``: ``--requests`` parallel transitions (answer times of
    the refused ones as the client saw them, and inside the app from the request metric), then a second burst
    and SIGTERM ``--sigterm-after`` seconds after sending it (non-JSON answers, exit time). With ``--client
    asyncio`` the first burst comes from raw sockets in one asyncio loop, after a control: as many liveness
    probes at once, idle and while the model works. Prints JSON. Run from the repository root:

        python -m tests.service.burst --bundle model/default_bundle --requests 64 --queue-limit 16
        python -m tests.service.burst --bundle model/default_bundle --queue-limit 16 --client asyncio --no-sigterm
    """
    import argparse
    import sys
    from pathlib import Path

    from tests.service.conftest import transition_body
    from tests.service.server import Server

    p = argparse.ArgumentParser(description=main.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--bundle", type=Path, required=True)
    p.add_argument("--requests", type=int, default=64)
    p.add_argument("--queue-limit", type=int, default=16, help="RSMT_QUEUE_LIMIT of the server (omitted if 0)")
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--sigterm-after", type=float, default=0.2, metavar="S",
                   help="SIGTERM this long after sending the second burst (and after --sigterm-queued)")
    p.add_argument("--sigterm-queued", type=int, default=0, metavar="N",
                   help="first wait (up to 30 s) until N requests wait in the work queue (rsmt_work_queue_waiting)")
    p.add_argument("--drain-s", type=float, default=1.0)
    p.add_argument("--grace-s", type=float, default=8.0)
    p.add_argument("--no-sigterm", action="store_true", help="measure the first burst only")
    p.add_argument("--switch-interval-ms", type=float, default=0.0,
                   help="the server's GIL switch interval (sys.setswitchinterval; default: Python's 5 ms)")
    p.add_argument("--client", choices=("threads", "asyncio"), default="threads",
                   help="first burst: a thread and httpx client per request, or raw sockets from one asyncio loop")
    args = p.parse_args()

    env = {"RSMT_SHUTDOWN_DRAIN_S": str(args.drain_s), "RSMT_SHUTDOWN_GRACE_S": str(args.grace_s),
           "RSMT_WARMUP_MAX_BATCH": "8"}
    if args.queue_limit:
        env["RSMT_QUEUE_LIMIT"] = str(args.queue_limit)
    # The rsmt command's own main, from the working directory's code (a checkout to compare need not be installed).
    switch = f"sys.setswitchinterval({args.switch_interval_ms / 1e3}); " if args.switch_interval_ms else ""
    serve = [sys.executable, "-c", f"import sys; {switch}from rsmt_cli.main import main; sys.exit(main())", "serve"]
    srv = Server(args.bundle, command=[*serve, "--host", "127.0.0.1", "--port", "{port}"], env=env)
    srv.start(timeout_s=300)
    try:
        # A procedural walk on the Bandai-Namco joint names (those of the default model and the test rig).
        body = transition_body(frames=args.frames, seed=7)
        if args.client == "asyncio":
            # The control: as many liveness probes at once, before any model work (idle server) ...
            control = {"idle": _times(raw_burst(srv.port, None, args.requests))}
            busy = Burst(srv.url, body, 2)  # ... and while the model works (the event loop shares the GIL with it)
            wait_for(lambda: metric(srv.url, "rsmt_work_queue_waiting") >= 1, 30, 0.02)
            control["model_working"] = _times(raw_burst(srv.port, None, args.requests))
            busy.join(300)
            first = _summary(raw_burst(srv.port, body, args.requests)) | {"control_live_ms": control}
        else:
            first = _summary(Burst(srv.url, body, args.requests).join(300))
        # Time inside the app (from the request metric) of the transitions refused with 503.
        first["in_app_503"] = in_app(srv.url, "/v1/transition", "503")
        at_sigterm = {} if args.no_sigterm else _sigterm_burst(srv, body, args)
    finally:
        srv.stop()
    _report(args, first, at_sigterm)


def _sigterm_burst(srv: Any, body: dict, args: Any) -> dict:
    """A second burst, then SIGTERM: its answers (non-JSON ones counted) and the time to the process's exit."""
    import signal

    second = Burst(srv.url, body, args.requests)
    if args.sigterm_queued:
        wait_for(lambda: metric(srv.url, "rsmt_work_queue_waiting") >= args.sigterm_queued, 30, 0.02)
    time.sleep(args.sigterm_after)
    waiting = metric(srv.url, "rsmt_work_queue_waiting")
    sent = time.monotonic()
    assert srv.proc is not None
    srv.proc.send_signal(signal.SIGTERM)
    code = srv.proc.wait(timeout=args.drain_s + args.grace_s + 30)
    exit_s = time.monotonic() - sent
    return {"exit_s": round(exit_s, 2), "exit_code": code, "queued_at_sigterm": waiting, **_summary(second.join(60))}


def _report(args: Any, first: dict, at_sigterm: dict) -> None:
    import os
    import platform
    import sys

    print(json.dumps({"machine": {"cpus": os.cpu_count(), "python": sys.version.split()[0], "platform": platform.platform()},
                      "settings": vars(args) | {"bundle": str(args.bundle)}, "burst": first,
                      "load_average": os.getloadavg(), "sigterm": at_sigterm}, indent=1))


if __name__ == "__main__":
    main()
