"""Whole dataset takes as context, target and style, everywhere a short clip works: ``Client``, ``StreamClient``,
``rsmt client transition`` and ``rsmt client stream``, against a real server on the default model.

The clients cut a context to the frames the model reads, a target to its last two and a style clip to the
middle of the model's maximum (saying so once); the server, sent the uncut take, refuses it and names the
option that cuts it. Skipped with the reason when the motion data is absent.
"""

from __future__ import annotations

import json
import logging
import subprocess
import sys
from pathlib import Path

import httpx
import numpy as np
import pytest
from rsmt_client import Client, StreamClient
from rsmt_client.bvh import BvhFile
from rsmt_client.motion_cuts import Cutter, ModelLimits
from rsmt_client.stream_protocol import StreamSession

from model.inference.bundle import DEFAULT_BUNDLE
from tests.service.server import Server

pytestmark = [pytest.mark.real_data, pytest.mark.slow]
TAKES = {"context": "dataset-2_walk_normal_001.bvh", "target": "dataset-2_walk-turn-left_normal_001.bvh",
         "style": "dataset-2_walk_elderly_001.bvh"}
FRAMES = 40


@pytest.fixture(scope="module")
def takes(shared_data: Path) -> dict[str, Path]:
    folder = shared_data / "data" if (shared_data / "data").is_dir() else shared_data  # dataset 2 keeps its takes in data/
    paths = {k: folder / name for k, name in TAKES.items()}
    missing = [str(p) for p in paths.values() if not p.is_file()]
    if missing:
        pytest.skip(f"takes not in the motion data: {missing}")
    return paths


@pytest.fixture(scope="module")
def server():
    srv = Server(DEFAULT_BUNDLE, env={"RSMT_WARMUP_MAX_BATCH": "1"}).start(300)
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def model_info(server) -> dict:
    return httpx.get(server.url + "/v1/model").json()


def _cut(path: Path, start: int | None, frames: int) -> str:
    bvh = BvhFile.read(path)
    first = bvh.num_frames - frames if start is None else start
    return bvh.window(first, frames).format(precision=None)


def test_whole_takes_over_http_give_the_frames_of_what_the_model_reads(server, takes, model_info, caplog) -> None:
    ctx, style = model_info["context_frames"], model_info["style_clip_frames"]["max"]
    whole = {k: p.read_text() for k, p in takes.items()}
    frames = {k: BvhFile.parse(t).num_frames for k, t in whole.items()}
    assert frames["style"] > style and frames["context"] > ctx and frames["target"] > 2, frames

    # Sent as they are, the takes are refused: the body is too large or the style clip too long; the style
    # clip alone is too long, and the message names the option that cuts it.
    body = {"context": {"bvh": whole["context"]}, "target": {"bvh": whole["target"]}, "style": {"bvh": whole["style"]},
            "frames": FRAMES, "deterministic": True}
    raw = httpx.post(server.url + "/v1/transition", json=body, timeout=60)
    code = raw.json()["error"]["code"]
    assert (raw.status_code, code) in ((413, "payload_too_large"), (422, "too_many_frames")), raw.text
    print(f"\nthe three whole takes sent as they are: {len(raw.request.content)} bytes, {raw.status_code} {code}")
    alone = httpx.post(server.url + "/v1/styles", json={"name": "x", "motion": {"bvh": whole["style"]}}, timeout=60)
    err = alone.json()["error"]
    assert alone.status_code == 422 and err["code"] == "too_many_frames", err
    assert f"--start S --frames {style}" in err["message"], err

    middle = (frames["style"] - style) // 2
    cut = {"context": _cut(takes["context"], None, ctx), "target": _cut(takes["target"], None, 2),
           "style": _cut(takes["style"], middle, style)}
    sizes = {k: (len(whole[k].encode()), len(cut[k].encode())) for k in whole}
    print(f"\nwhole takes (frames, bytes) -> cut: {[(k, frames[k], *sizes[k]) for k in whole]}")
    # A whole context and target with a built-in style fit in a body: the server reads the last frames of
    # each, so the frames the client's cuts give are the ones the whole takes give.
    uncut = httpx.post(server.url + "/v1/transition", timeout=60, json={
        "context": {"bvh": whole["context"]}, "target": {"bvh": whole["target"]}, "frames": FRAMES,
        "style_id": "builtin:elderly", "deterministic": True})
    assert uncut.status_code == 200, uncut.text
    with caplog.at_level(logging.WARNING, logger="rsmt_client"), Client(server.url) as c:
        builtin = c.transition(takes["context"], takes["target"], FRAMES, style_id="builtin:elderly", deterministic=True)
        by_takes = c.transition(takes["context"], takes["target"], FRAMES, style=takes["style"], deterministic=True)
        again = c.transition(takes["context"], takes["target"], FRAMES, style=takes["style"], deterministic=True)
        by_cuts = c.transition(cut["context"], cut["target"], FRAMES, style=cut["style"], deterministic=True)
        registered = c.register_style(takes["style"], name="elderly-take")
    served = np.array([f["rotations"] for f in uncut.json()["frames"]], dtype=np.float32)
    np.testing.assert_array_equal(builtin.rotations, served)
    said = [r.getMessage() for r in caplog.records if r.name == "rsmt_client"]
    assert len(said) == 1 and f"sending the middle {style} (frames {middle}-{middle + style - 1})" in said[0], said
    assert by_takes.num_frames == FRAMES and registered["frames"] == style
    np.testing.assert_array_equal(by_takes.rotations, by_cuts.rotations)
    np.testing.assert_array_equal(by_takes.root_positions, by_cuts.root_positions)
    np.testing.assert_array_equal(by_takes.rotations, again.rotations)
    assert registered["style_id"] == by_takes.style_id  # the same clip: the middle of the take


