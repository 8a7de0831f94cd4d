"""The client's sans-I/O core, driven by hand: HTTP operations (what is requested, in what order, what comes
back), retry decisions, and the stream session's per-character reassembly. No sockets: these are the decisions
the sync and async clients share."""

from __future__ import annotations

import json

import httpx
import numpy as np
import pytest
from rsmt_client import Frame, Poses, RetryPolicy, RsmtError, TargetAt
from rsmt_client import http_protocol as ops
from rsmt_client._retry import Retrying
from rsmt_client.stream_protocol import StreamSession

from service.streaming.frames import encode_binary, frame_layout

MODEL = {"name": "m", "fps": 30.0,
         "skeleton": {"joints": [{"name": f"J{j}", "parent": j - 1, "offset": [0, 1, 0]} for j in range(2)]}}


def _answer(request: ops.Request, status: int, body: object) -> httpx.Response:
    return httpx.Response(status, json=body, request=httpx.Request(request.method, "http://h" + request.path))


def _transition_answer() -> dict:
    frame = {"root_position": [1, 2, 3], "rotations": [[0, 0, 0, 1], [0, 0, 0, 1]]}
    return {"frames": [frame, frame], "fps": 30.0, "style_id": "sty_a", "model": "m", "timing_ms": {"total": 1.5}}


def test_transition_asks_for_the_model_once():
    state = ops.ClientState("http://h/")
    op = ops.transition(state, {"bvh": "HIERARCHY"}, {"bvh": "HIERARCHY"}, 2, "sty_a", None, 7, True, None, None)
    first = next(op)
    assert (first.method, first.path) == ("GET", "/v1/model")  # joint names and frame limits are not known yet
    second = op.send(_answer(first, 200, MODEL))
    assert (second.method, second.path) == ("POST", "/v1/transition")
    assert second.json["seed"] == 7 and second.json["style_id"] == "sty_a" and "exact_arrival" not in second.json
    with pytest.raises(StopIteration) as done:
        op.send(_answer(second, 200, _transition_answer()))
    poses = done.value.value
    assert isinstance(poses, Poses) and poses.joints == ("J0", "J1") and poses.timing_ms == {"total": 1.5}
    np.testing.assert_array_equal(poses.root_positions, [[1, 2, 3], [1, 2, 3]])
    # Known now: the next transition is one request.
    op = ops.transition(state, {"bvh": "HIERARCHY"}, {"bvh": "HIERARCHY"}, 2, None, {"bvh": "HIERARCHY"}, None, False,
                        None, True)
    request = next(op)
    assert request.json["style"] == {"bvh": "HIERARCHY"} and request.json["exact_arrival"] is True
    with pytest.raises(StopIteration):
        op.send(_answer(request, 200, _transition_answer()))
    with pytest.raises(ValueError, match="exactly one"):
        next(ops.transition(state, {}, {}, 2, None, None, None, False, None, False))


def test_retry_decisions():
    seen: list[tuple[int, float]] = []
    retrying = Retrying(RetryPolicy(attempts=3, backoff_s=0.5, jitter=0.0), on_retry=lambda n, w, r: seen.append((n, w)))
    request = ops.Request("GET", "/v1/model")
    busy = _answer(request, 503, {"error": {"code": "not_ready", "message": "warming up"}})
    assert ops.wait_after_response(retrying, _answer(request, 200, MODEL)) is None
    assert ops.wait_after_response(retrying, busy) == 0.5
    assert ops.wait_after_refusal(retrying, "http://h", ConnectionRefusedError("refused")) == 1.0
    with pytest.raises(RsmtError) as err:  # the third failure is the last try
        ops.wait_after_response(retrying, busy)
    assert err.value.code == "not_ready" and err.value.status == 503 and seen == [(0, 0.5), (1, 1.0)]
    with pytest.raises(RsmtError) as err:  # not retryable at all
        ops.wait_after_response(Retrying(RetryPolicy()), _answer(request, 404, {"error": {"code": "x", "message": "y"}}))
    assert err.value.code == "x"


def _session() -> StreamSession:
    return StreamSession({"type": "hello", "protocol": 1, "model": MODEL, "frame_layout": frame_layout(2),
                          "limits": {"max_message_bytes": 200}})


def _binary(slot: int, seq: int) -> bytes:
    rots = np.tile(np.array([0, 0, 0, 1], np.float32), (1, 2, 1))
    return encode_binary(np.array([slot]), np.array([seq]), np.array([seq / 30]), np.array([[0, 0, seq]]), rots,
                         np.array([3 - seq]))[0]


def test_session_files_each_characters_traffic():
    s = _session()
    wire: list[str | bytes] = [
        json.dumps({"type": "started", "character": "a", "slot": 0}),
        json.dumps({"type": "started", "character": "b", "slot": 1}),
        _binary(0, 0), _binary(1, 0), _binary(1, 1), _binary(0, 1),
        json.dumps({"type": "pong", "id": 1}),
        json.dumps({"type": "end", "character": "b", "reason": "cancelled", "frames": 2}),
        json.dumps({"type": "end", "character": "a", "reason": "arrived", "frames": 2}),
    ]
    a, ended = s.begin_collect("a")
    assert not ended
    for raw in wire:
        if s.take(s.parse(raw), a):
            break
    assert [f.seq for f in a.frames] == [0, 1] and a.end is not None and a.end["reason"] == "arrived"
    assert [m["type"] for m in a.messages] == ["started"]
    # b's traffic and the pong waited, in arrival order; b ends from the queue alone.
    b, ended = s.begin_collect("b")
    assert ended and [f.seq for f in b.frames] == [0, 1] and all(isinstance(f, Frame) for f in b.frames)
    assert s.next_pending() == {"type": "pong", "id": 1} and s.next_pending() is None
    assert s.transition_poses(a).joints == ("J0", "J1")


