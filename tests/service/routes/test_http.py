"""HTTP routes against a real uvicorn: health, models, styles, transitions, metrics, and every kind of bad input."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator

import httpx
import numpy as np
import pytest

from model.motion.bvh import BvhDocument, BvhJoint
from tests.service.conftest import (
    bvh,
    context_clip,
    poses,
    target_clip,
    transition_body,
    walk,
)


@pytest.fixture(scope="module")
def style_id(client) -> str:
    return client.post("/v1/styles", json={"name": "walk", "motion": bvh(walk(120))}).json()["style_id"]


def assert_error(r: httpx.Response, status: int, code: str, *words: str) -> dict:
    assert r.status_code == status, r.text
    body = r.json()
    assert set(body) == {"error"} and set(body["error"]) == {"code", "message"}, body
    assert body["error"]["code"] == code, body
    for w in words:
        assert w in body["error"]["message"], body
    return body


# ---------------------------------------------------------------------- health and models
def test_health(client):
    assert client.get("/v1/health/live").status_code == 200
    r = client.get("/v1/health/ready")
    assert r.status_code == 200 and r.json()["models"] == ["rsmt"]


def test_model_description(client):
    m = client.get("/v1/model").json()
    # max_transition_frames: twice the 60-frame training horizon.
    assert m["fps"] == 30 and m["context_frames"] == 10 and m["max_transition_frames"] == 120
    assert m["target_velocity_flag"] is False  # the test bundle predates the flag: one frame means "at rest"
    assert m["style_clip_frames"] == {"min": 16, "max": 240}
    sk = m["skeleton"]
    assert len(sk["joints"]) == 21 and sk["joints"][0] == {"name": "Hips", "parent": -1, "offset": [0.0, 0.0, 0.0]}
    assert (sk["units"], sk["up_axis"], sk["handedness"]) == ("cm", "y", "right")
    assert {"name", "version", "training_data", "license"} <= set(m)
    listing = client.get("/v1/models").json()
    assert listing["default"] == "rsmt" and listing["models"] == [m]
    assert client.get("/v1/models/rsmt").json() == m
    assert_error(client.get("/v1/models/nope"), 404, "unknown_model", "rsmt")


def test_openapi_and_docs(client):
    schema = client.get("/openapi.json").json()
    for path in ("/v1/styles", "/v1/transition", "/v1/model", "/v1/health/ready", "/metrics"):
        assert path in schema["paths"]
    assert client.get("/docs").status_code == 200


# ---------------------------------------------------------------------- styles
def test_style_from_bvh_and_json_poses_share_an_id(client):
    clip = walk(90, turn_deg_s=20.0)
    a = client.post("/v1/styles", json={"name": "turn", "motion": bvh(clip)})
    assert a.status_code == 201, a.text
    a = a.json()
    assert a["style_id"].startswith("sty_") and a["frames"] == 90 and a["name"] == "turn"
    b = client.post("/v1/styles", json={"name": "turn", "motion": poses(clip)})
    assert b.status_code == 201 and b.json()["style_id"] == a["style_id"] and b.json()["cached"] is True
    # Joint columns in another order, mapped by name, are the same clip.
    order = list(reversed(range(21)))
    names = [client.get("/v1/model").json()["skeleton"]["joints"][j]["name"] for j in order]
    shuffled = {"root_positions": clip.root_positions.tolist(), "rotations": clip.rotations[:, order].tolist(),
                "joints": names}
    c = client.post("/v1/styles", json={"name": "turn", "motion": shuffled})
    assert c.status_code == 201 and c.json()["style_id"] == a["style_id"]


def test_style_list_get_delete(client):
    sid = client.post("/v1/styles", json={"name": "slow", "motion": bvh(walk(60, speed_cm_s=70.0))}).json()["style_id"]
    assert sid in [s["style_id"] for s in client.get("/v1/styles").json()["styles"]]
    one = client.get(f"/v1/styles/{sid}").json()
    assert one["style_id"] == sid and one["frames"] == 60
    assert client.delete(f"/v1/styles/{sid}").status_code == 204
    assert_error(client.get(f"/v1/styles/{sid}"), 404, "unknown_style")
    assert_error(client.delete(f"/v1/styles/{sid}"), 404, "unknown_style")


def test_style_length_limits(client):
    assert_error(client.post("/v1/styles", json={"name": "x", "motion": bvh(walk(10))}), 422, "too_few_frames", "16")
    assert_error(client.post("/v1/styles", json={"name": "x", "motion": bvh(walk(300))}), 422, "too_many_frames", "240")


# ---------------------------------------------------------------------- transitions
def test_transition_json(client, style_id):
    r = client.post("/v1/transition", json=transition_body(40, style_id=style_id))
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["fps"] == 30 and len(body["frames"]) == 40 and body["style_id"] == style_id
    frame = body["frames"][0]
    assert len(frame["root_position"]) == 3 and len(frame["rotations"]) == 21
    q = np.array([f["rotations"] for f in body["frames"]])
    assert np.allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-4)
    t = body["timing_ms"]
    assert t["total"] >= t["engine"] > 0 and math.isclose(t["per_frame"], t["engine"] / 40, rel_tol=1e-2)


def test_transition_bvh_has_exactly_n_frames(client, style_id):
    r = client.post("/v1/transition", json=transition_body(37, style_id=style_id, output="bvh"))
    assert r.status_code == 200, r.text
    doc = BvhDocument.parse(r.json()["bvh"])
    assert doc.num_frames == 37 and abs(doc.fps - 30) < 1e-6
    assert doc.names[0] == "Hips" and len(doc.names) == 21


def test_same_seed_same_frames(client, style_id):
    a = client.post("/v1/transition", json=transition_body(20, seed=11, style_id=style_id)).json()["frames"]
    b = client.post("/v1/transition", json=transition_body(20, seed=11, style_id=style_id)).json()["frames"]
    c = client.post("/v1/transition", json=transition_body(20, seed=12, style_id=style_id)).json()["frames"]
    assert a == b
    assert a != c
    d1 = client.post("/v1/transition", json=transition_body(20, seed=None, deterministic=True, style_id=style_id)).json()
    d2 = client.post("/v1/transition", json=transition_body(20, seed=5, deterministic=True, style_id=style_id)).json()
    assert d1["frames"] == d2["frames"]


def test_inline_style_and_json_poses(client):
    body = {"context": poses(context_clip()), "target": poses(target_clip()), "frames": 12, "seed": 1,
            "style": poses(walk(40)), "output": "json"}
    r = client.post("/v1/transition", json=body)
    assert r.status_code == 200, r.text
    assert len(r.json()["frames"]) == 12
    # BVH and JSON context give the same frames.
    body2 = {**body, "context": bvh(context_clip()), "target": bvh(target_clip()), "style": bvh(walk(40))}
    frames2 = client.post("/v1/transition", json=body2).json()["frames"]
    assert np.allclose(np.array([f["rotations"] for f in r.json()["frames"]]),
                       np.array([f["rotations"] for f in frames2]), atol=1e-4)


# ---------------------------------------------------------------------- bad input
Post = Callable[[object], httpx.Response]


def _check_bad_bvh(post: Post, ok: dict) -> None:
    """Malformed BVH names the line; a deep hierarchy is an error, not a crash; missing joints are named."""
    assert_error(post({**ok, "context": {"bvh": "HIERARCHY\nROOT Hips\n{\n OFFSET 0 0\n}"}}), 422, "bad_motion", "line 4")
    text = bvh(context_clip())["bvh"].splitlines()
    text[-1] = text[-1] + " 1.0"
    assert_error(post({**ok, "context": {"bvh": "\n".join(text)}}), 422, "bad_motion", "expected")
    assert_error(post({**ok, "context": {"bvh": "not a bvh"}}), 422, "bad_motion", "HIERARCHY")
    # Deeply nested hierarchy: an error, not a crash.
    deep = "HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\n" + "".join(f"JOINT j{i}\n{{\nOFFSET 0 0 0\n" for i in range(3000))
    assert post({**ok, "context": {"bvh": deep}}).status_code in (413, 422)
    # Missing joints are named.
    doc = BvhDocument.parse(bvh(context_clip())["bvh"])
    keep = [i for i, n in enumerate(doc.names) if n not in ("Hand_L",)]
    cols = [c for i in keep for c in range(doc.channel_slices()[i].start, doc.channel_slices()[i].stop)]
    joints = []
    for i in keep:
        j = doc.joints[i]
        parent = keep.index(j.parent) if j.parent >= 0 else -1
        joints.append(BvhJoint(j.name, parent, j.offset, j.channels, j.end_site))
    missing = BvhDocument(joints, doc.frame_time, doc.motion[:, cols]).format()
    assert_error(post({**ok, "context": {"bvh": missing}}), 422, "skeleton_mismatch", "Hand_L")


def _check_bad_poses(post: Post, ok: dict) -> None:
    """JSON poses: NaN, non-unit quaternions, wrong joint count, ragged, missing named joints."""
    p = poses(context_clip())
    nan = {**p, "rotations": [[list(q) for q in f] for f in p["rotations"]]}
    nan["rotations"][3][5][1] = float("nan")
    assert_error(post({**ok, "context": nan}), 422, "bad_motion", "frame 3", "joint 5")
    big = {**p, "rotations": [[list(q) for q in f] for f in p["rotations"]]}
    big["rotations"][7][2] = [0.0, 0.0, 0.0, 2.0]
    assert_error(post({**ok, "context": big}), 422, "bad_motion", "frame 7", "joint 2", "norm 2")
    inf_root = {**p, "root_positions": [list(r) for r in p["root_positions"]]}
    inf_root["root_positions"][1][0] = float("inf")
    assert_error(post({**ok, "context": inf_root}), 422, "bad_motion", "root_positions[1]")
    short = {**p, "rotations": [f[:20] for f in p["rotations"]]}
    assert_error(post({**ok, "context": short}), 422, "skeleton_mismatch", "21")
    ragged = {**p, "rotations": [f[:20] if i == 4 else f for i, f in enumerate(p["rotations"])]}
    assert_error(post({**ok, "context": ragged}), 422, "bad_motion", "rotations[4]")
    named = {**p, "rotations": [f[:20] for f in p["rotations"]], "joints": [f"j{i}" for i in range(20)]}
    assert_error(post({**ok, "context": named}), 422, "skeleton_mismatch", "Hips")
    assert_error(post({**ok, "context": {**p, "root_positions": p["root_positions"][:-1]}}), 422, "bad_motion")
    assert_error(post({**ok, "context": {**p, "root_positions": [[0, 0]] * 20}}), 422, "validation_error")


def _check_bad_bodies(client: httpx.Client) -> None:
    """Not JSON, not an object, too big (whole or chunked), and an unknown path."""
    bad = client.post("/v1/transition", content=b"{nope", headers={"content-type": "application/json"})
    assert_error(bad, 400, "invalid_json")
    assert_error(client.post("/v1/transition", json=[1, 2]), 422, "validation_error")
    huge = client.post("/v1/transition", content=b"[" + b"0," * (600 << 10) + b"0]",
                       headers={"content-type": "application/json"})
    assert_error(huge, 413, "payload_too_large")

    def chunks() -> Iterator[bytes]:
        for _ in range(40):
            yield b" " * (32 << 10)

    chunked = client.post("/v1/transition", content=chunks(), headers={"content-type": "application/json"})
    assert_error(chunked, 413, "payload_too_large")
    assert_error(client.get("/v1/nothing"), 404, "not_found")


def test_bad_requests(client, server, style_id):
    def post(body: object) -> httpx.Response:  # json.dumps writes NaN and Infinity, as some clients do
        return client.post("/v1/transition", content=json.dumps(body), headers={"content-type": "application/json"})

    ok = transition_body(10, style_id=style_id)
    assert post(ok).status_code == 200

    _check_bad_bvh(post, ok)
    _check_bad_poses(post, ok)

    # Frame counts.
    assert_error(post({**ok, "frames": 0}), 422, "validation_error", "frames")
    assert_error(post({**ok, "frames": 121}), 422, "too_many_frames", "120")
    assert_error(post({**ok, "context": bvh(context_clip().window(0, 5))}), 422, "too_few_frames", "10")
    slow = BvhDocument.parse(bvh(context_clip())["bvh"])
    slow.frame_time = 0.5  # 2 fps: 20 frames become 286 at 30 fps, within limits
    assert post({**ok, "context": {"bvh": slow.format()}}).status_code == 200
    slow.frame_time = 100.0  # 0.01 fps: refused before it is resampled
    assert_error(post({**ok, "context": {"bvh": slow.format()}}), 422, "bad_motion", "fps")

    # Styles and models.
    assert_error(post({**ok, "style_id": "sty_nope"}), 404, "unknown_style", "POST /v1/styles")
    assert_error(post({**ok, "model": "nope"}), 404, "unknown_model")
    both = {**ok, "style": bvh(walk(30))}
    assert_error(post(both), 422, "validation_error", "exactly one")
    assert_error(post({**ok, "seed": -1}), 422, "validation_error", "seed")
    assert_error(post({**ok, "output": "fbx"}), 422, "validation_error", "output")
    assert_error(post({**ok, "extra": 1}), 422, "validation_error", "extra")

    _check_bad_bodies(client)
    assert_error(client.put("/v1/transition", json={}), 405, "method_not_allowed")

    assert server.ready() == 200
    assert post(ok).status_code == 200


def test_metrics(client, style_id):
    client.post("/v1/transition", json=transition_body(5, style_id=style_id))
    client.get("/v1/styles/sty_nope")
    text = client.get("/metrics").text
    for series in ("rsmt_http_request_duration_seconds_bucket", 'route="/v1/styles/{style_id}"',
                   "rsmt_style_cache_hits_total", "rsmt_style_cache_entries", 'rsmt_errors_total{code="unknown_style"}',
                   "rsmt_transition_frames_total", "rsmt_live_streams", "rsmt_batch_size"):
        assert series in text, series
