"""The Python client (``rsmt_client``) and ``rsmt client`` CLI against a live ``rsmt serve``: sync and async HTTP,
WebSocket streams (JSON and binary), retries on 429/503, numpy results, BVH in and out, errors."""

from __future__ import annotations

import asyncio
import email.utils
import json
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from rsmt_client import (
    NO_RETRY,
    AsyncClient,
    AsyncStreamClient,
    Client,
    Frame,
    Poses,
    RetryPolicy,
    RsmtError,
    StreamClient,
    parse_retry_after,
    stream_url,
)

from model.data.synthetic import synthetic_walk
from model.motion.bvh_clip import dump_clip, load_clip
from rsmt_cli.main import main as rsmt_main
from tests.clients.conftest import serve_command
from tests.clients.helpers import API_KEY, FRAMES, SEED
from tests.model.motion.rotation_angle import quat_angle
from tests.service.server import Server


@pytest.fixture(scope="module")
def client(server):
    with Client(server.url, api_key=API_KEY) as c:
        yield c


@pytest.fixture(scope="module")
def style_id(client, motions) -> str:
    return client.register_style(motions["style"], name="walk")["style_id"]


def _rot_close(a: np.ndarray, b: np.ndarray, atol: float) -> bool:
    """Rotations equal up to the quaternion sign."""
    import torch

    return float(quat_angle(torch.from_numpy(np.asarray(a, np.float64)),
                            torch.from_numpy(np.asarray(b, np.float64))).max()) < atol


# ---------------------------------------------------------------------- HTTP, sync

def test_health_model_and_styles(client, motions, style_id):
    assert client.live() and client.ready()
    info = client.model()
    assert info["fps"] == 30.0 and len(info["skeleton"]["joints"]) == 21
    assert client.models()["default"] == info["name"]
    again = client.register_style(motions["style"], name="walk")
    assert again["style_id"] == style_id and again["cached"] is True
    assert style_id in {s["style_id"] for s in client.styles()}
    assert client.style(style_id)["frames"] == 120
    other = client.register_style(motions["style2"].read_text(), name="brisk")  # BVH text works as well as a path
    client.delete_style(other["style_id"])
    with pytest.raises(RsmtError) as err:
        client.style(other["style_id"])
    assert err.value.code == "unknown_style" and err.value.status == 404


def test_a_style_from_several_clips(server, client, motions, style_id):
    info = client.register_style_clips([motions["style"], motions["style2"].read_text()], name="both")
    assert info["clips"] == 2 and info["frames"] == 120 + 90 and info["name"] == "both" and info["style_id"] != style_id
    again = client.register_style_clips([motions["style2"], motions["style"]])  # another order: the same style
    assert again["style_id"] == info["style_id"] and again["cached"] is True and again["name"] == "style2"
    a = client.transition(motions["context"], motions["target"], FRAMES, style_id=info["style_id"], seed=SEED)
    assert a.style_id == info["style_id"] and a.num_frames == FRAMES
    client.delete_style(info["style_id"])  # forgotten on purpose: not registered again
    with pytest.raises(ValueError, match="1 to 5 clips; got 6"):
        client.register_style_clips([motions["style"]] * 6)

    async def run() -> dict:
        async with AsyncClient(server.url, api_key=API_KEY) as c:
            return await c.register_style_clips([motions["style"], motions["style2"]])

    assert asyncio.run(run())["style_id"] == info["style_id"]
    with pytest.raises(RsmtError) as err:
        client.register_style_clips([motions["style"], dump_clip(synthetic_walk(8))])  # too short a style clip
    assert err.value.code == "too_few_frames" and "motions[1]" in str(err.value)