def test_stream_client_takes_whole_takes(server, takes, caplog) -> None:
    with Client(server.url) as c:
        http = c.transition(takes["context"], takes["target"], FRAMES, style=takes["style"], deterministic=True)
    caplog.clear()  # that client said it once; the stream client says it once of its own
    with caplog.at_level(logging.WARNING, logger="rsmt_client"), StreamClient(server.url, encoding="binary") as s:
        limit = s.hello["limits"]["max_message_bytes"]
        # The style clip, even cut to the model's maximum, is more than one message may carry: the client
        # registers it over HTTP and starts by its id.
        streamed = s.transition(takes["context"], takes["target"], FRAMES, style=takes["style"], deterministic=True)
        by_builtin = s.transition(takes["context"], takes["target"], FRAMES, style_id="builtin:elderly", seed=3)
        start = StreamSession(s.hello).fitted(StreamSession.start_message(
            takes["context"], takes["target"], FRAMES, "builtin:elderly", None, None, True, "asap", "x", None, None),
            Cutter(ModelLimits.of(s.model)))
    size = len(json.dumps(start, separators=(",", ":")).encode())
    print(f"\nstart message with whole takes as context and target, cut: {size} bytes (limit {limit})")
    assert size < limit
    assert streamed.num_frames == FRAMES and by_builtin.num_frames == FRAMES
    assert streamed.style_id == http.style_id and by_builtin.style_id == "builtin:elderly"
    np.testing.assert_allclose(streamed.rotations, http.rotations, atol=1e-4)
    np.testing.assert_allclose(streamed.root_positions, http.root_positions, atol=1e-2)
    assert sum("sending the middle" in r.getMessage() for r in caplog.records) == 1


@pytest.mark.parametrize("command", [["transition"], ["stream", "--quiet"], ["stream", "--quiet", "--binary"]])
def test_the_cli_takes_whole_takes(server, takes, tmp_path, command: list[str]) -> None:
    out = tmp_path / "out.bvh"
    done = subprocess.run([sys.executable, "-m", "rsmt_cli.main", "client", *command, "--url", server.url,
                           "--context", str(takes["context"]), "--target", str(takes["target"]), "--frames", str(FRAMES),
                           "--style", str(takes["style"]), "--deterministic", "-o", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert BvhFile.read(out).num_frames == FRAMES
    assert done.stderr.count("sending the middle") == 1, done.stderr
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    assert summary["frames"] == FRAMES, summary
    if command[0] == "transition":
        assert summary["style_id"].startswith("sty_"), summary
    else:
        assert summary["reason"] == "arrived", summary