def test_session_errors_and_limits():
    s = _session()
    c, _ = s.begin_collect("c")
    with pytest.raises(RsmtError) as err:
        s.take(s.parse(json.dumps({"type": "error", "character": "c", "code": "unknown_style", "message": "no"})), c)
    assert err.value.code == "unknown_style" and err.value.character == "c"
    assert not s.take(s.parse(json.dumps({"type": "error", "character": "d", "code": "x", "message": "y"})), c)
    with pytest.raises(RsmtError, match="bad_request"):  # about no character: about everyone
        s.take(s.parse(json.dumps({"type": "error", "code": "bad_request", "message": "?"})), c)
    with pytest.raises(RsmtError) as err:  # over hello's 200-byte limit: refused before sending
        s.encode(StreamSession.start_message({"bvh": "x" * 300}, {}, 2, "sty", None, None, False, "asap", "c", None, None))
    assert err.value.code == "message_too_large"
    with pytest.raises(RsmtError, match="protocol 2"):
        StreamSession({"type": "hello", "protocol": 2})
    with pytest.raises(RsmtError, match="binary frame"):
        StreamSession.from_hello(b"\x00")


def test_the_reach_notice_of_a_stream_is_its_latest_target_s() -> None:
    from rsmt_client import Reach

    s = _session()
    far = {"feasible": False, "distance_cm": 930.0, "frames": 40, "needed_frames": 140, "reachable_cm": 266.7,
           "max_speed_cm_s": 200.0}
    wire: list[str | bytes] = [
        json.dumps({"type": "started", "character": "a", "slot": 0, "reach": {**far, "feasible": True}}),
        _binary(0, 0),
        json.dumps({"type": "retargeted", "character": "a", "from_seq": 1, "reach": far}),
        _binary(0, 1),
        json.dumps({"type": "end", "character": "a", "reason": "arrived", "frames": 2}),
    ]
    a, _ = s.begin_collect("a")
    for raw in wire:
        if s.take(s.parse(raw), a):
            break
    assert s.transition_poses(a).reach == Reach(False, 930.0, 40, 140, 266.7, 200.0)
    assert Reach.from_message({"reach": None}) is None and Reach.from_message(None) is None
    # What collect gives carries it too: ended "arrived", yet short of the target by what the speed cannot cover.
    assert a.end is not None and a.end["reason"] == "arrived"
    assert a.reach == Reach(False, 930.0, 40, 140, 266.7, 200.0) and a.stopped_short
    assert a.reach.short_cm == pytest.approx(930.0 - 266.7) and a.poses().reach == a.reach


def test_a_stream_retargeted_back_within_reach_arrives() -> None:
    s = _session()
    far = {"feasible": False, "distance_cm": 930.0, "frames": 40, "needed_frames": 140, "reachable_cm": 266.7,
           "max_speed_cm_s": 200.0}
    near = {**far, "feasible": True, "distance_cm": 120.0, "needed_frames": 18}
    b, _ = s.begin_collect("b")
    for raw in [json.dumps({"type": "started", "character": "b", "slot": 0, "reach": far}),
                json.dumps({"type": "retargeted", "character": "b", "from_seq": 1, "reach": near}),
                json.dumps({"type": "end", "character": "b", "reason": "arrived", "frames": 2})]:
        if s.take(s.parse(raw), b):
            break
    assert b.reach is not None and b.reach.feasible and b.reach.short_cm == 0.0 and not b.stopped_short
    c, _ = s.begin_collect("c")  # a model without gait limits says nothing either way
    s.take(s.parse(json.dumps({"type": "started", "character": "c", "slot": 1, "reach": None})), c)
    assert c.reach is None and not c.stopped_short


def test_a_style_switch_s_notice_is_the_last_one() -> None:
    s = _session()
    near = {"feasible": True, "distance_cm": 150.0, "frames": 40, "needed_frames": 19, "reachable_cm": 320.0,
            "max_speed_cm_s": 240.0}
    slow = {"feasible": False, "distance_cm": 145.6, "frames": 30, "needed_frames": 73, "reachable_cm": 60.0,
            "max_speed_cm_s": 60.0}
    d, _ = s.begin_collect("d")
    for raw in [json.dumps({"type": "started", "character": "d", "slot": 0, "reach": near}),
                json.dumps({"type": "style_changed", "character": "d", "from_seq": 10, "style_id": "sty_s",
                            "reach": slow}),
                json.dumps({"type": "end", "character": "d", "reason": "arrived", "frames": 40})]:
        if s.take(s.parse(raw), d):
            break
    assert d.reach is not None and d.reach.max_speed_cm_s == 60.0 and d.stopped_short
    assert d.reach.short_cm == pytest.approx(145.6 - 60.0)


def test_exact_arrival_is_sent_as_said_and_left_to_the_server_when_not():
    # False must reach the server: a target_at arrives exactly unless the request says "exact_arrival": false.
    bodies = {said: ops.transition_body({"bvh": "H"}, TargetAt(100.0, 0.0, 90.0), 20, "sty_a", None, None, False, "json",
                                        None, said) for said in (None, False, True)}
    assert "exact_arrival" not in bodies[None]
    assert bodies[False]["exact_arrival"] is False and bodies[True]["exact_arrival"] is True
    start = {said: StreamSession.start_message({"bvh": "H"}, TargetAt(100.0, 0.0, 90.0), 20, "sty_a", None, None, False,
                                               "realtime", "c", None, None, said) for said in (None, False)}
    assert "exact_arrival" not in start[None] and start[False]["exact_arrival"] is False
