"""No API key in any log line (issue 53, item 6), under `rsmt serve` (whose info level logs every WebSocket
URL, as compose.yaml sets it) and under plain uvicorn, at every level: ``?token=KEY`` on WebSocket and HTTP
URLs, right and wrong keys alike, is written ``token=[redacted]``; and (issue 64, item 5) a key whose name and
value are percent-encoded (``?%74oken=%6b%65%79...``) appears in no form either."""

from __future__ import annotations

import sys
from pathlib import Path
from urllib.parse import quote, unquote

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


def _percent_encoded(text: str, upper: bool = False) -> str:
    """Every byte of ``text`` as a percent-escape (``%6b%65%79...``)."""
    return "".join(("%%%02X" if upper else "%%%02x") % b for b in text.encode())


def test_no_percent_encoded_key_in_any_log_line(bundle_dir):
    """``?%74oken=%6b%65%79...`` (name and value percent-encoded) is the key to the server (the handshake is
    accepted); no form of it, raw, percent-encoded or decoded, reaches the info or access log."""
    env = {"RSMT_API_KEYS": KEY, "RSMT_LOG_LEVEL": "info", "RSMT_ACCESS_LOG": "true", "RSMT_LOG_FORMAT": "text"}
    server = Server(bundle_dir, env=env, command=SERVE).start()
    lower, upper = _percent_encoded(KEY), _percent_encoded(KEY, upper=True)
    half = KEY[:8] + _percent_encoded(KEY[8:])  # partly encoded
    try:
        for spelled in (lower, upper, half):
            with Ws(server.ws, query=f"%74oken={spelled}") as ws:  # accepted: the key was read from it
                assert ws.ping("in") == []
        with httpx.Client(base_url=server.url, timeout=30) as client:
            for spelled in (lower, upper, half):
                assert client.get(f"/v1/model?%74oken={spelled}", headers={"X-API-Key": KEY}).status_code == 200
                assert client.get(f"/v1/model?T%4fKEN={spelled}&x=1").status_code == 401
                assert client.get(f"/v1/styles/{spelled}", headers={"X-API-Key": KEY}).status_code == 404
    finally:
        server.stop()
    logs = Path(server.log.name).read_text()
    assert "WebSocket" in logs and "/v1/model" in logs, logs[-3000:]  # the lines were written
    forms = {"raw": KEY, "percent-encoded": lower, "percent-encoded (upper)": upper, "partly encoded": half,
             "url-quoted": quote(KEY, safe="")}
    for what, form in forms.items():
        assert form.lower() not in logs.lower(), (what, [line for line in logs.splitlines() if form in line])
    decoded = unquote(unquote(logs))
    assert KEY not in decoded, [line for line in decoded.splitlines() if KEY in line]
