"""``rsmt serve`` as the container runs it: readiness, SIGTERM (503, WebSockets closed 1001, bounded exit),
and a clear failure when there is no model."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time

import httpx
import pytest
from websockets.exceptions import ConnectionClosed

from tests.service.server import Server
from tests.service.wsclient import Ws


@pytest.mark.slow  # starts and stops rsmt serve
def test_rsmt_serve_sigterm(bundle_dir):
    # Exactly the container's command, on a free loopback port; the model comes from RSMT_MODELS.
    srv = Server(bundle_dir, command=["rsmt", "serve", "--host", "127.0.0.1", "--port", "{port}"],
                 env={"RSMT_SHUTDOWN_DRAIN_S": "1.5", "RSMT_SHUTDOWN_GRACE_S": "3"})
    srv.start()
    proc = srv.proc
    assert proc is not None
    try:
        assert srv.ready() == 200
        ws = Ws(srv.ws)
        closed: dict = {}

        def wait_close() -> None:
            try:
                while True:
                    ws.conn.recv(30)
            except ConnectionClosed as exc:
                closed["code"] = exc.rcvd.code if exc.rcvd else None
                closed["at"] = time.monotonic()

        reader = threading.Thread(target=wait_close)
        reader.start()
        sent = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        seen: int | str | None = None
        while time.monotonic() - sent < 1.2:  # readiness turns 503 while the drain lets LBs notice
            try:
                seen = httpx.get(srv.url + "/v1/health/ready", timeout=1).status_code
            except httpx.HTTPError:
                seen = "down"
            if seen != 200:
                break
            time.sleep(0.05)
        assert seen == 503, seen
        assert httpx.get(srv.url + "/v1/health/live", timeout=1).status_code == 200
        reader.join(10)
        assert closed.get("code") == 1001 and closed["at"] - sent < 1.0
        code = proc.wait(timeout=1.5 + 3 + 3)
        assert time.monotonic() - sent < 1.5 + 3 + 3
        assert code in (0, -signal.SIGTERM), code
    finally:
        srv.stop()
    # Not on a terminal, the logs are JSON lines; at the default level they still say where the service was.
    events = [json.loads(line) for line in srv.logs().splitlines() if line.startswith("{")]
    announced = {e["event"]: e for e in events if e["logger"] == "service.announce"}
    assert announced["ready"]["url"] == srv.url and announced["ready"]["models"] == ["rsmt"]
    assert announced["ready"]["viewer"] == srv.url + "/viewer"
    assert announced["stopped"]["url"] == srv.url and events[-1]["event"] == "stopped"


@pytest.mark.slow  # starts rsmt serve
def test_rsmt_serve_says_where_it_is_in_text(bundle_dir):
    srv = Server(bundle_dir, command=["rsmt", "serve", "--host", "127.0.0.1", "--port", "{port}", "--log-format", "text"])
    srv.start()
    ready_lines = srv.logs().splitlines()
    # Liveness says only that the process runs; the models are readiness's answer (docs/api-contract.md).
    assert httpx.get(srv.url + "/v1/health/live").json() == {"status": "alive"}
    assert httpx.get(srv.url + "/v1/health/ready").json() == {"status": "ready", "models": ["rsmt"]}
    code = srv.stop()
    lines = srv.logs().splitlines()
    url = srv.url
    assert f"RSMT ready at {url}, model rsmt; viewer {url}/viewer, API docs {url}/docs" in ready_lines
    assert lines[-1] == f"RSMT at {url} stopped", lines
    assert not [line for line in lines if line.startswith("{")]
    assert code in (0, -signal.SIGTERM), (code, lines)


@pytest.mark.slow  # starts rsmt serve with worker processes
def test_rsmt_serve_workers_get_the_command_line_settings(bundle_dir, tmp_path):
    # The environment points nowhere: the workers can only serve if --models reaches them.
    srv = Server(bundle_dir, command=["rsmt", "serve", "--host", "127.0.0.1", "--port", "{port}", "--workers", "2",
                                      "--models", str(bundle_dir)],
                 env={"RSMT_MODELS": str(tmp_path / "none")})
    srv.start()
    try:
        assert httpx.get(srv.url + "/v1/model", timeout=10).json()["name"] == "rsmt"
    finally:
        code = srv.stop()
    assert code in (0, -signal.SIGTERM), (code, srv.logs())


@pytest.mark.slow  # starts rsmt serve processes
def test_no_model_fails_at_startup_with_a_hint(tmp_path):
    out = subprocess.run(["rsmt", "serve", "--port", "0", "--models", str(tmp_path / "none")], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 2
    assert "no model bundle" in out.stderr and "rsmt train" in out.stderr and "--models" in out.stderr
    env = {**os.environ, "RSMT_MODELS": str(tmp_path)}  # an empty directory, under plain uvicorn
    out = subprocess.run([sys.executable, "-m", "uvicorn", "--factory", "service.app:create_app", "--port", "0"],
                         capture_output=True, text=True, timeout=120, env=env)
    assert out.returncode != 0 and "no model bundle" in out.stderr


def test_heap_is_frozen_once_warm(bundle_dir):
    # A full garbage collection over the loaded models stalled the step thread for ~100 ms (four
    # frames of every stream); the lifespan freezes the heap after warm-up so that cannot recur.
    import asyncio
    import gc

    from service.app import create_app
    from service.lifecycle import lifespan
    from service.settings import Settings
    from service.state import Phase

    async def run() -> int:
        app = create_app(Settings(models=bundle_dir, warmup_max_batch=2))
        async with lifespan(app):
            for _ in range(600):
                if app.state.service.phase is Phase.READY:
                    return gc.get_freeze_count()
                await asyncio.sleep(0.1)
            raise AssertionError(f"never ready: {app.state.service.phase} {app.state.service.failure}")

    gc.unfreeze()
    assert gc.get_freeze_count() == 0
    try:
        assert asyncio.run(run()) > 1000  # the models' modules and tensors, at least
    finally:
        gc.unfreeze()
