"""WebSocket ``/v1/stream`` against a real uvicorn: frames, pacing, retarget, style, cancel, many characters,
binary frames, bad messages, oversize messages, idle connections and clients that stop reading."""

from __future__ import annotations

import socket
import time

import httpx
import numpy as np
import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from tests.service.conftest import bvh, context_clip, target_clip, walk
from tests.service.server import Server
from tests.service.wsclient import Ws, poses_of, start_message

FPS = 30.0


@pytest.fixture(scope="module")
def server(bundle_dir):
    srv = Server(bundle_dir, env={"RSMT_IDLE_TIMEOUT_S": "2", "RSMT_SLOW_CLIENT_GRACE_S": "1",
                                  "RSMT_MAX_CHARACTERS_PER_CONNECTION": "16", "RSMT_WS_SEND_BUFFER_BYTES": "65536"}).start()
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def styles(server) -> dict[str, str]:
    out = {}
    for name, clip in (("walk", walk(120)), ("brisk", walk(90, speed_cm_s=150.0, cadence_hz=1.1, stride_deg=30.0))):
        r = httpx.post(server.url + "/v1/styles", json={"name": name, "motion": bvh(clip)}, timeout=30)
        out[name] = r.json()["style_id"]
    return out


def test_hello(server):
    with Ws(server.ws) as ws:
        h = ws.hello
        assert h["protocol"] == 1 and h["model"]["fps"] == FPS
        layout = h["frame_layout"]
        assert layout["encoding"] == "float32-le" and layout["floats_per_frame"] == 7 + 4 * 21
        assert [f["name"] for f in layout["fields"]] == ["slot", "seq", "t", "root_position", "rotations", "remaining"]
        assert set(h["limits"]) >= {"max_characters", "send_queue_frames", "idle_timeout_s", "max_message_bytes"}


def test_frames_in_order_then_end(server, styles):
    with Ws(server.ws) as ws:
        ws.send(start_message("hero", 25, style_id=styles["walk"], request_id=7))
        started = ws.recv()
        assert started["type"] == "started" and started["character"] == "hero" and started["frames"] == 25
        got = ws.run({"hero"})["hero"]
        frames = got["frames"]
        assert [f["seq"] for f in frames] == list(range(25))
        assert [f["remaining"] for f in frames] == list(range(24, -1, -1))
        assert all(abs(f["t"] - (f["seq"] + 1) / FPS) < 1e-9 for f in frames)
        assert len(frames[0]["pose"]["rotations"]) == 21
        assert got["end"]["reason"] == "arrived" and got["end"]["frames"] == 25


def test_stream_equals_http_transition(server, styles):
    body = {"context": bvh(context_clip()), "target": bvh(target_clip()), "frames": 30, "seed": 9,
            "style_id": styles["walk"]}
    http = httpx.post(server.url + "/v1/transition", json=body, timeout=30).json()["frames"]
    with Ws(server.ws) as ws:
        ws.send(start_message("a", 30, seed=9, style_id=styles["walk"]))
        frames = ws.run({"a"})["a"]["frames"]
    roots, rots = poses_of(frames)
    assert np.allclose(roots, np.array([f["root_position"] for f in http]), atol=1e-4)
    assert np.allclose(rots, np.array([f["rotations"] for f in http]), atol=1e-4)


@pytest.mark.alone  # timed
def test_realtime_pacing(server, styles):
    with Ws(server.ws) as ws:
        ws.send(start_message("rt", 30, pace="realtime", style_id=styles["walk"]))
        arrivals = []
        ws.run({"rt"}, on_frame=lambda _ws, f: arrivals.append(time.monotonic()))
    span = arrivals[-1] - arrivals[0]
    assert 29 / FPS * 0.8 < span < 29 / FPS * 2.5, span  # about 0.97 s; loose for a shared 2-core machine
    gaps = np.diff(arrivals)
    assert np.median(gaps) > 0.5 / FPS  # frames are spread out, not burst


def _run_sending(ws: Ws, name: str, at_seq: int, message: dict) -> dict:
    """Run the started character ``name`` to its end, sending ``message`` once, when its frame ``at_seq`` arrives."""
    sent: list[int] = []

    def on_frame(w: Ws, f: dict) -> None:
        if f["seq"] == at_seq and not sent:
            w.send(message)
            sent.append(1)

    return ws.run({name}, on_frame=on_frame)[name]


def _baseline(ws: Ws, styles, name: str, frames: int = 60) -> list[dict]:
    ws.send(start_message(name, frames, deterministic=True, style_id=styles["walk"]))
    return ws.run({name})[name]["frames"]