def test_transition_gives_numpy_arrays_and_is_repeatable(client, motions, style_id):
    a = client.transition(motions["context"], motions["target"], FRAMES, style_id=style_id, seed=SEED)
    b = client.transition(motions["context"], motions["target"], FRAMES, style_id=style_id, seed=SEED)
    assert isinstance(a, Poses) and a.num_frames == FRAMES
    assert a.root_positions.shape == (FRAMES, 3) and a.rotations.shape == (FRAMES, 21, 4)
    assert a.root_positions.dtype == np.float32 and a.rotations.dtype == np.float32
    assert a.style_id == style_id and a.fps == 30.0 and a.timing_ms["total"] > 0
    assert a.joints is not None and a.joints[0] == "Hips"
    np.testing.assert_array_equal(a.root_positions, b.root_positions)
    np.testing.assert_array_equal(a.rotations, b.rotations)
    # An inline style clip encodes to the same style: same frames.
    c = client.transition(motions["context"], motions["target"], FRAMES, style=motions["style"], seed=SEED)
    np.testing.assert_allclose(c.rotations, a.rotations, atol=1e-6)


def test_bvh_out_round_trips(client, motions, style_id, tmp_path):
    poses = client.transition(motions["context"], motions["target"], 30, style_id=style_id, seed=3, deterministic=True)
    path = poses.save_bvh(tmp_path / "out.bvh", client.model())
    clip = load_clip(path)
    assert clip.num_frames == 30 and clip.fps == pytest.approx(30.0)
    assert list(clip.skeleton.names) == [j["name"] for j in client.model()["skeleton"]["joints"]]
    np.testing.assert_allclose(clip.root_positions.numpy(), poses.root_positions, atol=1e-4)
    assert _rot_close(clip.rotations.numpy(), poses.rotations, atol=1e-4)
    # The server's own BVH output (output: bvh) has the same frames.
    server_clip = load_clip(client.transition_bvh(motions["context"], motions["target"], 30, style_id=style_id,
                                                  seed=3, deterministic=True))
    assert server_clip.num_frames == 30
    np.testing.assert_allclose(server_clip.root_positions.numpy(), poses.root_positions, atol=1e-3)
    assert _rot_close(server_clip.rotations.numpy(), poses.rotations, atol=1e-3)
    # Poses go back in as a Motion payload (e.g. to chain transitions).
    chained = client.transition(poses, motions["target"], 10, style_id=style_id, seed=1)
    assert chained.num_frames == 10


def test_errors_keep_the_server_code(server, client, motions):
    with pytest.raises(RsmtError) as err:
        client.transition(motions["context"], motions["target"], 10, style_id="sty_nope")
    assert err.value.code == "unknown_style" and err.value.status == 404 and "POST /v1/styles" in err.value.message
    with Client(server.url, api_key="wrong-key-wrong-key-wrong") as bad, pytest.raises(RsmtError) as err:
        bad.model()
    assert err.value.code == "unauthorized" and err.value.status == 401
    with pytest.raises(RsmtError) as err:
        client.transition(motions["context"], motions["target"], 10_000, style_id="x")
    assert err.value.status == 422
    with pytest.raises(ValueError):
        client.transition(motions["context"], motions["target"], 10)  # no style at all
    with Client("http://127.0.0.1:9", retry=RetryPolicy(attempts=2, backoff_s=0.01)) as nowhere, \
            pytest.raises(RsmtError) as err:
        nowhere.model()
    assert err.value.code == "connection"


# ---------------------------------------------------------------------- HTTP, async

def test_async_client_matches_sync(server, client, motions, style_id):
    sync = client.transition(motions["context"], motions["target"], 20, style_id=style_id, seed=SEED)

    async def go() -> tuple[dict, Poses, list]:
        async with AsyncClient(server.url, api_key=API_KEY) as c:
            info = await c.model()
            style = await c.register_style(motions["style"], name="walk")
            poses = await c.transition(motions["context"], motions["target"], 20, style_id=style["style_id"], seed=SEED)
            many = await asyncio.gather(*[c.transition(motions["context"], motions["target"], 10, style_id=style_id,
                                                       seed=s) for s in range(3)])
            return info, poses, many

    info, poses, many = asyncio.run(go())
    assert info["name"] == client.model()["name"]
    np.testing.assert_array_equal(poses.rotations, sync.rotations)
    assert [p.num_frames for p in many] == [10, 10, 10]


# ---------------------------------------------------------------------- WebSocket

