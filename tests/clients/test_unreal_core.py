"""The Unreal plugin's engine-independent core (``Source/RsmtCore``), compiled with g++ as Unreal would (no
exceptions, no RTTI, warnings as errors): unit checks, then sessions captured from a live server (hello +
frames, JSON and binary; a start the core built to a place and facing) replayed in pieces the way
``IWebSocket::OnRawMessage`` delivers them."""

from __future__ import annotations

import json

import httpx
import numpy as np
import pytest
import torch
from rsmt_client import Client
from rsmt_client.stream import FrameLayout

from model.motion.bvh_clip import load_clip
from model.motion.skeleton import Skeleton
from tests.clients.arrival import miss, place_from
from tests.clients.helpers import (
    API_KEY,
    FRAMES,
    SEED,
    UNREAL,
    capture,
    json_lines,
    read_capture,
    run,
    unreal_to_model,
)

pytestmark = pytest.mark.timeout(600)


def test_core_selftest(core_test_exe):
    proc = run([str(core_test_exe), "selftest"], timeout=120)
    summary = json_lines(proc.stdout)[-1]["selftest"]
    assert summary["failures"] == 0 and summary["checks"] > 500


def test_plugin_layout():
    plugin = json.loads((UNREAL / "RsmtLink.uplugin").read_text())
    assert {m["Name"] for m in plugin["Modules"]} == {"RsmtCore", "RsmtLink"}
    assert {"Name": "LiveLink", "Enabled": True} in plugin["Plugins"]
    build = (UNREAL / "Source" / "RsmtLink" / "RsmtLink.Build.cs").read_text()
    assert all(m in build for m in ('"WebSockets"', '"LiveLinkInterface"', '"RsmtCore"', '"HTTP"'))
    # The core stays free of Unreal: only the module entry point includes an engine header.
    for path in (UNREAL / "Source" / "RsmtCore").rglob("*.[ch]*"):
        if path.name in ("RsmtCoreModule.cpp", "RsmtCore.Build.cs"):
            continue
        text = path.read_text()
        assert "CoreMinimal" not in text and "FString" not in text and "#include \"Modules" not in text, path


@pytest.fixture(scope="module")
def captures(server, motions, tmp_path_factory) -> dict[str, object]:
    d = tmp_path_factory.mktemp("captures")
    with Client(server.url, api_key=API_KEY) as c:
        style_id = c.register_style(motions["style"])["style_id"]
        http = c.transition(motions["context"], motions["target"], FRAMES, style_id=style_id, seed=SEED,
                            deterministic=True)
    start = {"type": "start", "character": "ue", "context": {"bvh": motions["context"].read_text()},
             "target": {"bvh": motions["target"].read_text()}, "frames": FRAMES, "style_id": style_id, "seed": SEED,
             "deterministic": True, "pace": "asap"}
    out: dict[str, object] = {"http": http}
    for encoding in ("json", "binary"):
        out[encoding] = capture(server.ws, encoding, start, d / f"{encoding}.rec")
    return out


def _python_decode(path) -> tuple[np.ndarray, np.ndarray]:
    """The same capture decoded by the Python client's code (layout from hello)."""
    records = read_capture(path)
    hello = json.loads(records[0][1])
    layout = FrameLayout(hello["frame_layout"], len(hello["model"]["skeleton"]["joints"]))
    roots, rots = [], []
    for kind, payload in records[1:]:
        if kind == "B":
            f = layout.decode(payload)
            roots.append(f.root_position)
            rots.append(f.rotations)
        else:
            msg = json.loads(payload)
            if msg["type"] == "frame":
                roots.append(msg["pose"]["root_position"])
                rots.append(msg["pose"]["rotations"])
    return np.array(roots, np.float64), np.array(rots, np.float64)