def test_retarget_changes_where_it_arrives(server, styles):
    with Ws(server.ws) as ws:
        base = _baseline(ws, styles, "base")
        ws.send(start_message("moved", 60, deterministic=True, style_id=styles["walk"]))
        got = _run_sending(ws, "moved", 10, {"type": "retarget", "character": "moved",
                                             "target": bvh(target_clip(shift=250.0)), "request_id": "r1"})
    acks = [m for m in got["messages"] if m["type"] == "retargeted"]
    assert len(acks) == 1
    k = acks[0]["from_seq"]
    assert 10 < k < 60  # flow control bounds how far ahead frames were made
    b_roots, b_rots = poses_of(base)
    m_roots, m_rots = poses_of(got["frames"])
    assert len(got["frames"]) == 60 and got["end"]["reason"] == "arrived"
    assert np.allclose(m_rots[:k], b_rots[:k], atol=1e-4) and np.allclose(m_roots[:k], b_roots[:k], atol=1e-4)
    assert np.abs(m_roots[-1] - b_roots[-1]).max() > 1.0  # cm: it arrives elsewhere


def test_retarget_frames_changes_length(server, styles):
    with Ws(server.ws) as ws:
        ws.send(start_message("len", 60, pace="realtime", style_id=styles["walk"]))
        got = _run_sending(ws, "len", 2, {"type": "retarget", "character": "len", "frames": 5})
    k = next(m for m in got["messages"] if m["type"] == "retargeted")["from_seq"]
    assert len(got["frames"]) == k + 5 == got["end"]["frames"]
    assert got["frames"][-1]["remaining"] == 0


def test_style_switch(server, styles):
    with Ws(server.ws) as ws:
        base = _baseline(ws, styles, "base")
        ws.send(start_message("sw", 60, deterministic=True, style_id=styles["walk"]))
        got = _run_sending(ws, "sw", 5, {"type": "style", "character": "sw", "style_id": styles["brisk"]})
    ack = next(m for m in got["messages"] if m["type"] == "style_changed")
    k = ack["from_seq"]
    assert ack["style_id"] == styles["brisk"] and 5 < k < 60
    assert ack["reach"] is None  # this model has no gait limits: no reach to work out
    _, b_rots = poses_of(base)
    _, s_rots = poses_of(got["frames"])
    assert np.allclose(s_rots[:k], b_rots[:k], atol=1e-4)
    assert np.abs(s_rots[k:] - b_rots[k:]).max() > 1e-3


def test_cancel(server, styles):
    with Ws(server.ws) as ws:
        ws.send(start_message("c", 60, pace="realtime", style_id=styles["walk"]))
        got = _run_sending(ws, "c", 3, {"type": "cancel", "character": "c"})
        assert got["end"]["reason"] == "cancelled" and got["end"]["frames"] == len(got["frames"]) < 60
        seen = ws.ping("after")  # nothing more arrives for it
        assert not [m for m in seen if m.get("character") == "c"]
        ws.send({"type": "cancel", "character": "c", "request_id": 3})
        err = ws.recv()
        assert err["type"] == "error" and err["code"] == "unknown_character" and err["request_id"] == 3


def test_many_characters_one_connection(server, styles):
    names = [f"n{i}" for i in range(12)]
    with Ws(server.ws) as ws:
        for i, n in enumerate(names):
            pace = "realtime" if i % 3 == 0 else "asap"
            ws.send(start_message(n, 20 + i, seed=i, pace=pace, style_id=styles["walk" if i % 2 else "brisk"]))
        got = ws.run(set(names))
        slots = set()
        for i, n in enumerate(names):
            assert [f["seq"] for f in got[n]["frames"]] == list(range(20 + i))
            assert got[n]["end"]["frames"] == 20 + i
            slots.add(got[n]["frames"][0]["slot"])
        assert len(slots) == 12
        # An id can be reused once its character has ended; a live one cannot.
        ws.send(start_message("again", 40, pace="realtime", style_id=styles["walk"]))
        ws.send(start_message("again", 10, style_id=styles["walk"], request_id="dup"))
        seen = ws.ping("p1")
        dup = [m for m in seen if m["type"] == "error"]
        assert dup and dup[0]["code"] == "character_exists" and dup[0]["request_id"] == "dup"
        ws.send({"type": "cancel", "character": "again"})


def test_exact_arrival(server, styles):
    target = target_clip()
    with Ws(server.ws) as ws:
        ws.send(start_message("short", 8, style_id=styles["walk"], exact_arrival=True))
        ws.send(start_message("long", 30, style_id=styles["walk"], exact_arrival=True))
        got = ws.run({"short", "long"})
    for name, n in (("short", 8), ("long", 30)):
        roots, rots = poses_of(got[name]["frames"])
        assert len(roots) == n
        assert np.allclose(roots[-1], target.root_positions[-1].numpy(), atol=1e-2)
        dots = np.abs((rots[-1] * target.rotations[-1].numpy()).sum(-1))
        assert dots.min() > 1 - 1e-4