def test_stream_json_and_binary_match_http(server, client, motions, style_id):
    http = client.transition(motions["context"], motions["target"], FRAMES, style_id=style_id, seed=SEED,
                             deterministic=True)
    got = {}
    for encoding in ("json", "binary"):
        with StreamClient(server.url, api_key=API_KEY, encoding=encoding) as s:
            assert s.hello["protocol"] == 1 and s.layout.floats_per_frame == 7 + 4 * 21
            c = s.start(motions["context"], motions["target"], FRAMES, style_id=style_id, seed=SEED, deterministic=True,
                        pace="asap")
            result = s.collect(c)
        assert [f.seq for f in result.frames] == list(range(FRAMES))
        assert all(isinstance(f, Frame) and f.character == c for f in result.frames)
        assert [f.remaining for f in result.frames] == list(range(FRAMES - 1, -1, -1))
        assert result.frames[-1].t == pytest.approx(FRAMES / 30.0, abs=1e-6)
        assert result.end is not None and result.end["reason"] == "arrived" and result.end["frames"] == FRAMES
        got[encoding] = result.poses(s.joint_names)
    for poses in got.values():
        np.testing.assert_allclose(poses.root_positions, http.root_positions, atol=1e-4)
        np.testing.assert_allclose(poses.rotations, http.rotations, atol=1e-4)
    np.testing.assert_array_equal(got["json"].rotations, got["binary"].rotations)  # the same float32 numbers


def test_a_request_sets_its_own_style_strength_over_http_and_the_stream(server, client, motions, style_id):
    args = (motions["context"], motions["target"], FRAMES)
    plain = client.transition(*args, style_id=style_id, seed=SEED, deterministic=True)
    one = client.transition(*args, style_id=style_id, seed=SEED, deterministic=True, style_strength=1.0)
    np.testing.assert_array_equal(one.rotations, plain.rotations)  # 1 is the server's setting here
    strong = client.transition(*args, style_id=style_id, seed=SEED, deterministic=True, style_strength=1.25)
    assert np.abs(strong.rotations - plain.rotations).max() > 1e-3
    with StreamClient(server.url, api_key=API_KEY) as s:
        streamed = s.transition(*args, style_id=style_id, seed=SEED, deterministic=True, style_strength=1.25)
    np.testing.assert_allclose(streamed.rotations, strong.rotations, atol=1e-4)
    for bad in (-0.5, 4.5):
        with pytest.raises(RsmtError) as err:
            client.transition(*args, style_id=style_id, seed=SEED, style_strength=bad)
        assert err.value.code == "validation_error" and "style_strength" in str(err.value)


def test_stream_retarget_cancel_ping_and_many_characters(server, motions, style_id):
    with StreamClient(server.url, api_key=API_KEY, encoding="binary") as s:
        a = s.start(motions["context"], motions["target"], 60, style_id=style_id, pace="realtime")
        b = s.start(motions["context"], motions["target"], 60, style_id=style_id, pace="realtime")
        sent: list[int] = []

        def on_frame(client: StreamClient, f: Frame) -> None:
            if f.seq == 2 and not sent:
                client.retarget(a, target=motions["target2"], frames=5, request_id="r1")
                client.cancel(b)
                client.ping("p1")
                sent.append(1)

        ra = s.collect(a, on_frame=on_frame)
        k = next(m for m in ra.messages if m["type"] == "retargeted")["from_seq"]
        assert ra.end is not None and len(ra.frames) == k + 5 == ra.end["frames"] and ra.end["reason"] == "arrived"
        rb = s.collect(b)  # b's traffic was queued while a was collected
        assert rb.end is not None and rb.end["reason"] == "cancelled" and len(rb.frames) < 60
        kinds = []
        while True:  # the pong came while a and b were collected
            try:
                item = s.recv(timeout=2)
                assert isinstance(item, dict), item  # both characters have ended: no frame is left
                kinds.append(item["type"])
            except RsmtError as exc:
                assert exc.code == "timeout"
                break
        assert "pong" in kinds


