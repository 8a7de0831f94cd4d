"""A transition's ``frames`` is decided in one place, the engine's check (:meth:`Engine.check_frames`), which the
service's cap (``RSMT_MAX_TRANSITION_FRAMES``) lowers when the model is loaded: every surface (a whole transition,
a stream's ``start`` and ``retarget``, the model's description, the ``hello``) answers with the same range, the
request schema decides nothing, and the error names the model and the range."""

from __future__ import annotations

import httpx
import pytest

from model.inference.bundle import Bundle
from model.inference.engine import Engine
from model.inference.errors import FramesOutOfRange, TooManyFrames
from service.schemas import RetargetMessage, StartMessage, TransitionRequest
from tests.service.conftest import bvh, context_clip, target_clip
from tests.service.server import Server
from tests.service.wsclient import Ws, start_message

CAP = 30


@pytest.fixture(scope="module")
def server(bundle_dir):
    srv = Server(bundle_dir, env={"RSMT_MAX_TRANSITION_FRAMES": str(CAP)}).start()
    yield srv
    srv.stop()


def _transition(server: Server, frames: int) -> httpx.Response:
    body = {"context": bvh(context_clip()), "target": bvh(target_clip()), "frames": frames,
            "style": bvh(context_clip()), "seed": 1}
    return httpx.post(server.url + "/v1/transition", json=body, timeout=60)


def test_the_engine_takes_the_cap_and_checks_alone(bundle_dir):
    engine = Engine(Bundle.load(bundle_dir), max_frames=CAP)
    own = Engine(Bundle.load(bundle_dir))
    assert engine.max_frames == CAP < own.max_frames
    assert Engine(Bundle.load(bundle_dir), max_frames=10 * own.max_frames).max_frames == own.max_frames
    with pytest.raises(TooManyFrames, match=rf"between 1 and {CAP} for model '{engine.name}'; got {CAP + 1}"):
        engine.check_frames(CAP + 1)
    with pytest.raises(FramesOutOfRange, match=rf"between 1 and {CAP} for model '{engine.name}'; got 0"):
        engine.check_frames(0)
    engine.check_frames(CAP)


def test_the_schema_decides_no_range():
    for model in (TransitionRequest, StartMessage, RetargetMessage):
        spec = str(model.model_json_schema()["properties"]["frames"])
        assert "'minimum': 1" in spec and "maximum" not in spec, (model.__name__, spec)
    big = {"type": "retarget", "character": "a", "frames": 10**9}
    assert RetargetMessage.model_validate(big).frames == 10**9  # the engine refuses it, not the schema


def test_a_transition_answers_the_engines_range(server):
    model = httpx.get(server.url + "/v1/model", timeout=30).json()
    assert model["max_transition_frames"] == CAP
    name = model["name"]
    for frames, code in ((CAP + 1, "too_many_frames"), (10**9, "too_many_frames"), (0, "validation_error"),
                         (-3, "validation_error")):
        r = _transition(server, frames)
        assert r.status_code == 422, r.text
        err = r.json()["error"]
        assert err["code"] == code and err["message"] == (f"frames must be between 1 and {CAP} for model {name!r}; "
                                                          f"got {frames}"), err
    assert _transition(server, CAP).status_code == 200


def test_a_stream_answers_the_engines_range(server):
    with Ws(server.ws) as ws:
        assert ws.hello["limits"]["max_transition_frames"] == CAP
        name = ws.hello["model"]["name"]
        for frames, code in ((CAP + 1, "too_many_frames"), (0, "validation_error")):
            ws.send(start_message("x", frames, request_id=f"s{frames}", style=bvh(context_clip())))
            err = ws.recv()
            assert err["type"] == "error" and err["code"] == code and err["request_id"] == f"s{frames}", err
            assert f"between 1 and {CAP} for model {name!r}; got {frames}" in err["message"], err
        ws.send(start_message("live", CAP, pace="realtime", style=bvh(context_clip())))
        started = ws.recv()
        assert started["type"] == "started", started
        for frames, code in ((CAP + 1, "too_many_frames"), (0, "validation_error")):
            ws.send({"type": "retarget", "character": "live", "frames": frames, "request_id": f"r{frames}"})
            for _ in range(10 * CAP):  # frames of the live character come first
                m = ws.recv()
                if m["type"] not in ("frame", "end"):
                    break
            assert m["type"] == "error" and m["code"] == code and m["request_id"] == f"r{frames}", m
            assert f"between 1 and {CAP} for model {name!r}; got {frames}" in m["message"], m
