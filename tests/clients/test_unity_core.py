"""The Unity package's engine-independent core, compiled with Mono's ``mcs``: unit checks (JSON, coordinate
conversion against known values, binary frames with any layout, jitter buffer, joint binding), a type check
of the MonoBehaviour and asset code against UnityEngine stubs, and a console harness against a live server
(hello, style registration over HTTP, start, frames, retarget, a start to a place and facing, ping). Skipped
with a reason without Mono."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from rsmt_client import Client

from model.motion.bvh_clip import load_clip
from model.motion.skeleton import Skeleton
from tests.clients.arrival import miss, place_from
from tests.clients.helpers import API_KEY, FRAMES, SEED, UNITY, json_lines, mono_tools, run, run_harness, unity_to_model

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]  # slow: compiles with Mono's mcs


def test_core_selftest(harness_exe):
    proc = run_harness(harness_exe, "selftest")
    assert proc.returncode == 0, proc.stderr
    summary = json_lines(proc.stdout)[-1]["selftest"]
    assert summary["failures"] == 0 and summary["checks"] > 500


def test_monobehaviour_and_asset_code_type_check(tmp_path):
    """Runtime/Unity, the .bvh importer (Editor) and the samples compile against stand-ins of the UnityEngine,
    UnityEditor and Inference Engine types they use."""
    mcs, _ = mono_tools()
    stubs = UNITY.parents[1] / "tests" / "clients" / "unity_stubs"
    sources = sorted(str(p) for p in (UNITY / "Runtime").rglob("*.cs")) + \
        sorted(str(p) for p in (UNITY / "Editor").rglob("*.cs")) + \
        sorted(str(p) for p in (UNITY / "Samples~").rglob("*.cs")) + [str(p) for p in sorted(stubs.glob("*.cs"))]
    run([mcs, "-nologo", "-target:library", "-warnaserror", "-r:System.Net.Http.dll", f"-out:{tmp_path / 'u.dll'}",
         *sources], timeout=300)
    # The core's assembly definition keeps UnityEngine out; the runtime one references the core.
    core = json.loads((UNITY / "Runtime" / "Core" / "Rsmt.Link.Core.asmdef").read_text())
    runtime = json.loads((UNITY / "Runtime" / "Rsmt.Link.asmdef").read_text())
    assert core["noEngineReferences"] is True and runtime["references"] == ["Rsmt.Link.Core"]
    assert all("using UnityEngine" not in p.read_text() for p in (UNITY / "Runtime" / "Core").glob("*.cs"))
    package = json.loads((UNITY / "package.json").read_text())
    assert package["name"] == "com.rsmt.link" and package["samples"][0]["path"] == "Samples~/BasicTransition"
    # Importing the rig asset (glTF) needs glTFast; the .bvh importer runs in the editor only.
    assert package["dependencies"]["com.unity.cloud.gltfast"]
    editor = json.loads((UNITY / "Editor" / "Rsmt.Link.Editor.asmdef").read_text())
    assert editor["includePlatforms"] == ["Editor"]
    assert '[ScriptedImporter(1, "bvh")]' in (UNITY / "Editor" / "RsmtBvhImporter.cs").read_text()


@pytest.mark.parametrize("encoding", ["json", "binary"])
def test_harness_against_live_server(harness_exe, server, client_bundle, motions, tmp_path, encoding):
    out = tmp_path / "result.json"
    # target_at: 1 m ahead of where the context ends and 40 cm to its left, turned 30 degrees (model units, axes).
    skeleton = Skeleton.load(client_bundle / "skeleton.json")
    context = load_clip(motions["context"], dtype=torch.float64)
    place = place_from(skeleton, context.root_positions.numpy(), context.rotations.numpy(), 100.0, 40.0, 30.0)
    proc = run_harness(harness_exe, "run", "--url", server.url, "--api-key", API_KEY, "--context", str(motions["context"]),
                       "--target", str(motions["target"]), "--style", str(motions["style"]), "--style2",
                       str(motions["style2"]), "--frames", str(FRAMES), "--seed", str(SEED), "--deterministic",
                       "--encoding", encoding, "--retarget", str(motions["target2"]),
                       "--retarget-after", "4", "--retarget-frames", "12",
                       "--target-at", f"{place.x!r},{place.z!r},{place.yaw!r}", "--target-at-frames", str(FRAMES),
                       "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-3000:]
    r = json.loads(out.read_text())
    assert r["hello"] == {"joints": 21, "fps": 30, "units": "cm", "encoding": encoding, "metres_per_unit": 0.01}
    with Client(server.url, api_key=API_KEY) as c:
        assert r["style_id"] == c.register_style(motions["style"])["style_id"]  # same clip, same content hash
        two = c.register_style_clips([motions["style2"], motions["style"]])  # the harness's two clips, another order
        assert r["multi"] == {"style_id": two["style_id"], "clips": 2, "frames": two["frames"]}
        http = c.transition(motions["context"], motions["target"], FRAMES, style_id=r["style_id"], seed=SEED,
                            deterministic=True)
    frames = r["frames"]
    assert [f["seq"] for f in frames] == list(range(FRAMES)) and r["end"] == {"reason": "arrived", "frames": FRAMES}
    assert r["pong"] is True and r["started"]["frames"] == FRAMES
    # Unity axes and metres: x mirrored, /100; the inverse gives back the model's poses.
    roots = np.array([f["root"] for f in frames])
    rots = np.array([f["rotations"] for f in frames])
    np.testing.assert_allclose(roots[:, 0], -http.root_positions[:, 0] / 100.0, atol=1e-6)
    np.testing.assert_allclose(roots[:, 1:], http.root_positions[:, 1:] / 100.0, atol=1e-6)
    m_roots, m_rots = unity_to_model(roots, rots, r["hello"]["metres_per_unit"])
    np.testing.assert_allclose(m_roots, http.root_positions, atol=1e-4)
    np.testing.assert_allclose(m_rots, http.rotations, atol=1e-4)
    # Retarget mid-way: frames from `from_seq` on follow the new length; the jitter buffer played them in order.
    rt = r["retarget"]
    assert rt["from_seq"] > 4 and rt["end_frames"] == rt["from_seq"] + 12 == rt["received"] and rt["reason"] == "arrived"
    assert rt["monotonic"] is True and rt["shown_last"] == rt["received"] - 1 and rt["samples"] > rt["received"]
    # The start to a place and facing arrives there: the last frame, back in the model's axes, as the model measures it.
    placed = r["target_at"]
    assert placed["received"] == FRAMES and placed["end"] == {"reason": "arrived", "frames": FRAMES}
    last_root, last_rots = unity_to_model(np.array([placed["last"]["root"]]), np.array([placed["last"]["rotations"]]),
                                          r["hello"]["metres_per_unit"])
    distance, turn = miss(skeleton, place, last_root, last_rots)
    print(f"unity target_at {place} ({encoding}): {distance:.3f} cm, {turn:.3f} degrees off")
    assert placed["last"]["seq"] == FRAMES - 1 and distance <= 8.0 and turn <= 10.0
