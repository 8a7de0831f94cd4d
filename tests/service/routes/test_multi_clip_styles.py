"""A style from several clips through a real uvicorn (``POST /v1/styles`` with ``motions``), with the memory store
and with Redis: one id for 1-5 clips whatever their order, ``cached: true`` the second time, used by id in
``POST /v1/transition`` and in a WebSocket stream like any style, and the contract's errors for 0 or 6 clips,
a bad clip (named by its index) and clips on two rigs."""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import numpy as np
import pytest
import torch

from model.motion.clip import Clip
from model.motion.skeleton import Skeleton
from tests.service.conftest import bvh, context_clip, poses, target_clip, walk
from tests.service.server import Server, server_with_style_store
from tests.service.wsclient import Ws, poses_of, start_message


@pytest.fixture(scope="module", params=["memory", pytest.param("redis", marks=pytest.mark.slow)])
def server(request, bundle_dir) -> Iterator[Server]:
    with server_with_style_store(request.param, bundle_dir) as srv:
        yield srv


def _three() -> list[dict]:
    """Three clips of one style on the model's rig, two as BVH and one as JSON poses."""
    return [bvh(walk(60, cadence_hz=1.2)), poses(walk(90, turn_deg_s=25.0, cadence_hz=1.2)),
            bvh(walk(45, stride_deg=35.0, cadence_hz=1.2))]


def _register(server: Server, **body) -> httpx.Response:
    return httpx.post(server.url + "/v1/styles", json={"name": "brisk", **body}, timeout=60)


def _error(r: httpx.Response, status: int, code: str) -> str:
    assert r.status_code == status, r.text
    err = r.json()["error"]
    assert err["code"] == code and set(err) >= {"code", "message"}, r.text
    return err["message"]


def test_three_clips_one_id_whatever_the_order_then_cached(server):
    clips = _three()
    first = _register(server, motions=clips)
    assert first.status_code == 201, first.text
    info = first.json()
    assert info["clips"] == 3 and info["frames"] == 60 + 90 + 45 and info["cached"] is False and info["name"] == "brisk"
    again = _register(server, motions=[clips[2], clips[0], clips[1]])
    assert again.status_code == 201 and again.json()["style_id"] == info["style_id"] and again.json()["cached"] is True
    got = httpx.get(f"{server.url}/v1/styles/{info['style_id']}", timeout=30).json()
    assert (got["clips"], got["frames"]) == (3, 195)
    listed = httpx.get(server.url + "/v1/styles", timeout=30).json()["styles"]
    assert [s["clips"] for s in listed if s["style_id"] == info["style_id"]] == [3]
    # One clip in motions is that clip's style, the same as motion gives.
    one = _register(server, motions=[clips[0]]).json()
    single = _register(server, motion=clips[0]).json()
    assert one["style_id"] == single["style_id"] != info["style_id"] and one["clips"] == single["clips"] == 1
    assert _register(server, motions=clips[:2]).json()["style_id"] not in {info["style_id"], one["style_id"]}


def test_a_style_of_several_clips_in_a_transition_and_a_stream(server):
    sid = _register(server, motions=_three()).json()["style_id"]
    one = _register(server, motion=_three()[0]).json()["style_id"]
    body = {"context": bvh(context_clip()), "target": bvh(target_clip()), "frames": 30, "seed": 9}
    r = httpx.post(server.url + "/v1/transition", json={**body, "style_id": sid}, timeout=60)
    assert r.status_code == 200 and r.json()["style_id"] == sid, r.text
    http = r.json()["frames"]
    alone = httpx.post(server.url + "/v1/transition", json={**body, "style_id": one}, timeout=60).json()["frames"]
    assert not np.allclose(np.array([f["rotations"] for f in http]), np.array([f["rotations"] for f in alone]))
    with Ws(server.ws) as ws:
        ws.send(start_message("multi", 30, seed=9, style_id=sid))
        assert ws.recv()["type"] == "started"
        frames = ws.run({"multi"})["multi"]["frames"]
        ws.send(start_message("switch", 30, seed=9, style_id=one))
        ws.send({"type": "style", "character": "switch", "style_id": sid})  # a live character takes it too
        switched = ws.run({"switch"})["switch"]
    roots, rots = poses_of(frames)
    assert np.allclose(roots, np.array([f["root_position"] for f in http]), atol=1e-4)
    assert np.allclose(rots, np.array([f["rotations"] for f in http]), atol=1e-4)
    assert switched["end"]["reason"] == "arrived" and not any(m.get("type") == "error" for m in switched["messages"])


def test_clip_counts_and_bad_clips_are_refused(server):
    clips = _three()
    assert "motions" in _error(_register(server, motions=[]), 422, "validation_error")
    assert "motions" in _error(_register(server, motions=[clips[0]] * 6), 422, "validation_error")
    assert "exactly one of motion" in _error(_register(server, motion=clips[0], motions=clips), 422, "validation_error")
    assert "exactly one of motion" in _error(_register(server), 422, "validation_error")
    short = _error(_register(server, motions=[clips[0], bvh(walk(8)), clips[2]]), 422, "too_few_frames")
    assert short.startswith("motions[1]: ") and "16 to" in short
    long = _error(_register(server, motions=[clips[0], clips[1], bvh(walk(300))]), 422, "too_many_frames")
    assert long.startswith("motions[2]: ") and "--frames" in long
    broken = _error(_register(server, motions=[clips[0], {"bvh": "HIERARCHY\nnot a bvh"}]), 422, "bad_motion")
    assert broken.startswith("motions[1]")


def _with_a_prop(clip: Clip) -> Clip:
    """The clip on a rig with one more joint (a prop under the left hand): mappable onto the model's rig alone."""
    sk = clip.skeleton
    hand = sk.names.index("Hand_L")
    rig = Skeleton.build([*sk.names, "Prop"], [*sk.parents, hand], [*(list(o) for o in sk.offsets), [5.0, 0.0, 0.0]],
                         profile="bandai-namco")
    rot = torch.cat([clip.rotations, clip.rotations[:, :1] * 0 + torch.tensor([0.0, 0.0, 0.0, 1.0])], dim=1)
    return Clip(rig, rot, clip.root_positions, clip.fps)


def test_clips_on_two_rigs_are_refused(server):
    prop = bvh(_with_a_prop(walk(60)))
    assert _register(server, motion=prop).status_code == 201  # each rig maps onto the model's
    message = _error(_register(server, motions=[bvh(walk(60)), prop]), 422, "skeleton_mismatch")
    assert message.startswith("motions[1] is on another rig than motions[0]")
    assert _register(server, motions=[prop, prop]).status_code == 201