def test_stream_errors_and_token_in_query(server, motions, style_id):
    with StreamClient(server.url, api_key=API_KEY, token_in_query=True) as s:  # what WebGL clients must do
        c = s.start(motions["context"], motions["target"], 10, style_id="sty_unknown", pace="asap")
        with pytest.raises(RsmtError) as err:
            s.collect(c, timeout=20)
        assert err.value.code == "unknown_style" and err.value.character == c
        # A 120-frame style clip inline is over the server's 64 KiB message limit (sent, the server would close
        # the connection with 1009): the client registers it over HTTP and starts by its id.
        c = s.start(motions["context"], motions["target"], 10, style=motions["style"], pace="asap")
        result = s.collect(c, timeout=20)
        started = next(m for m in result.messages if m["type"] == "started")
        assert result.end is not None and result.end["reason"] == "arrived" and started["style_id"] == style_id
    with pytest.raises(RsmtError) as err:
        StreamClient(server.url, api_key="wrong-key-wrong-key-wrong")
    assert err.value.code == "unauthorized" and err.value.status == 401
    assert stream_url("https://h:1/base/", "binary", "k") == "wss://h:1/base/v1/stream?encoding=binary&token=k"


def test_async_stream(server, client, motions, style_id):
    http = client.transition(motions["context"], motions["target"], 20, style_id=style_id, seed=SEED, deterministic=True)

    async def go() -> Poses:
        async with await AsyncStreamClient.connect(server.url, api_key=API_KEY, encoding="binary") as s:
            assert s.model["fps"] == 30.0
            by_clip = await s.transition(motions["context"], motions["target"], 20, style=motions["style"], seed=SEED,
                                         deterministic=True)  # over the message limit inline: registered, by id
            assert by_clip.style_id == style_id
            return await s.transition(motions["context"], motions["target"], 20, style_id=style_id, seed=SEED,
                                      deterministic=True)

    poses = asyncio.run(go())
    assert poses.style_id == style_id
    np.testing.assert_allclose(poses.rotations, http.rotations, atol=1e-4)


def test_exact_arrival_reaches_the_target_pose(server, client, motions, style_id):
    target = load_clip(motions["target"])
    free = client.transition(motions["context"], motions["target"], 20, style_id=style_id, seed=SEED)
    exact = client.transition(motions["context"], motions["target"], 20, style_id=style_id, seed=SEED, exact_arrival=True)
    with StreamClient(server.url, api_key=API_KEY) as s:
        streamed = s.transition(motions["context"], motions["target"], 20, style_id=style_id, seed=SEED,
                                exact_arrival=True)
    np.testing.assert_allclose(streamed.rotations, exact.rotations, atol=1e-4)
    last = target.rotations[-1].numpy()

    def miss(p: Poses) -> float:
        import torch

        return float(quat_angle(torch.from_numpy(p.rotations[-1].astype(np.float64)),
                                torch.from_numpy(last.astype(np.float64))).max())

    assert miss(exact) < 1e-3 < miss(free)


def test_binary_frames_of_another_model_use_started_floats_per_frame():
    """A multi-model server sends hello for the default model; a character of another model announces its
    binary layout in ``started.floats_per_frame``."""
    from rsmt_client.stream_protocol import StreamSession

    from service.streaming.frames import encode_binary, frame_layout

    model = {"fps": 30.0, "skeleton": {"joints": [{"name": f"J{j}", "parent": j - 1, "offset": [0, 1, 0]}
                                                  for j in range(3)]}}
    session = StreamSession({"type": "hello", "protocol": 1, "model": model, "frame_layout": frame_layout(3)})
    session.parse(json.dumps({"type": "started", "character": "small", "slot": 0, "floats_per_frame": 19}))
    session.parse(json.dumps({"type": "started", "character": "big", "slot": 1, "floats_per_frame": 27}))
    rots5 = np.tile(np.array([0, 0, 0, 1], np.float32), (1, 5, 1))
    big = session.parse(encode_binary(np.array([1]), np.array([4]), np.array([0.5]), np.array([[1, 2, 3]]), rots5,
                                      np.array([7]))[0])
    small = session.parse(encode_binary(np.array([0]), np.array([2]), np.array([0.1]), np.array([[4, 5, 6]]),
                                        rots5[:, :3], np.array([1]))[0])
    assert isinstance(big, Frame) and big.character == "big" and big.rotations.shape == (5, 4) and big.remaining == 7
    assert isinstance(small, Frame) and small.character == "small" and small.rotations.shape == (3, 4)
    assert small.seq == 2
    np.testing.assert_array_equal(big.root_position, [1, 2, 3])


# ---------------------------------------------------------------------- retries

