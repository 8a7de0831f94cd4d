"""Helpers of the work-queue tests: parallel ``POST /v1/transition`` requests, each on its own connection,
and the server's Prometheus series."""

from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass

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


def post(url: str, body: dict, timeout_s: float, client: httpx.Client | None = None) -> Answer:
    """One request on a fresh connection (of ``client``, which this closes); closing the client on a timeout
    closes the connection, as a client that gives up does."""
    client = client if client is not None else httpx.Client(timeout=timeout_s)
    with client:
        started = time.monotonic()
        try:
            r = client.post(url + "/v1/transition", json=body)
        except httpx.HTTPError as exc:
            return Answer(None, time.monotonic() - started, error=repr(exc))
        return Answer(r.status_code, time.monotonic() - started, r.content, r.headers.get("content-type", ""),
                      r.headers.get("retry-after"))


class Burst:
    """``n`` requests sent at once from ``n`` threads; :meth:`join` waits for every answer."""

    def __init__(self, url: str, body: dict, n: int, timeout_s: float = 60.0) -> None:
        self.answers: list[Answer | None] = [None] * n
        # Clients (with their TLS contexts, costly) are made before any request is sent.
        clients = [httpx.Client(timeout=timeout_s) for _ in range(n)]
        self._threads = [threading.Thread(target=self._one, args=(i, url, body, timeout_s, clients[i]), daemon=True)
                         for i in range(n)]
        for t in self._threads:
            t.start()

    def _one(self, i: int, url: str, body: dict, timeout_s: float, client: httpx.Client) -> None:
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
    the refused ones), then a second burst and SIGTERM ``--sigterm-after`` seconds after sending it (non-JSON
    answers, exit time). Prints JSON. Run from the repository root:

        python -m tests.service.burst --bundle model/default_bundle --requests 64 --queue-limit 16
    """
    import argparse
    import os
    import platform
    import signal
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
    args = p.parse_args()

    env = {"RSMT_SHUTDOWN_DRAIN_S": str(args.drain_s), "RSMT_SHUTDOWN_GRACE_S": str(args.grace_s),
           "RSMT_WARMUP_MAX_BATCH": "8"}
    if args.queue_limit:
        env["RSMT_QUEUE_LIMIT"] = str(args.queue_limit)
    # The rsmt command's own main, from the working directory's code (a checkout to compare need not be installed).
    serve = [sys.executable, "-c", "import sys; from rsmt_cli.main import main; sys.exit(main())", "serve"]
    srv = Server(args.bundle, command=[*serve, "--host", "127.0.0.1", "--port", "{port}"], env=env)
    srv.start(timeout_s=300)
    try:
        # A procedural walk on the Bandai-Namco joint names (those of the default model and the test rig).
        body = transition_body(frames=args.frames, seed=7)
        first = _summary(Burst(srv.url, body, args.requests).join(300))
        # Time inside the app (from the request metric) of the transitions refused with 503.
        in_app = {k: metric(srv.url, f"rsmt_http_request_duration_seconds_{k}", route="/v1/transition", status="503")
                  for k in ("sum", "count")}
        first["in_app_ms_mean_503"] = round(1e3 * in_app["sum"] / in_app["count"], 2) if in_app["count"] else None
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
        at_sigterm = _summary(second.join(60))
    finally:
        srv.stop()
    print(json.dumps({"machine": {"cpus": os.cpu_count(), "python": sys.version.split()[0], "platform": platform.platform()},
                      "settings": vars(args) | {"bundle": str(args.bundle)}, "burst": first,
                      "sigterm": {"exit_s": round(exit_s, 2), "exit_code": code, "queued_at_sigterm": waiting,
                                  **at_sigterm}}, indent=1))


if __name__ == "__main__":
    main()
