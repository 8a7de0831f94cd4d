"""No API key in any log line (issue 53, item 6), under `rsmt serve` (whose info level logs every WebSocket
URL, as compose.yaml sets it) and under plain uvicorn, at every level: ``?token=KEY`` on WebSocket and HTTP
URLs, right and wrong keys alike, is written ``token=[redacted]``."""

from __future__ import annotations

import sys
from pathlib import Path

import httpx
import pytest
from websockets.exceptions import InvalidStatus

from tests.service.server import Server
from tests.service.wsclient import Ws

pytestmark = pytest.mark.slow  # several servers at several log levels

KEY = "log-redaction-key-0123456789abcdef"
WRONG = "wrong-token-zyxwvutsrqponm98765"
SERVE = ["rsmt", "serve", "--host", "127.0.0.1", "--port", "{port}"]


def _uvicorn(level: str) -> list[str]:
    return [sys.executable, "-m", "uvicorn", "--factory", "service.app:create_app", "--host", "127.0.0.1", "--port",
            "{port}", "--log-level", level, "--no-proxy-headers"]


@pytest.mark.parametrize(("command", "level"), [(SERVE, "info"), (SERVE, "debug"), (None, "debug")],
                         ids=["rsmt-serve-info", "rsmt-serve-debug", "uvicorn-debug"])
def test_no_key_in_any_log_line(bundle_dir, command, level):
    env = {"RSMT_API_KEYS": KEY, "RSMT_LOG_LEVEL": level, "RSMT_ACCESS_LOG": "true", "RSMT_LOG_FORMAT": "text"}
    server = Server(bundle_dir, env=env, command=command or _uvicorn(level)).start()
    try:
        with Ws(server.ws, query=f"token={KEY}") as ws:
            assert ws.ping("in") == []
        with pytest.raises(InvalidStatus):
            Ws(server.ws, query=f"token={WRONG}")
        with httpx.Client(base_url=server.url, timeout=30) as client:
            assert client.get(f"/v1/model?token={KEY}", headers={"X-API-Key": KEY}).status_code == 200
            assert client.get(f"/v1/model?token={WRONG}").status_code == 401
            assert client.get("/v1/model", headers={"Authorization": f"Bearer {WRONG}"}).status_code == 401
    finally:
        server.stop()
    logs = Path(server.log.name).read_text()
    assert "WebSocket" in logs and "token=[redacted]" in logs, logs[-3000:]  # the lines were written, redacted
    assert KEY not in logs and WRONG not in logs, [line for line in logs.splitlines() if KEY in line or WRONG in line]
