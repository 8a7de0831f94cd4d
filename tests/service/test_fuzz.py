"""Fuzzing: the motion decoders (BVH text and JSON poses, in-process), schemathesis over the OpenAPI schema
(in-process), hypothesis over WebSocket messages (real server). Bounded; the assertion is that a decoder raises
nothing but its 4xx errors, nothing answers 5xx and the server stays healthy.

The budget is CI's by default, the same examples every run. ``RSMT_FUZZ_SCALE=N`` runs N times as many
examples each, drawn afresh (seed them with ``--hypothesis-seed``), for a long fuzzing session in chunks:

    RSMT_FUZZ_SCALE=20 python -m pytest -q tests/service/test_fuzz.py --hypothesis-seed=1 --hypothesis-show-statistics
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from model.inference.engine import Engine
from model.motion.clip import Clip
from service.app import create_app
from service.errors import ServiceError
from service.motion import MotionLimits, motion_to_clip
from service.schemas import CLIENT_TYPES, BvhMotion, PoseMotion
from service.settings import Settings
from tests.model.motion.bvh_strategies import ANY_BVH_TEXT, HOSTILE_NUMBERS, WORDS
from tests.service.conftest import bvh, walk
from tests.service.wsclient import Ws

pytestmark = pytest.mark.slow  # fuzzes the API (schemathesis, hypothesis)

SCALE = max(1, int(os.environ.get("RSMT_FUZZ_SCALE", "1")))


def budget(examples: int):
    """Hypothesis settings of ``examples`` examples (times RSMT_FUZZ_SCALE; fixed examples unless scaled)."""
    return settings(max_examples=examples * SCALE, deadline=None, suppress_health_check=list(HealthCheck),
                    derandomize=SCALE == 1)


def _schema():
    import atexit
    import shutil
    import tempfile

    from model.data.synthetic import synthetic_skeleton
    from model.inference.bundle import Bundle

    # Made at collection (schemathesis reads the schema then), so no fixture can own it: removed at exit.
    folder = tempfile.mkdtemp(prefix="rsmt-fuzz-")
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    path = Bundle.create(synthetic_skeleton(), seed=0).save(Path(folder) / "rsmt")
    app = create_app(Settings(models=path, threads=1, warmup_max_batch=2, max_body_bytes=256 << 10))
    return schemathesis.openapi.from_asgi("/openapi.json", app), Engine(Bundle.load(path), threads=1)


schema, engine = _schema()


@schema.parametrize()
@budget(25)
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
@budget(60)
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
    log = Path(server.log.name).read_text()
    assert "Traceback" not in log, log[-3000:]  # no unhandled exception anywhere in the server


# ---------------------------------------------------------------------- the decoders themselves, in-process
MODEL_BVH_LINES = bvh(walk(6))["bvh"].splitlines()


@st.composite
def damaged_model_bvh(draw: st.DrawFn) -> str:
    """A BVH of the model's own skeleton (so that decoding gets past the joint names), damaged 1-4 times."""
    lines = list(MODEL_BVH_LINES)
    for _ in range(draw(st.integers(1, 4))):
        at = draw(st.integers(0, len(lines) - 1))
        edit = draw(st.sampled_from(["token", "drop", "copy", "cut", "line"]))
        toks = lines[at].split() or [""]
        if edit == "token":
            toks[draw(st.integers(0, len(toks) - 1))] = draw(st.sampled_from(WORDS + HOSTILE_NUMBERS))
            lines[at] = " ".join(toks)
        elif edit == "drop":
            del lines[at]
        elif edit == "copy":
            lines.insert(at, lines[at])
        elif edit == "cut":
            lines[at] = lines[at][:draw(st.integers(0, len(lines[at])))]
        else:
            lines.insert(at, " ".join(draw(st.lists(st.sampled_from(HOSTILE_NUMBERS), max_size=8))))
        if not lines:
            lines = [""]
    return "\n".join(lines)


number = st.one_of(st.floats(), st.sampled_from([0.0, 1.0, -1.0, 1e308, -1e308, 5e-324]), st.integers(-10**20, 10**20),
                   st.text(max_size=4), st.none(), st.booleans())
joints = len(engine.skeleton.names)


@st.composite
def pose_payload(draw: st.DrawFn) -> dict:
    """JSON poses: nearly the model's shape (its joint count, a few frames), with hostile numbers and shapes."""
    frames = draw(st.integers(0, 4))
    width = draw(st.sampled_from([joints, joints, 0, 1, joints + 1]))
    rotations = [[draw(st.lists(number, min_size=3, max_size=5)) if draw(st.integers(0, 9)) == 0 else [0.0, 0.0, 0.0, 1.0]
                  for _ in range(width)] for _ in range(frames)]
    roots = [draw(st.lists(number, min_size=2, max_size=4)) if draw(st.booleans()) else [0.0, 90.0, float(f)]
             for f in range(draw(st.sampled_from([frames, frames, frames + 1, 0])))]
    payload: dict = {"root_positions": roots, "rotations": rotations}
    if draw(st.booleans()):
        payload["fps"] = draw(number)
    if draw(st.booleans()):
        payload["joints"] = draw(st.sampled_from([list(engine.skeleton.names), list(engine.skeleton.names)[::-1], ["x"]]))
    return payload


motion_payload = st.one_of(ANY_BVH_TEXT.map(lambda t: {"bvh": t}), damaged_model_bvh().map(lambda t: {"bvh": t}),
                           pose_payload(), junk)


@given(motion_payload)
@budget(300)
def test_motion_decoders_raise_only_their_own_errors(payload):
    """Any payload: a clip on the model's skeleton, or a validation error (422), or one of the decoders' 4xx codes."""
    limits = MotionLimits(max_frames=1200)
    for kind in (BvhMotion, PoseMotion):
        try:
            motion = kind.model_validate(payload)
        except ValidationError:
            continue
        try:
            clip = motion_to_clip(motion, engine, limits, "context")
        except ServiceError as exc:
            assert 400 <= exc.status < 500, (exc.code, exc.message)
            continue
        assert isinstance(clip, Clip) and clip.skeleton.names == engine.skeleton.names