@pytest.mark.slow  # streams up to the character limit
def test_character_limit_per_connection(server, styles):
    with Ws(server.ws) as ws:
        for i in range(17):
            ws.send(start_message(f"l{i}", 60, pace="realtime", style_id=styles["walk"]))
        seen = ws.ping("p")
        errors = [m for m in seen if m["type"] == "error"]
        assert len(errors) == 1 and errors[0]["code"] == "too_many_characters"
        assert sum(m["type"] == "started" for m in seen) == 16


def test_binary_and_json_frames_agree(server, styles):
    out = {}
    for encoding in ("json", "binary"):
        with Ws(server.ws, encoding=encoding) as ws:
            ws.send(start_message("b", 24, seed=4, style_id=styles["walk"]))
            out[encoding] = ws.run({"b"})["b"]
    assert [f["seq"] for f in out["binary"]["frames"]] == list(range(24))
    jr, jq = poses_of(out["json"]["frames"])
    br, bq = poses_of(out["binary"]["frames"])
    assert np.allclose(jr, br, atol=1e-4) and np.allclose(jq, bq, atol=1e-4)
    assert [f["remaining"] for f in out["binary"]["frames"]] == [f["remaining"] for f in out["json"]["frames"]]
    assert np.allclose([f["t"] for f in out["binary"]["frames"]], [f["t"] for f in out["json"]["frames"]], atol=1e-6)


def test_bad_messages_get_errors_and_the_connection_stays(server, styles):
    bad: list[tuple[str | bytes, str]] = [
        ("garbage", "invalid_json"),
        ("[1, 2]", "validation_error"),
        ('{"no": "type"}', "validation_error"),
        ('{"type": "dance"}', "validation_error"),
        ('{"type": "start"}', "validation_error"),
        ('{"type": "start", "context": {"bvh": "nope"}, "target": {"bvh": "nope"}, "frames": 5, "style_id": "x"}',
         "bad_motion"),
        ('{"type": "retarget", "character": "ghost", "frames": 5}', "unknown_character"),
        ('{"type": "style", "character": "ghost", "style_id": "x"}', "unknown_character"),
        ('{"type": "cancel"}', "validation_error"),
        ('{"type": "ping", "extra": 1}', "validation_error"),
        (b"\x00\x01binary", "validation_error"),
    ]
    with Ws(server.ws) as ws:
        for message, code in bad:
            ws.send(message)
            err = ws.recv()
            assert err["type"] == "error" and err["code"] == code, (message, err)
        for extra, code in (({"frames": 0}, "validation_error"), ({"frames": 121}, "too_many_frames"),
                            ({"style_id": "sty_unknown"}, "unknown_style"),
                            ({"context": bvh(context_clip().window(0, 4))}, "too_few_frames")):
            msg = {**start_message("x", 10, request_id=f"q{code}", style_id=styles["walk"]), **extra}
            ws.send(msg)
            err = ws.recv()
            assert err["type"] == "error" and err["code"] == code and err["request_id"] == f"q{code}", err
        assert ws.ping("still") == []
    assert server.ready() == 200


def test_oversize_message_closes_1009(server):
    with Ws(server.ws) as ws:
        ws.send("x" * (70 << 10))
        with pytest.raises(ConnectionClosed) as info:
            ws.recv(10)
        assert info.value.rcvd is not None and info.value.rcvd.code == 1009
    assert server.ready() == 200


@pytest.mark.alone  # timed
def test_idle_connection_closes_1000(server):
    with Ws(server.ws) as ws:
        started = time.monotonic()
        with pytest.raises(ConnectionClosed) as info:
            ws.recv(10)
        rcvd = info.value.rcvd
        assert rcvd is not None and rcvd.code == 1000 and rcvd.reason == "idle"
        assert 1.5 < time.monotonic() - started < 6


@pytest.mark.alone  # timed
def test_client_that_never_reads_is_closed_1008(server, styles):
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", server.port))
    conn = connect(server.ws + "?encoding=json", sock=sock, proxy=None, compression=None, max_queue=1,
                   open_timeout=20)
    try:
        for i in range(16):
            conn.send(__import__("json").dumps(start_message(f"s{i}", 60, seed=i, style_id=styles["walk"])))
        time.sleep(2.5)  # never read: buffers and queues fill, the grace (1 s) passes, the close frame waits
        codes = None
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            try:
                conn.recv(10)
            except ConnectionClosed as exc:
                codes = exc.rcvd
                break
        assert codes is not None and codes.code == 1008 and "not reading" in codes.reason
    finally:
        conn.close()
    assert server.ready() == 200
    with Ws(server.ws) as ws:  # and it still streams
        ws.send(start_message("after", 5, style_id=styles["walk"]))
        assert len(ws.run({"after"})["after"]["frames"]) == 5
