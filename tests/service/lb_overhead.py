"""What the load balancer adds to a transition: ``python -m tests.service.lb_overhead``.

Starts the local topology of tests/service/test_replicas.py (``redis-server``, ``rsmt serve`` replicas,
``haproxy`` in front, all on 127.0.0.1), registers a style through the balancer, then sends the same
``POST /v1/transition`` alternately straight to a replica (round robin over them) and through HAProxy,
each on its own keep-alive connection, and prints the client's round-trip p50 and p99 of both and the
difference of the p50s. On a busy machine the model's own time varies far more than a millisecond, so it
also prints the time outside the server (round trip minus the ``timing_ms.total`` the replica reports:
connection, HTTP and, for the balanced path, HAProxy), whose p50 difference is the balancer's cost with
the model's noise taken out, and the median of the differences within each pair (sent one after the
other, so slow drifts of the machine's load cancel). The order of each pair alternates so that neither
side always goes first. The model is a random-weight bundle on the synthetic rig unless ``--bundle``
names one; the balancer's cost does not depend on it.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

from model.data.synthetic import synthetic_skeleton
from model.inference.bundle import Bundle
from tests.service.conftest import bvh, transition_body, walk
from tests.service.topology import Topology

KEY = "lb-overhead-key-0123456789"


def timed_post(client: httpx.Client, body: dict) -> tuple[float, float]:
    """(client round trip, server total) in ms of one transition."""
    started = time.perf_counter()
    r = client.post("/v1/transition", json=body)
    took = (time.perf_counter() - started) * 1000.0
    r.raise_for_status()
    return took, float(r.json()["timing_ms"]["total"])


def measure(topology: Topology, requests: int, frames: int, warmup: int, api_key: str = KEY) -> dict[str, object]:
    """Send the pairs on ``topology`` (whose replicas accept ``api_key``) and return the figures."""
    headers = {"X-API-Key": api_key}
    reg = httpx.post(topology.lb.url + "/v1/styles", json={"name": "walk", "motion": bvh(walk(30))}, headers=headers,
                     timeout=60)
    reg.raise_for_status()
    body = transition_body(frames, style_id=reg.json()["style_id"], deterministic=True)
    lb = httpx.Client(base_url=topology.lb.url, headers=headers, timeout=60, trust_env=False)
    direct = [httpx.Client(base_url=r.url, headers=headers, timeout=60, trust_env=False) for r in topology.replicas]
    times: dict[str, list[tuple[float, float]]] = {"direct": [], "lb": []}
    try:
        for i in range(warmup + requests):
            pair = [("direct", direct[i % len(direct)]), ("lb", lb)]
            for name, client in pair if i % 2 == 0 else pair[::-1]:
                took = timed_post(client, body)
                if i >= warmup:
                    times[name].append(took)
    finally:
        lb.close()
        for c in direct:
            c.close()
    out: dict[str, object] = {"requests": requests, "frames": frames}
    for name, rows in times.items():
        rt = np.array([t for t, _ in rows])
        server = np.array([s for _, s in rows])
        outside = rt - server
        out[name] = {"p50_ms": round(float(np.percentile(rt, 50)), 2), "p99_ms": round(float(np.percentile(rt, 99)), 2),
                     "server_total_p50_ms": round(float(np.percentile(server, 50)), 2),
                     "outside_p50_ms": round(float(np.percentile(outside, 50)), 3),
                     "outside_p99_ms": round(float(np.percentile(outside, 99)), 3)}
    d, b = out["direct"], out["lb"]
    assert isinstance(d, dict) and isinstance(b, dict)
    out["lb_adds_p50_ms"] = round(b["p50_ms"] - d["p50_ms"], 2)
    out["lb_adds_outside_p50_ms"] = round(b["outside_p50_ms"] - d["outside_p50_ms"], 3)
    pairs = np.array([lb_t - d_t for (lb_t, _), (d_t, _) in zip(times["lb"], times["direct"], strict=True)])
    out["lb_adds_paired_p50_ms"] = round(float(np.percentile(pairs, 50)), 3)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tests.service.lb_overhead", description=__doc__.split("\n\n")[0])
    ap.add_argument("--requests", type=int, default=300, help="transitions each way (default 300)")
    ap.add_argument("--frames", type=int, default=40, help="frames per transition (default 40)")
    ap.add_argument("--warmup", type=int, default=20, help="pairs sent first and not counted (default 20)")
    ap.add_argument("--replicas", type=int, default=3)
    ap.add_argument("--bundle", type=Path, help="model bundle (default: a random-weight one on the synthetic rig)")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="rsmt-lb-") as tmp:
        bundle = args.bundle or Bundle.create(synthetic_skeleton(), seed=0).save(Path(tmp) / "rsmt")
        topology = Topology(bundle, {"RSMT_API_KEYS": KEY, "RSMT_WARMUP_MAX_BATCH": "2"}, args.replicas).start()
        try:
            out = measure(topology, args.requests, args.frames, args.warmup)
        finally:
            topology.stop()
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        for name in ("direct", "lb"):
            f = out[name]
            assert isinstance(f, dict)
            print(f"{name:>6}: round trip p50 {f['p50_ms']:.2f} ms, p99 {f['p99_ms']:.2f} ms; server total p50 "
                  f"{f['server_total_p50_ms']:.2f} ms; outside the server p50 {f['outside_p50_ms']:.3f} ms, "
                  f"p99 {f['outside_p99_ms']:.3f} ms ({args.requests} x {args.frames}-frame transitions)")
        print(f"the load balancer adds {out['lb_adds_p50_ms']:.2f} ms to the round trip at p50 "
              f"(median of the {args.requests} pairs' differences {out['lb_adds_paired_p50_ms']:.3f} ms), "
              f"{out['lb_adds_outside_p50_ms']:.3f} ms to the time outside the server at p50")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
