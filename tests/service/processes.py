"""Redis and HAProxy as subprocesses on free 127.0.0.1 ports, started and stopped by PID with bounded waits.

Both come from Debian packages (``.ci/run`` installs them when missing); tests that need them skip with
a reason where the command is absent.
"""

from __future__ import annotations

import shutil
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest

from tests.service.server import free_port


def need(command: str) -> str:
    """The path of ``command``, or skip the test saying how to install it."""
    path = shutil.which(command)
    if path is None:
        pytest.skip(f"{command} is not installed (apt-get install -y redis-server haproxy; .ci/run does it)")
    return path


def _stop(proc: subprocess.Popen | None, timeout_s: float = 10.0) -> None:
    if proc is None or proc.poll() is not None:
        return
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)


def _wait_ready(ready: Callable[[], bool], proc: subprocess.Popen, what: str, waiting_for: str, log: Path,
                timeout_s: float) -> None:
    """Poll ``ready`` until it is true; a ``proc`` that exits, or ``timeout_s`` passing, is a RuntimeError
    with the end of its log (``waiting_for`` says what was awaited). ``ready`` may raise OSError or
    httpx.HTTPError for "not yet"."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"{what} exited with {proc.returncode}:\n{log.read_text()[-3000:]}")
        try:
            if ready():
                return
        except (OSError, httpx.HTTPError):
            pass
        time.sleep(0.05)
    _stop(proc)
    raise RuntimeError(f"{what} did not {waiting_for} within {timeout_s} s:\n{log.read_text()[-3000:]}")


def _wait_port(port: int, proc: subprocess.Popen, what: str, log: Path, timeout_s: float) -> None:
    def accepts() -> bool:
        with socket.create_connection(("127.0.0.1", port), timeout=0.5):
            return True

    _wait_ready(accepts, proc, what, f"listen on port {port}", log, timeout_s)


def _wait_http(url: str, proc: subprocess.Popen, what: str, log: Path, timeout_s: float) -> None:
    """Until ``url`` answers 200 from ``proc``: a port that merely accepts connections may be another
    process's (one that took it first), and ``proc`` may still be about to exit on failing to bind it."""
    _wait_ready(lambda: httpx.get(url, timeout=0.5).status_code == 200, proc, what, f"answer {url}", log, timeout_s)


def _wait_redis(port: int, proc: subprocess.Popen, log: Path, timeout_s: float) -> None:
    """Until the redis-server ``proc`` answers PING on ``port``: a port that merely accepts connections may
    be another process's (one that took it first), and ``proc`` may still be about to exit on failing to bind."""
    def pong() -> bool:
        with socket.create_connection(("127.0.0.1", port), timeout=0.5) as sock:
            sock.sendall(b"PING\r\n")
            return sock.recv(64).startswith(b"+PONG")

    _wait_ready(pong, proc, "redis-server", f"answer PING on port {port}", log, timeout_s)


def _on_free_ports(start_once: Callable[[], None], new_ports: Callable[[], None], attempts: int) -> None:
    """``start_once()``; when it fails because a port was taken by another process before the server bound
    it (the race of :func:`free_port`), ``new_ports()`` and again, at most ``attempts`` times in all."""
    for attempt in range(attempts):
        try:
            start_once()
            return
        except RuntimeError as exc:
            if "Address already in use" not in str(exc) or attempt == attempts - 1:
                raise
            new_ports()


class RedisProcess:
    """``redis-server`` on a free port, with an append-only file in its own folder: a restart keeps the data."""

    def __init__(self) -> None:
        self.binary = need("redis-server")
        self.port = free_port()
        self.dir = Path(tempfile.mkdtemp(prefix="rsmt-redis-"))
        self.log = self.dir / "redis.log"
        self.proc: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    def start(self, timeout_s: float = 20.0, attempts: int = 3) -> RedisProcess:
        """Start redis-server, or start it again on its port (its data kept). On a first start, a free port
        taken by another process before redis bound it (the race of :func:`free_port`) is retried on a new
        port, at most ``attempts`` times in all; a restart keeps its port, which clients already hold."""
        _on_free_ports(lambda: self._start_once(timeout_s), self._new_port, attempts if self.proc is None else 1)
        return self

    def _start_once(self, timeout_s: float) -> None:
        with self.log.open("a") as log:
            self.proc = subprocess.Popen(
                [self.binary, "--port", str(self.port), "--bind", "127.0.0.1", "--dir", str(self.dir),
                 "--appendonly", "yes", "--appendfsync", "always", "--save", "", "--daemonize", "no"],
                stdout=log, stderr=subprocess.STDOUT)
        _wait_redis(self.port, self.proc, self.log, timeout_s)

    def _new_port(self) -> None:
        self.log.write_text("")  # the next attempt's failure is judged by its own output (a first start: no data yet)
        self.port = free_port()

    def stop(self) -> None:
        _stop(self.proc)

    def cleanup(self) -> None:
        self.stop()
        shutil.rmtree(self.dir, ignore_errors=True)


