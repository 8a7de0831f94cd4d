"""The viewer's page and helper endpoints over HTTP (no browser): what is served, offline, and the takes it reads."""

from __future__ import annotations

import asyncio
import re

import httpx
import numpy as np
import pytest
import torch

from model.data.synthetic import synthetic_skeleton, synthetic_walk
from model.motion.bvh_clip import dump_clip
from service.app import create_app
from service.settings import Settings
from service.viewer.page import STATIC_DIR

STATIC_FILES = sorted(p for p in STATIC_DIR.rglob("*") if p.is_file())


def test_viewer_redirects_to_its_page_and_serves_every_module(viewer_server) -> None:
    r = httpx.get(viewer_server.url + "/viewer")
    assert r.status_code == 307 and r.headers["location"].endswith("/viewer/")
    page = httpx.get(viewer_server.url + "/viewer/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert 'src="js/main.js"' in page.text and 'href="viewer.css"' in page.text
    assert page.headers["cache-control"] == "no-cache"  # revalidated: never a mix of old and new modules
    # Every module imported anywhere is served, as JavaScript (browsers refuse modules of another type).
    modules = {"main.js"}
    for path in STATIC_DIR.glob("js/*.js"):
        modules |= set(re.findall(r'from "\./([\w-]+\.js)"', path.read_text()))
    for name in sorted(modules):
        r = httpx.get(f"{viewer_server.url}/viewer/js/{name}")
        assert r.status_code == 200, name
        assert "javascript" in r.headers["content-type"], (name, r.headers["content-type"])
    missing = httpx.get(viewer_server.url + "/viewer/js/nothing.js")
    assert missing.status_code == 404 and missing.json()["error"]["code"] == "not_found"


def test_the_page_needs_nothing_from_outside() -> None:
    # Offline: no CDN, no web fonts, no absolute URL of any host in what the page loads.
    assert {p.name for p in STATIC_FILES} >= {"index.html", "viewer.css", "main.js", "math.js", "renderer.js", "transport.js"}
    for path in STATIC_FILES:
        text = re.sub(r'xmlns(:\w+)?="http://www\.w3\.org/[^"]*"', "", path.read_text())  # a namespace name, never fetched
        assert not re.search(r"(https?:)?//[a-z0-9.-]+\.[a-z]{2,}", text, re.IGNORECASE), path
        if path.suffix == ".css":
            assert "@import" not in text and "url(" not in text, path


def test_rig_roles_and_demos_on_the_models_skeleton(viewer_server) -> None:
    model = httpx.get(viewer_server.url + "/v1/model").json()
    joints = len(model["skeleton"]["joints"])
    rig = httpx.get(viewer_server.url + "/v1/viewer/rig").json()
    sk = synthetic_skeleton()
    assert rig["roles"]["left_hip"] == sk.index("UpperLeg_L") and rig["roles"]["right_shoulder"] == sk.index("UpperArm_R")
    assert len(rig["roles"]["mirror"]) == joints
    demos = httpx.get(viewer_server.url + "/v1/viewer/demos").json()["demos"]
    kinds = {d["kind"] for d in demos}
    assert kinds == {"take", "style"}
    for d in demos:
        clip = httpx.get(f"{viewer_server.url}/v1/viewer/demos/{d['name']}").json()
        rot = np.asarray(clip["rotations"])
        assert clip["fps"] == model["fps"] and rot.shape == (clip["frames"], joints, 4)
        assert np.allclose(np.linalg.norm(rot, axis=-1), 1.0, atol=1e-5)
        if d["kind"] == "style":
            assert model["style_clip_frames"]["min"] <= clip["frames"] <= model["style_clip_frames"]["max"]
    r = httpx.get(viewer_server.url + "/v1/viewer/demos/no-such-demo")
    assert r.status_code == 404 and "walk" in r.json()["error"]["message"]
    assert httpx.get(viewer_server.url + "/v1/viewer/demos?model=nope").status_code == 404


def test_demos_of_a_model_with_builtin_styles_are_generated_by_it_and_others_have_none(tmp_path) -> None:
    # In process with the lifespan run: a bundle with a built-in style (its code only), and one on a rig that is
    # not the synthetic one. The styled model's takes are its own walks from a standing pose along three paths.
    from fastapi.testclient import TestClient

    from model.inference.bundle import Bundle
    from model.inference.bundle_styles import StyleClip
    from model.inference.style_packing import write_builtin_styles
    from model.motion.skeleton import Skeleton
    from service.viewer.model_takes import TAKE_S, path_point

    sk = synthetic_skeleton()
    styled = Bundle.create(sk, seed=0)
    styled.meta.name = "styled"
    write_builtin_styles(styled.save(tmp_path / "styled"), [StyleClip("slow", synthetic_walk(45, speed_cm_s=60.0))])
    other = Skeleton.build(sk.names, sk.parents, [[2 * v for v in o] for o in sk.offsets], profile="bandai-namco")
    bare = Bundle.create(other, seed=0)
    bare.meta.name = "bare"
    bare.save(tmp_path / "bare")
    with TestClient(create_app(Settings(models=tmp_path, eager=True, warmup_max_batch=1))) as client:
        demos = client.get("/v1/viewer/demos?model=styled").json()["demos"]
        assert [(d["name"], d["kind"]) for d in demos] == [
            ("walk-slow", "take"), ("walk-slow-turn-left", "take"), ("walk-slow-turn-right", "take")]
        assert all("generated by the model from a standing pose" in d["description"] for d in demos)
        fps, ctx = styled.config.fps, styled.config.context
        walk_s = (round(TAKE_S * fps) - ctx) / fps
        ends = {}
        for d in demos:
            clip = client.get(f"/v1/viewer/demos/{d['name']}?model=styled").json()
            assert clip["frames"] == round(TAKE_S * fps) and clip["fps"] == fps
            rot, root = np.asarray(clip["rotations"]), np.asarray(clip["root_positions"])
            assert np.allclose(np.linalg.norm(rot, axis=-1), 1.0, atol=1e-5)
            # Standing still over the origin for the context, then (exact arrival) on the path's end.
            assert np.allclose(root[:ctx, [0, 2]], 0.0, atol=1e-4) and np.allclose(rot[:ctx], rot[0], atol=1e-6)
            ends[d["name"]] = root[-1, [0, 2]]
        for name, turn in (("walk-slow", 0.0), ("walk-slow-turn-left", 90.0), ("walk-slow-turn-right", -90.0)):
            x, z, _ = path_point(walk_s, walk_s, turn)
            assert np.allclose(ends[name], [x, z], atol=0.5), (name, ends[name], (x, z))
        assert ends["walk-slow-turn-left"][0] > 100 > 0 > -100 > ends["walk-slow-turn-right"][0]
        # The same take on a second request.
        again = client.get("/v1/viewer/demos/walk-slow-turn-left?model=styled").json()
        assert np.allclose(again["root_positions"][-1], [ends["walk-slow-turn-left"][0], again["root_positions"][-1][1],
                                                          ends["walk-slow-turn-left"][1]])
        assert client.get("/v1/viewer/demos?model=bare").json()["demos"] == []
        r = client.get("/v1/viewer/demos/walk?model=bare")
        assert r.status_code == 404 and "upload a BVH take" in r.json()["error"]["message"]


def test_a_demo_take_and_style_drive_the_contract_endpoints_as_the_viewer_does(viewer_server) -> None:
    url = viewer_server.url
    ctx = httpx.get(url + "/v1/model").json()["context_frames"]
    take = httpx.get(url + "/v1/viewer/demos/walk-turn-left").json()
    style = httpx.get(url + "/v1/viewer/demos/style-slow").json()
    motion = {k: style[k] for k in ("root_positions", "rotations")}
    reg = httpx.post(url + "/v1/styles", json={"name": "style-slow", "motion": motion})
    assert reg.status_code == 201, reg.text
    c, n = 60, 30

    def poses(a: int, b: int) -> dict:
        return {"root_positions": take["root_positions"][a:b], "rotations": take["rotations"][a:b]}

    body = {"context": poses(c - ctx + 1, c + 1), "target": poses(c + n - 1, c + n + 1), "frames": n,
            "style_id": reg.json()["style_id"], "seed": 5}
    r = httpx.post(url + "/v1/transition", json=body, timeout=60)
    assert r.status_code == 200, r.text
    assert len(r.json()["frames"]) == n
    exported = httpx.post(url + "/v1/transition", json={**body, "output": "bvh"}, timeout=60).json()["bvh"]
    assert f"Frames: {n}\n" in exported


def test_an_uploaded_take_is_read_onto_the_models_rig_and_fps(viewer_server) -> None:
    # 60 fps and XYZ channel order: the server's reader makes it the model's 30 fps, local x,y,z,w quaternions.
    walk60 = synthetic_walk(61, fps=60.0, turn_deg_s=20.0)
    bvh = dump_clip(walk60, rotation_order="XYZ")
    r = httpx.post(viewer_server.url + "/v1/viewer/clip", json={"name": "turn.bvh", "motion": {"bvh": bvh}})
    assert r.status_code == 200, r.text
    clip = r.json()
    assert clip["name"] == "turn.bvh" and clip["fps"] == 30.0 and clip["frames"] == 31
    # Every other frame of the 60 fps take, exactly where the clocks meet.
    assert np.allclose(clip["root_positions"], walk60.root_positions[::2].numpy(), atol=1e-3)
    dots = (torch.tensor(clip["rotations"]) * walk60.rotations[::2]).sum(-1).abs()  # q and -q are one rotation
    assert torch.all(dots > 1 - 1e-4)


@pytest.mark.parametrize(("bvh", "code", "words"), [
    ("HIERARCHY\nROOT Hips\n{\n\tOFFSET 0 0 zero\n", "bad_motion", "line 4"),
    (dump_clip(synthetic_walk(5)).replace("Toes_L", "Toe_Left"), "skeleton_mismatch", "Toes_L"),
])
def test_an_unusable_upload_is_refused_with_the_reason(viewer_server, bvh: str, code: str, words: str) -> None:
    r = httpx.post(viewer_server.url + "/v1/viewer/clip", json={"motion": {"bvh": bvh}})
    assert r.status_code == 422
    err = r.json()["error"]
    assert err["code"] == code and words in err["message"], err


def test_with_api_keys_the_page_is_public_and_the_helpers_are_not(viewer_bundle) -> None:
    # In process, lifespan not run: no model is loaded, which the static page never needs; the demo list (the
    # model's own takes) answers not_ready once the key is accepted.
    key = "k" * 24
    app = create_app(Settings(models=viewer_bundle, api_keys=[key]))

    async def probe() -> list[int]:
        async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://viewer") as client:
            return [(await client.get(path, headers=headers)).status_code for path, headers in (
                ("/viewer/", {}), ("/viewer/js/transport.js", {}), ("/v1/viewer/demos", {}),
                ("/v1/viewer/demos", {"X-API-Key": key}))]

    assert asyncio.run(probe()) == [200, 200, 401, 503]
