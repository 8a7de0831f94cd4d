"""The local topology of tests/service/test_replicas.py and of the load-balancer measurement
(``python -m tests.service.lb_overhead``): ``redis-server``, ``rsmt serve`` replicas on 127.0.0.1 sharing
it as their style store, and ``haproxy`` in front, all started and stopped by PID."""

from __future__ import annotations

import csv
import io
import re
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx

from tests.service.processes import HaproxyProcess, RedisProcess
from tests.service.server import Server

START_S = 240.0  # replicas warming up at once on a small, busy machine


class Topology:
    """``redis``, ``replicas`` and ``lb``; :meth:`start` brings them up (replicas in parallel), :meth:`stop`
    takes everything down, whatever started."""

    def __init__(self, bundle: Path, env: dict[str, str], replicas: int = 3) -> None:
        self.redis = RedisProcess()
        self.env = {"RSMT_STYLE_STORE": self.redis.url, **env}
        self.replicas = [Server(bundle, env=self.env, command=["rsmt", "serve", "--host", "127.0.0.1", "--port", "{port}"])
                         for _ in range(replicas)]
        self.lb = HaproxyProcess([r.port for r in self.replicas])

    def start(self, timeout_s: float = START_S) -> Topology:
        try:
            self.redis.start()
            with ThreadPoolExecutor(len(self.replicas)) as pool:
                list(pool.map(lambda s: s.start(timeout_s), self.replicas))
            self.lb.start()
            self.wait_all_up()
        except BaseException:
            self.stop()
            raise
        return self

    def stop(self) -> None:
        self.lb.cleanup()
        for r in self.replicas:
            r.stop()
        self.redis.cleanup()

    def server_states(self) -> dict[str, dict[str, str]]:
        """HAProxy's view of every server, ``"backend/server"`` -> its stats row (``status``, ``stot``, ...)."""
        text = httpx.get(self.lb.stats_url + ";csv", timeout=5).text.lstrip("# ")
        rows = csv.DictReader(io.StringIO(text))
        return {f"{r['pxname']}/{r['svname']}": r for r in rows if r["svname"] not in ("FRONTEND", "BACKEND")}

    def wait_all_up(self, timeout_s: float = 30.0) -> None:
        """Until HAProxy has every server of both backends UP (its checks passed ``rise`` times)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if all(r["status"] == "UP" for r in self.server_states().values()):
                return
            time.sleep(0.1)
        raise RuntimeError(f"HAProxy did not see every replica up within {timeout_s} s: {self.server_states()}")

    def http_sessions(self) -> list[int]:
        """Requests HAProxy sent to each replica's HTTP backend so far (``stot``), in replica order
        (kept across replica restarts, unlike the replicas' own metrics)."""
        states = self.server_states()
        return [int(states[f"rsmt_http/r{i}"]["stot"]) for i in range(len(self.replicas))]


def live_streams(server: Server, api_key: str | None) -> int:
    """``rsmt_live_streams`` of one replica (0 when it does not answer)."""
    try:
        text = httpx.get(server.url + "/metrics", headers={"X-API-Key": api_key} if api_key else {}, timeout=5).text
    except httpx.HTTPError:
        return 0
    m = re.search(r"^rsmt_live_streams (\d+)", text, re.M)
    return int(m.group(1)) if m else 0