def test_retry_after_parsing():
    assert parse_retry_after("3") == 3.0 and parse_retry_after(None) is None and parse_retry_after("soon") is None
    later = email.utils.formatdate(time.time() + 30, usegmt=True)
    seconds = parse_retry_after(later)
    assert seconds is not None and 25 < seconds <= 31
    policy = RetryPolicy(attempts=3, backoff_s=0.5, jitter=0.0)
    assert policy.wait(0, 503, {}) == 0.5 and policy.wait(1, 503, {}) == 1.0 and policy.wait(2, 503, {}) is None
    assert policy.wait(0, 429, {"retry-after": "2"}) == 2.0
    assert policy.wait(0, 429, {"retry-after": "600"}) is None  # longer than max_retry_after_s: the caller decides
    assert policy.wait(0, 404, {}) is None


def _flaky(statuses: list[tuple[int, dict]]):
    calls = []

    def handler(request: httpx.Request) -> httpx.Response:
        calls.append(request)
        status, headers = statuses[min(len(calls) - 1, len(statuses) - 1)]
        body = {"name": "m"} if status == 200 else {"error": {"code": "rate_limited" if status == 429 else "not_ready",
                                                             "message": "later"}}
        return httpx.Response(status, json=body, headers=headers)

    return handler, calls


def test_sync_retries_503_and_429_honouring_retry_after():
    handler, calls = _flaky([(503, {}), (429, {"Retry-After": "2"}), (200, {})])
    waits: list[float] = []
    with Client("http://test", transport=httpx.MockTransport(handler), sleep=waits.append,
                retry=RetryPolicy(backoff_s=0.1, jitter=0.0)) as c:
        assert c.model() == {"name": "m"}
    assert len(calls) == 3 and waits[0] == pytest.approx(0.1) and waits[1] == pytest.approx(2.0, abs=0.25)
    handler, calls = _flaky([(429, {"Retry-After": "1"})])
    with Client("http://test", transport=httpx.MockTransport(handler), sleep=lambda s: None,
                retry=RetryPolicy(attempts=3)) as c, pytest.raises(RsmtError) as err:
        c.model()
    assert len(calls) == 3 and err.value.code == "rate_limited" and err.value.retry_after == 1.0


def test_async_retries():
    handler, calls = _flaky([(503, {"Retry-After": "0"}), (200, {})])
    retried = []

    async def go() -> dict:
        async with AsyncClient("http://test", transport=httpx.MockTransport(handler),
                               on_retry=lambda n, w, r: retried.append((n, r.status_code))) as c:
            return await c.model()

    assert asyncio.run(go()) == {"name": "m"} and retried == [(0, 503)] and len(calls) == 2


@pytest.mark.slow  # waits out Retry-After
def test_live_429_is_retried_after_retry_after(client_bundle, motions):
    """A server with a tiny rate limit (1 request/s, burst 1): the client waits as told and gets through."""
    srv = Server(client_bundle, env={"RSMT_RATE_LIMIT_PER_S": "1", "RSMT_RATE_LIMIT_BURST": "1",
                                     "RSMT_WARMUP_MAX_BATCH": "1"}, command=serve_command(client_bundle)).start()
    try:
        retried = []
        with Client(srv.url, on_retry=lambda n, w, r: retried.append((r.status_code, r.headers.get("retry-after"), w))) as c:
            t0 = time.monotonic()
            c.model()
            c.model()  # the bucket is empty: 429 with Retry-After: 1, then success
            elapsed = time.monotonic() - t0
        assert retried and retried[0][0] == 429 and retried[0][1] == "1" and retried[0][2] >= 1.0
        assert elapsed >= 1.0
        with Client(srv.url, retry=NO_RETRY) as c, pytest.raises(RsmtError) as err:
            c.model()
            c.model()
        retry_after = err.value.retry_after
        assert err.value.code == "rate_limited" and err.value.status == 429
        assert retry_after is not None and retry_after >= 1
        # The WebSocket handshake is rate limited too; the stream client retries it the same way.
        with StreamClient(srv.url) as s:
            assert s.hello["type"] == "hello"
    finally:
        srv.stop()


# ---------------------------------------------------------------------- CLI

