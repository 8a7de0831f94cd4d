"""A real uvicorn (or ``rsmt serve``) subprocess on a free 127.0.0.1 port, for the service tests."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx

# Settings every test server shares unless a test overrides them.
BASE_ENV = {
    "RSMT_THREADS": "1",
    "RSMT_WARMUP_MAX_BATCH": "8",
    "RSMT_LOG_LEVEL": "warning",
    "RSMT_SHUTDOWN_DRAIN_S": "0.3",
    "RSMT_SHUTDOWN_GRACE_S": "3",
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """Start with :meth:`start`, stop with :meth:`stop` (SIGTERM, then kill); ``url``/``ws`` address it."""

    def __init__(self, bundle: Path, env: dict[str, str] | None = None, command: list[str] | None = None) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.ws = f"ws://127.0.0.1:{self.port}/v1/stream"
        self.env = {**os.environ, **BASE_ENV, "RSMT_MODELS": str(bundle), **(env or {})}
        self.command = command or [
            sys.executable, "-m", "uvicorn", "--factory", "service.app:create_app", "--host", "127.0.0.1",
            "--port", str(self.port), "--ws-max-size", self.env.get("RSMT_WS_MAX_MESSAGE_BYTES", str(64 << 10)),
            "--timeout-graceful-shutdown", "3", "--log-level", "warning", "--ws-per-message-deflate", "false",
            "--no-proxy-headers",  # as `rsmt serve` by default: X-Forwarded-For from 127.0.0.1 is not trusted
        ]
        self.command = [c.replace("{port}", str(self.port)) for c in self.command]
        self.log = tempfile.NamedTemporaryFile("w+", prefix="rsmt-server-", suffix=".log", delete=False)
        self.proc: subprocess.Popen | None = None

    def start(self, timeout_s: float = 90.0) -> Server:
        self.proc = subprocess.Popen(self.command, env=self.env, stdout=self.log, stderr=subprocess.STDOUT,
                                     cwd=Path(__file__).resolve().parents[2])
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}:\n{self.logs()}")
            try:
                if httpx.get(self.url + "/v1/health/ready", timeout=1.0).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.1)
        self.stop()
        raise RuntimeError(f"server not ready within {timeout_s} s:\n{self.logs()}")

    def ready(self) -> int:
        return httpx.get(self.url + "/v1/health/ready", timeout=5.0).status_code

    def logs(self) -> str:
        self.log.flush()
        return Path(self.log.name).read_text()[-4000:]

    def stop(self, timeout_s: float = 10.0) -> int | None:
        if self.proc is None or self.proc.poll() is not None:
            return None if self.proc is None else self.proc.returncode
        self.proc.send_signal(signal.SIGTERM)
        try:
            return self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait(5)


@contextmanager
def server_with_style_store(store: str, bundle_dir: Path, env: dict[str, str] | None = None) -> Iterator[Server]:
    """A test server whose styles live in ``store``: ``"memory"`` (the process's own) or ``"redis"`` (a Redis
    server of its own, started first and removed after)."""
    from tests.service.processes import RedisProcess

    env = dict(env or {})
    redis = None
    if store == "redis":
        redis = RedisProcess().start()
        env["RSMT_STYLE_STORE"] = redis.url
    elif store != "memory":
        raise ValueError(f"style store 'memory' or 'redis', got {store!r}")
    srv = Server(bundle_dir, env=env).start()
    try:
        yield srv
    finally:
        srv.stop()
        if redis is not None:
            redis.cleanup()