def haproxy_config(port: int, replicas: list[int], check_inter_ms: int = 300, stats_port: int | None = None) -> str:
    """The test topology's ``haproxy.cfg`` (deploy/haproxy.cfg is its production twin): HTTP to the replica
    with the fewest connections, the WebSocket path pinned by source address; both skip a replica whose
    readiness is not 200, and a request whose replica refused the connection, closed it without answering
    (a keep-alive connection of a replica that is stopping) or answered 503 (draining, overloaded) is sent
    again to another replica. ``stats_port``: HAProxy's statistics page (``/stats;csv``) there."""
    servers = "\n".join(f"  server r{i} 127.0.0.1:{p} check inter {check_inter_ms}ms fall 1 rise 2"
                        for i, p in enumerate(replicas))
    stats = (f"\nfrontend stats\n  bind 127.0.0.1:{stats_port}\n  stats enable\n  stats uri /stats\n"
             if stats_port is not None else "")
    return f"""global
  maxconn 512

defaults
  mode http
  option redispatch 1
  retries 2
  retry-on conn-failure empty-response 503
  timeout connect 1s
  timeout client 60s
  timeout server 60s
  timeout tunnel 120s

frontend rsmt
  bind 127.0.0.1:{port}
  acl stream path_beg /v1/stream
  use_backend rsmt_ws if stream
  default_backend rsmt_http

backend rsmt_http
  balance leastconn
  option httpchk GET /v1/health/ready
  http-check expect status 200
{servers}

backend rsmt_ws
  balance source
  hash-type consistent
  option httpchk GET /v1/health/ready
  http-check expect status 200
{servers}
{stats}"""


class HaproxyProcess:
    """``haproxy`` in the foreground (``-db``) with :func:`haproxy_config` in front of ``replicas``."""

    def __init__(self, replicas: list[int]) -> None:
        self.binary = need("haproxy")
        self.replicas = replicas
        self.dir = Path(tempfile.mkdtemp(prefix="rsmt-haproxy-"))
        self.config = self.dir / "haproxy.cfg"
        self.log = self.dir / "haproxy.log"
        self.proc: subprocess.Popen | None = None
        self._pick_ports()

    def _pick_ports(self) -> None:
        self.port, self.stats_port = free_port(), free_port()
        self.config.write_text(haproxy_config(self.port, self.replicas, stats_port=self.stats_port))

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def stats_url(self) -> str:
        return f"http://127.0.0.1:{self.stats_port}/stats"

    def start(self, timeout_s: float = 20.0, attempts: int = 3) -> HaproxyProcess:
        """Start haproxy; a free port taken by another process before haproxy bound it (the race of
        :func:`free_port`) is retried on new ports, at most ``attempts`` times in all."""
        _on_free_ports(lambda: self._start_once(timeout_s), self._new_ports, attempts)
        return self

    def _start_once(self, timeout_s: float) -> None:
        with self.log.open("a") as log:
            self.proc = subprocess.Popen([self.binary, "-db", "-f", str(self.config)], stdout=log,
                                         stderr=subprocess.STDOUT)
        _wait_port(self.port, self.proc, "haproxy", self.log, timeout_s)
        # The stats page answering proves every listener is bound: haproxy binds them one by one and
        # exits on the first it cannot take, which may come after the main port already accepts.
        _wait_http(self.stats_url, self.proc, "haproxy", self.log, timeout_s)

    def _new_ports(self) -> None:
        self.log.write_text("")
        self._pick_ports()

    def cleanup(self) -> None:
        _stop(self.proc)
        shutil.rmtree(self.dir, ignore_errors=True)
