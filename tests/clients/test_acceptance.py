"""Acceptance of issue 6: one transition (same seed, deterministic) requested through the Python client, the
Unity core's C# harness and the Unreal core's C++ program decodes to the same poses within 1e-4 once each
engine's coordinate conversion is inverted."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rsmt_client import Client, StreamClient

from tests.clients.helpers import (
    API_KEY,
    FRAMES,
    SEED,
    capture,
    json_lines,
    run,
    run_harness,
    unity_to_model,
    unreal_to_model,
)

pytestmark = pytest.mark.timeout(600)
TOLERANCE = 1e-4


def test_three_clients_agree(server, motions, harness_exe, core_test_exe, tmp_path, record_property):
    poses: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    # Python: HTTP and the WebSocket stream (binary), model axes as they come.
    with Client(server.url, api_key=API_KEY) as c:
        style_id = c.register_style(motions["style"], name="walk")["style_id"]
        http = c.transition(motions["context"], motions["target"], FRAMES, style_id=style_id, seed=SEED,
                            deterministic=True)
    poses["python-http"] = (http.root_positions.astype(np.float64), http.rotations.astype(np.float64))
    with StreamClient(server.url, api_key=API_KEY, encoding="binary") as s:
        ws = s.transition(motions["context"], motions["target"], FRAMES, style_id=style_id, seed=SEED,
                          deterministic=True)
    poses["python-stream"] = (ws.root_positions.astype(np.float64), ws.rotations.astype(np.float64))

    # C# (Unity core): its own style registration and stream; Unity axes and metres, inverted.
    for encoding in ("binary", "json"):
        out = tmp_path / f"unity-{encoding}.json"
        proc = run_harness(harness_exe, "run", "--url", server.url, "--api-key", API_KEY, "--context",
                           str(motions["context"]), "--target", str(motions["target"]), "--style", str(motions["style"]),
                           "--frames", str(FRAMES), "--seed", str(SEED), "--deterministic", "--encoding", encoding,
                           "--out", str(out))
        assert proc.returncode == 0, proc.stderr[-3000:]
        r = json.loads(out.read_text())
        assert r["style_id"] == style_id
        poses[f"unity-{encoding}"] = unity_to_model(np.array([f["root"] for f in r["frames"]]),
                                                    np.array([f["rotations"] for f in r["frames"]]),
                                                    r["hello"]["metres_per_unit"])

    # C++ (Unreal core): sessions captured from the server, replayed in OnRawMessage-sized pieces; Unreal axes, inverted.
    start = {"type": "start", "character": "ue", "context": {"bvh": motions["context"].read_text()},
             "target": {"bvh": motions["target"].read_text()}, "frames": FRAMES, "style_id": style_id, "seed": SEED,
             "deterministic": True, "pace": "asap"}
    for encoding in ("binary", "json"):
        rec = capture(server.ws, encoding, start, tmp_path / f"{encoding}.rec")
        frames = [m for m in json_lines(run([str(core_test_exe), "replay", str(rec), "13"], timeout=120).stdout)
                  if "frame" in m]
        poses[f"unreal-{encoding}"] = unreal_to_model(np.array([f["root"] for f in frames]),
                                                      np.array([f["rotations"] for f in frames]))

    ref_roots, ref_rots = poses["python-http"]
    worst = {}
    for name, (roots, rots) in poses.items():
        assert roots.shape == (FRAMES, 3) and rots.shape == (FRAMES, 21, 4), name
        worst[name] = max(float(np.abs(roots - ref_roots).max()), float(np.abs(rots - ref_rots).max()))
    names = list(poses)
    pairwise = max(max(float(np.abs(poses[a][0] - poses[b][0]).max()), float(np.abs(poses[a][1] - poses[b][1]).max()))
                   for i, a in enumerate(names) for b in names[i + 1:])
    record_property("max_abs_difference", pairwise)
    print(f"\nacceptance: max abs difference across {len(names)} decodings: {pairwise:.3g} "
          f"(per client vs python-http: {json.dumps({k: float(f'{v:.3g}') for k, v in worst.items()})})")
    assert pairwise <= TOLERANCE, worst