def _check_cli_styles(common: list[str], motions: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> dict:
    """`rsmt client styles add` registers one clip or several, `styles list` shows them as JSON lines or a table;
    returns the first style added."""
    assert rsmt_main(["client", "styles", "add", str(motions["style"]), "--name", "walk", *common]) == 0
    added = json.loads(capsys.readouterr().out)
    assert added["name"] == "walk" and added["style_id"].startswith("sty_")
    assert rsmt_main(["client", "styles", "add", str(motions["style"]), str(motions["style2"]), *common]) == 0
    both = json.loads(capsys.readouterr().out)
    assert both["clips"] == 2 and both["name"] == "style" and both["style_id"] != added["style_id"]
    assert rsmt_main(["client", "styles", "add", str(motions["style"]), str(motions["style2"]), "--frames", "30",
                      *common]) == 2
    assert "cut one clip" in capsys.readouterr().err
    assert rsmt_main(["client", "styles", "list", "--json", *common]) == 0
    listed = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert added["style_id"] in {s["style_id"] for s in listed}
    assert {"style_id": "builtin:walk", "name": "walk", "frames": 40, "clips": 1, "cached": True, "model": "rsmt",
            "builtin": True} in listed
    assert rsmt_main(["client", "styles", "list", *common]) == 0
    table = capsys.readouterr().out.splitlines()
    assert table[0].split() == ["style_id", "frames", "model", "kind", "name"]
    assert table[1].split() == ["builtin:walk", "40", "rsmt", "built-in", "walk"]
    assert [line.split()[3] for line in table[2:]] == ["registered"] * (len(table) - 2)
    return added


def _check_cli_http_matches_stream(common: list[str], motion: list[str], tmp_path: Path,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    """`client transition` and `client stream` write the same deterministic transition."""
    out_http, out_ws = tmp_path / "http.bvh", tmp_path / "ws.bvh"
    assert rsmt_main(["client", "transition", *motion, "-o", str(out_http), *common]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frames"] == 20 and summary["out"] == str(out_http)
    assert rsmt_main(["client", "stream", *motion, "--binary", "--pace", "asap", "-o", str(out_ws), *common]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [m["seq"] for m in lines if m["type"] == "frame"] == list(range(20))
    assert lines[-1]["type"] == "end" and lines[-1]["reason"] == "arrived" and lines[-1]["encoding"] == "binary"
    a, b = load_clip(out_http), load_clip(out_ws)
    assert a.num_frames == b.num_frames == 20
    np.testing.assert_allclose(a.root_positions.numpy(), b.root_positions.numpy(), atol=1e-3)
    assert _rot_close(a.rotations.numpy(), b.rotations.numpy(), atol=1e-3)


def test_cli_commands(server, motions, tmp_path, capsys):
    common = ["--url", server.url, "--api-key", API_KEY]
    added = _check_cli_styles(common, motions, capsys)
    motion = ["--context", str(motions["context"]), "--target", str(motions["target"]), "--frames", "20",
              "--style", added["style_id"], "--seed", "5", "--deterministic"]
    _check_cli_http_matches_stream(common, motion, tmp_path, capsys)

    # A style clip path works in place of an id; errors print the server's code and exit 1.
    assert rsmt_main(["client", "transition", *motion[:6], "--style", str(motions["style2"]), *common]) == 0
    assert len(json.loads(capsys.readouterr().out)["root_positions"]) == 20
    # Streamed, a style clip path is registered over HTTP first: inline, a 120-frame clip is more than
    # a WebSocket message may carry (the server closes with 1009).
    assert rsmt_main(["client", "stream", *motion[:6], "--style", str(motions["style"]), "--quiet", *common]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 20
    assert rsmt_main(["client", "transition", *motion[:6], "--style", "sty_missing", *common]) == 1
    assert "unknown_style" in capsys.readouterr().err
    assert rsmt_main(["client", "styles", "add", str(tmp_path / "missing.bvh"), *common]) == 2


def test_cli_console_script(server):
    """The installed ``rsmt`` entry point runs the client group too."""
    proc = subprocess.run([sys.executable, "-m", "rsmt_cli.main", "client", "styles", "list", "--url", server.url,
                           "--api-key", API_KEY], capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("style_id")
