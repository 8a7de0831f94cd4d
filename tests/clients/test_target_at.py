"""``target_at``: a transition asked to arrive at a place and facing, through a real server of the default model and
the Python client (``Client.transition``, a stream's ``start``, ``rsmt client transition --target-at``), arrives
within 8 cm of the place and 10 degrees of the facing asked. The poses come from the model's own demo walk."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import httpx
import numpy as np
import pytest
import torch
from rsmt_client import Client, StreamClient, TargetAt

from model.inference.bundle import DEFAULT_BUNDLE
from model.motion.bvh_clip import load_clip
from model.motion.skeleton import Skeleton
from tests.clients.arrival import miss, place_from

pytestmark = pytest.mark.slow  # a server of the default model
PLACE_CM, FACING_DEG = 8.0, 10.0
# (along the current facing, to its left, turn) from where the context ends: cm, cm, degrees.
CASES = [(250.0, 0.0, 0.0), (220.0, 120.0, 45.0), (200.0, -150.0, -60.0), (0.0, 200.0, 90.0), (150.0, 0.0, 180.0)]


@pytest.fixture(scope="module")
def walk(default_model_eager_server) -> dict:
    with Client(default_model_eager_server.url) as c:
        demo = c.demo("walk-normal")
    return {"root_positions": demo.root_positions[100:110].tolist(), "rotations": demo.rotations[100:110].tolist(),
            "fps": demo.fps}


@pytest.fixture(scope="module")
def skeleton() -> Skeleton:
    return Skeleton.load(DEFAULT_BUNDLE / "skeleton.json")


def places(skeleton: Skeleton, walk: dict) -> list[TargetAt]:
    """The cases as places in the world, from the context's last root and facing."""
    roots, rotations = np.asarray(walk["root_positions"][-1:]), np.asarray(walk["rotations"][-1:])
    return [place_from(skeleton, roots, rotations, ahead, side, turn) for ahead, side, turn in CASES]


def test_a_transition_arrives_at_the_place_and_facing_asked(default_model_eager_server, walk, skeleton):
    url = default_model_eager_server.url
    with Client(url) as c:
        for place in places(skeleton, walk):
            poses = c.transition(walk, place, 60, style_id="builtin:normal", seed=3)
            assert poses.num_frames == 60
            distance, turn = miss(skeleton, place, poses.root_positions, poses.rotations)
            print(f"target_at {place}: {distance:.2f} cm, {turn:.2f} degrees off")
            assert distance <= PLACE_CM and turn <= FACING_DEG
        place = places(skeleton, walk)[2]
        body = {"context": walk, "target_at": place.payload(), "frames": 60, "style_id": "builtin:normal", "seed": 3,
                "exact_arrival": False}
    with httpx.Client(base_url=url, timeout=120) as http:
        frames = http.post("/v1/transition", json=body).raise_for_status().json()["frames"]
    # Told not to bend its arrival, the network's own (a figure, not a bound).
    roots = np.array([f["root_position"] for f in frames])
    rotations = np.array([f["rotations"] for f in frames])
    distance, turn = miss(skeleton, place, roots, rotations)
    print(f"target_at {place}, exact_arrival false: {distance:.2f} cm, {turn:.2f} degrees off")
    assert len(frames) == 60


def test_a_stream_start_arrives_at_the_place_and_facing_asked(default_model_eager_server, walk, skeleton):
    place = places(skeleton, walk)[1]
    with StreamClient(default_model_eager_server.url) as s:
        character = s.start(walk, place, 45, style_id="builtin:normal", seed=5, pace="asap")
        result = s.collect(character, timeout=120)
    poses = result.poses(s.joint_names)
    assert poses.num_frames == 45 and (result.end or {}).get("reason") == "arrived"
    distance, turn = miss(skeleton, place, poses.root_positions, poses.rotations)
    print(f"stream target_at {place}: {distance:.2f} cm, {turn:.2f} degrees off")
    assert distance <= PLACE_CM and turn <= FACING_DEG


def test_the_cli_takes_a_place_and_facing(default_model_eager_server, walk, skeleton, tmp_path: Path):
    place = places(skeleton, walk)[2]
    with Client(default_model_eager_server.url) as c:
        context = tmp_path / "context.bvh"
        c.demo("walk-normal").save_bvh(context, c.model())
    # The demo as BVH, cut to the same frames: the CLI sends the file's last context_frames frames.
    lines = context.read_text().split("\n")
    motion = lines.index("MOTION")
    frames = [ln for ln in lines[motion + 3:] if ln.strip()][:110]
    context.write_text("\n".join(lines[:motion + 1] + [f"Frames: {len(frames)}", lines[motion + 2], *frames]) + "\n")
    out = tmp_path / "out.bvh"
    proc = subprocess.run([sys.executable, "-m", "rsmt_cli.main", "client", "transition", "--url",
                           default_model_eager_server.url, "--context", str(context),
                           f"--target-at={place.x},{place.z},{place.yaw}", "--frames", "50", "--style",
                           "builtin:normal", "--seed", "2", "-o", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout.strip().splitlines()[-1])["frames"] == 50
    clip = load_clip(out, dtype=torch.float64)
    distance, turn = miss(skeleton, place, clip.root_positions.numpy(), clip.rotations.numpy())
    print(f"cli target_at {place}: {distance:.2f} cm, {turn:.2f} degrees off")
    assert distance <= PLACE_CM and turn <= FACING_DEG


def test_a_target_and_a_place_together_or_neither_are_refused(default_model_eager_server, walk):
    body = {"context": walk, "frames": 30, "style_id": "builtin:normal"}
    with httpx.Client(base_url=default_model_eager_server.url, timeout=60) as http:
        for extra in ({}, {"target": walk, "target_at": {"x": 0.0, "z": 100.0, "yaw": 0.0}}):
            r = http.post("/v1/transition", json={**body, **extra})
            assert r.status_code == 422, r.text
            assert "give exactly one of target" in r.json()["error"]["message"] and "target_at" in r.json()["error"]["message"]
        r = http.post("/v1/transition", json={**body, "target_at": {"x": 0.0, "z": 100.0, "yaw": 720.0}})
        assert r.status_code == 422 and "yaw" in r.json()["error"]["message"], r.text