@pytest.mark.parametrize("encoding", ["json", "binary"])
@pytest.mark.parametrize("chunk", [7, 4096])
def test_replay_captured_session(core_test_exe, captures, encoding, chunk):
    proc = run([str(core_test_exe), "replay", str(captures[encoding]), str(chunk)], timeout=120)
    lines = json_lines(proc.stdout)
    frames = [m for m in lines if "frame" in m]
    events = [m["event"] for m in lines if "event" in m]
    summary = lines[-1]["summary"]
    assert summary["frames"] == FRAMES and summary["joints"] == 21
    assert summary["binary"] == (FRAMES if encoding == "binary" else 0)
    assert events == ["started", "end"]
    assert [f["seq"] for f in frames] == list(range(FRAMES)) and all(f["character"] == "ue" for f in frames)
    assert all(f["binary"] == (encoding == "binary") for f in frames)
    assert frames[-1]["remaining"] == 0 and frames[-1]["t"] == pytest.approx(FRAMES / 30.0, abs=1e-6)
    ue_roots = np.array([f["root"] for f in frames])
    ue_rots = np.array([f["rotations"] for f in frames])
    py_roots, py_rots = _python_decode(captures[encoding])
    # Unreal axes: (x, z, y) cm and (-x, -z, -y, w).
    np.testing.assert_allclose(ue_roots, py_roots[:, [0, 2, 1]], atol=1e-9)
    np.testing.assert_allclose(ue_rots, py_rots[..., [0, 2, 1, 3]] * [-1, -1, -1, 1], atol=1e-9)
    m_roots, m_rots = unreal_to_model(ue_roots, ue_rots)
    http = captures["http"]
    np.testing.assert_allclose(m_roots, http.root_positions, atol=1e-4)
    np.testing.assert_allclose(m_rots, http.rotations, atol=1e-4)


def test_style_registration_body_of_several_clips(core_test_exe, server, motions):
    """The core's POST /v1/styles body for two clips, sent to the server: one style of both, the id the Python
    client gets for the same clips in the other order."""
    proc = run([str(core_test_exe), "style-body", "ue-two", str(motions["style"]), str(motions["style2"])], timeout=60)
    r = httpx.post(server.url + "/v1/styles", content=proc.stdout.encode(), timeout=60,
                   headers={"Content-Type": "application/json", "X-API-Key": API_KEY})
    assert r.status_code == 201, r.text
    with Client(server.url, api_key=API_KEY) as c:
        two = c.register_style_clips([motions["style2"], motions["style"]])
    assert r.json()["style_id"] == two["style_id"] and r.json()["clips"] == 2 and r.json()["name"] == "ue-two"
    six = run([str(core_test_exe), "style-body", "six", *[str(motions["style"])] * 6], timeout=60, check=False)
    assert six.returncode == 1 and six.stdout == ""


@pytest.mark.parametrize("encoding", ["json", "binary"])
def test_a_start_to_a_place_and_facing_arrives_there(core_test_exe, server, client_bundle, motions, tmp_path, encoding):
    """The core's start (BuildStart with targetAtJson: 1 m ahead of where the context ends, 40 cm to its left, turned 30
    degrees) sent to the server; its frames, read by the core, end at the place and facing asked."""
    skeleton = Skeleton.load(client_bundle / "skeleton.json")
    context = load_clip(motions["context"], dtype=torch.float64)
    place = place_from(skeleton, context.root_positions.numpy(), context.rotations.numpy(), 100.0, 40.0, 30.0)
    with Client(server.url, api_key=API_KEY) as c:
        style_id = c.register_style(motions["style"])["style_id"]
    proc = run([str(core_test_exe), "start-at", "ue-at", str(motions["context"]), str(FRAMES), style_id, str(SEED),
                repr(place.x), repr(place.z), repr(place.yaw)], timeout=60)
    start = json.loads(proc.stdout)
    assert "target" not in start and start["pace"] == "asap"
    recording = capture(server.ws, encoding, start, tmp_path / f"target-at-{encoding}.rec")
    lines = json_lines(run([str(core_test_exe), "replay", str(recording), "4096"], timeout=120).stdout)
    frames = [m for m in lines if "frame" in m]
    assert [m["event"] for m in lines if "event" in m] == ["started", "end"]
    assert [f["seq"] for f in frames] == list(range(FRAMES)) and frames[-1]["remaining"] == 0
    roots, rotations = unreal_to_model(np.array([frames[-1]["root"]]), np.array([frames[-1]["rotations"]]))
    distance, turn = miss(skeleton, place, roots, rotations)
    print(f"unreal target_at {place} ({encoding}): {distance:.3f} cm, {turn:.3f} degrees off")
    assert distance <= 8.0 and turn <= 10.0
