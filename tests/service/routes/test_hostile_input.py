"""Hostile motion and loosely typed numbers against a real uvicorn: every Motion-taking route and the WebSocket
answer the contract's 4xx codes (never 500 or ``internal``), keep the connection and log no traceback."""

from __future__ import annotations

import httpx
import pytest

from tests.service.conftest import bvh, context_clip, poses, transition_body, walk
from tests.service.server import Server
from tests.service.wsclient import Ws, start_message

pytestmark = pytest.mark.slow  # hostile inputs and vanishing clients against a server of its own

ZERO_CHANNELS = "HIERARCHY\nROOT Hips\n{\n\tOFFSET 0 0 0\n\tCHANNELS 0\n}\nMOTION\nFrames: %s\nFrame Time: 0.0333333\n"


def _huge_frames_bvh() -> str:
    """A real take whose Frames: count has 4,400 digits (past int()'s 4,300)."""
    text = bvh(walk(20))["bvh"]
    return text.replace("Frames: 20", "Frames: " + "9" * 4400, 1)


def _frame_time(text: str, frame_time: str) -> str:
    head, _, rest = text.partition("Frame Time:")
    return head + "Frame Time: " + frame_time + "\n" + rest.split("\n", 1)[1]


HOSTILE = {
    "frames-4400-digits": _huge_frames_bvh(),
    "zero-channels-frames-1e19": ZERO_CHANNELS % "10000000000000000000",
    "zero-channels-frames-4400-digits": ZERO_CHANNELS % ("9" * 4400),
    "channels-4400-digits": bvh(walk(20))["bvh"].replace("CHANNELS 3", "CHANNELS " + "3" * 4400, 1),
    # Frame times whose rate overflows or leaves the sane range (issue 53, item 3: 1e-310 gave 500 / internal).
    **{f"frame-time-{ft}": _frame_time(bvh(walk(20))["bvh"], ft) for ft in ("1e-310", "5e-324", "1e-200", "1e-4", "2")},
}


@pytest.fixture(scope="module")
def style_id(client) -> str:
    return client.post("/v1/styles", json={"name": "walk", "motion": bvh(walk(60))}).json()["style_id"]


def _bodies(style_id: str, motion: dict) -> dict[str, tuple[str, dict]]:
    """Each place a Motion goes over HTTP, holding ``motion``."""
    ok = transition_body(10, style_id=style_id)
    return {
        "styles": ("/v1/styles", {"name": "x", "motion": motion}),
        "transition-context": ("/v1/transition", {**ok, "context": motion}),
        "transition-target": ("/v1/transition", {**ok, "target": motion}),
        "transition-style": ("/v1/transition", {**transition_body(10), "style": motion}),
        "viewer-clip": ("/v1/viewer/clip", {"motion": motion}),
    }


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_hostile_bvh_is_bad_motion_everywhere(client, server, style_id, case):
    for where, (path, body) in _bodies(style_id, {"bvh": HOSTILE[case]}).items():
        r = client.post(path, json=body)
        assert r.status_code == 422, (where, r.status_code, r.text[:300])
        error = r.json()["error"]
        assert error["code"] == "bad_motion" and len(error["message"]) < 400, (where, error)
        assert r.headers.get("connection") != "close", where  # the keep-alive connection stays
    assert client.get("/v1/health/live").status_code == 200
    assert "Traceback" not in server.logs()


def test_zero_channels_with_a_big_but_sane_count_is_too_many_frames(client):
    r = client.post("/v1/viewer/clip", json={"motion": {"bvh": ZERO_CHANNELS % "5000000"}})
    assert r.status_code == 422 and r.json()["error"]["code"] == "too_many_frames", r.text


def test_hostile_bvh_over_the_websocket(server):
    with Ws(server.ws) as ws:
        for n, (case, text) in enumerate(sorted(HOSTILE.items())):
            for field in ("context", "target", "style"):
                msg = start_message(f"c{n}{field}", 10, request_id=f"{case}/{field}", style=bvh(walk(30)))
                ws.send({**msg, field: {"bvh": text}})
                seen = ws.ping(f"{case}/{field}")
                assert [m["type"] for m in seen] == ["error"], seen
                assert seen[0]["code"] == "bad_motion" and seen[0]["request_id"] == f"{case}/{field}", seen
    assert "Traceback" not in server.logs()


# ---------------------------------------------------------------------- strict types (issue 24, row 8)
@pytest.mark.parametrize(("change", "field"), [
    ({"frames": "30"}, "frames"), ({"frames": True}, "frames"), ({"frames": 30.0}, "frames"),
    ({"seed": 2**53}, "seed"), ({"seed": "7"}, "seed"), ({"deterministic": 1}, "deterministic"),
    ({"context": {**poses(context_clip()), "rotations": [[[str(v) for v in q] for q in f]
                                                         for f in poses(context_clip())["rotations"]]}}, "context"),
], ids=["frames-string", "frames-true", "frames-float", "seed-2^53", "seed-string", "deterministic-1",
        "quaternions-as-strings"])
def test_numbers_are_strictly_typed(client, style_id, change, field):
    r = client.post("/v1/transition", json={**transition_body(10, style_id=style_id), **change})
    assert r.status_code == 422 and r.json()["error"]["code"] == "validation_error", r.text[:300]
    assert field in r.json()["error"]["message"], r.text[:300]


def test_largest_seed_and_generated_seeds_fit_javascript(client, style_id):
    r = client.post("/v1/transition", json=transition_body(5, style_id=style_id, seed=2**53 - 1))
    assert r.status_code == 200 and r.json()["seed"] == 2**53 - 1, r.text[:300]
    for _ in range(8):
        r = client.post("/v1/transition", json=transition_body(5, style_id=style_id, seed=None))
        assert r.status_code == 200 and 0 <= r.json()["seed"] <= 2**53 - 1, r.text[:300]


def test_websocket_frames_are_strictly_typed(server):
    changes: tuple[dict[str, object], ...] = ({"frames": "10"}, {"frames": True}, {"seed": 2**53})
    with Ws(server.ws) as ws:
        for n, change in enumerate(changes):
            ws.send({**start_message(f"s{n}", 10, style=bvh(walk(30))), **change})
            seen = ws.ping(f"strict{n}")
            assert [m["type"] for m in seen] == ["error"] and seen[0]["code"] == "validation_error", seen


# ---------------------------------------------------------------------- clients that vanish (issue 24, row 8)
def test_clients_vanishing_mid_stream_leave_no_traceback(bundle_dir):
    """A client that drops its TCP connection while frames are being sent (and more characters are being
    started): no 'Task exception was never retrieved' traceback on stderr, then or when the server stops (it
    would break the JSON log format), and the server carries on meanwhile."""
    import socket
    import struct

    server = Server(bundle_dir).start()
    try:
        for n in range(6):
            ws = Ws(server.ws)
            ws.send(start_message(f"gone{n}", 120, pace="asap", style=bvh(walk(30))))
            assert ws.recv()["type"] == "started"
            for k in range(3):  # the connection's handler is busy preparing these when the sender's write fails
                ws.send(start_message(f"more{n}-{k}", 120, pace="asap", style=bvh(walk(31 + k))))
            ws.conn.socket.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            ws.conn.socket.close()  # a reset, no close frame
        for _ in range(10):  # the server carries on
            assert httpx.post(server.url + "/v1/transition", json=transition_body(10), timeout=30).status_code == 200
        with Ws(server.ws) as ws:
            assert ws.ping("still-here") == []
    finally:
        server.stop()
    assert "never retrieved" not in server.logs() and "Traceback" not in server.logs(), server.logs()
