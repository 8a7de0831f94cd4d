"""Fuzzing: schemathesis over the OpenAPI schema (in-process), hypothesis over WebSocket messages (real server).
Both bounded; the assertion is that nothing answers 5xx and the server stays healthy."""

from __future__ import annotations

import json

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from service.app import create_app
from service.schemas import CLIENT_TYPES
from service.settings import Settings
from tests.service.conftest import bvh, walk
from tests.service.wsclient import Ws


def _schema():
    import atexit
    import shutil
    import tempfile
    from pathlib import Path

    from model.data.synthetic import synthetic_skeleton
    from model.inference.bundle import Bundle

    # Made at collection (schemathesis reads the schema then), so no fixture can own it: removed at exit.
    folder = tempfile.mkdtemp(prefix="rsmt-fuzz-")
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    path = Bundle.create(synthetic_skeleton(), seed=0).save(Path(folder) / "rsmt")
    app = create_app(Settings(models=path, threads=1, warmup_max_batch=2, max_body_bytes=256 << 10))
    return schemathesis.openapi.from_asgi("/openapi.json", app)


schema = _schema()


@schema.parametrize()
@settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
def test_openapi_no_server_errors(case):
    response = case.call()
    if case.path == "/v1/health/ready" and response.status_code == 503:
        return  # not ready yet (warming up) is that endpoint's documented answer
    assert response.status_code < 500, (case.method, case.path, response.status_code, response.text[:500])
    if response.status_code >= 400:
        body = response.json()
        assert set(body) == {"error"} and {"code", "message"} <= set(body["error"]), body


@pytest.fixture(scope="module")
def ws(server):
    with Ws(server.ws) as conn:
        yield conn


junk = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=20),
                    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
                    max_leaves=12)
motion = st.one_of(junk, st.builds(lambda t: {"bvh": t}, st.text(max_size=200)),
                   st.just(bvh(walk(12))), st.fixed_dictionaries({"root_positions": junk, "rotations": junk}))
message = st.fixed_dictionaries(
    {"type": st.sampled_from(list(CLIENT_TYPES) + ["", "frame", "START"]) | junk},
    optional={"character": st.text(max_size=70) | junk, "frames": st.integers(-5, 100) | junk,
              "context": motion, "target": motion, "style": motion, "style_id": st.text(max_size=30) | junk,
              "seed": st.integers() | junk, "pace": st.sampled_from(["realtime", "asap", "fast"]) | junk,
              "deterministic": st.booleans() | junk, "id": junk, "request_id": junk, "model": junk},
)
raw = st.one_of(message.map(json.dumps), st.text(max_size=300), st.binary(max_size=300))


@given(raw)
@settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
def test_websocket_messages_never_break_the_connection(ws, server, data):
    ws.send(data)
    seen = ws.ping("alive", timeout=30)  # whatever came back, the connection still answers in order
    for m in seen:
        assert m["type"] in ("error", "started", "frame", "end", "retargeted", "style_changed", "pong"), m
        if m["type"] == "error":
            assert m["code"] != "internal", m
    # Leave no character running into the next example.
    for m in seen:
        if m["type"] == "started":
            ws.send({"type": "cancel", "character": m["character"]})
    if any(m["type"] == "started" for m in seen):
        ws.ping("flushed", timeout=30)


def test_server_healthy_after_fuzzing(server, ws):
    assert server.ready() == 200
    assert ws.ping("final") is not None
