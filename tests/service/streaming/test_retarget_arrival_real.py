"""The stream yardstick through a real server (issue 23): every locomotion case of the test split, streamed
by the default model at the model's pace over ``/v1/stream``, one target frame, retargeted at frame 20 of 40 to
its target moved 1 m sideways, arrives where the in-process yardstick
(:mod:`model.evaluation.stream_retarget`) says, and that is within 8 cm on average. Skipped without the shared motion data.

A retarget applies from the next frame the server makes, so the client sends it when frame 19 comes in;
on a loaded 2-core machine it often comes in a frame or more late (the server's ``retargeted`` reply says
the frame it took effect from), and beside another test a client may fall so far behind that its retarget comes after
the stream has ended: such a case is streamed again. So the test checks that the server streams what the yardstick scores (the
in-process stream retargeted at those same frames arrives where the server's frames do) and that the
yardstick, every retarget at frame 20, is under 8 cm. Each case has its own connection: the messages of one
connection are read in turn, so the targets of several characters' retargets would be read one after another.
"""

from __future__ import annotations

import json
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import torch

from model.data.preprocessed import load_motion_cache
from model.evaluation.cases import CaseSet, build_cases, variant
from model.evaluation.methods import BundleMethod
from model.evaluation.stream_retarget import RetargetSettings, stream
from model.inference.bundle import DEFAULT_BUNDLE, Bundle
from tests.service.conftest import poses
from tests.service.server import Server
from tests.service.wsclient import Ws, poses_of

pytestmark = [pytest.mark.real_data, pytest.mark.usefixtures("one_thread")]  # keeps the realtime pace

SETTINGS = RetargetSettings()  # 40 frames, retargeted at frame 20, one target frame
CONNECTIONS = 24  # cases streamed at once, each on its own connection (one connection's messages are handled in turn)
LATE_FRAMES = 15  # a retarget taking effect later than this after frame 20 came from a client behind the pace
TRIES = 3  # a case whose retarget came too late (its client fell behind beside other work) is streamed again
TARGET_CM = 8.0


@pytest.fixture(scope="module")
def cases(shared_data: Path) -> CaseSet:
    cache = load_motion_cache(shared_data, progress=False)
    every = CaseSet.load(cache, build_cases(cache, cache.split.test))
    model = Bundle.load(DEFAULT_BUNDLE)
    # Poses are sent in the model's joint order and at its frame rate (neither named in the message).
    assert every.skeleton.names == model.skeleton.names and every.fps == model.config.fps
    return every.subset(every.locomotion_index)


@pytest.fixture(scope="module")
def server(default_model_server: Server) -> Server:
    return default_model_server  # tests/service/conftest.py: shared with the other read-only streams of the default model


Streamed = tuple[np.ndarray, np.ndarray, int]


def _stream_one(server: Server, cases: CaseSet, b: int) -> Streamed | None:
    """Case ``b`` streamed on its own connection and retargeted when frame 19 comes in:
    ``(roots, rotations, the frame the retarget took effect from)``; None where the retarget took effect more than
    :data:`LATE_FRAMES` after frame 20 or not before the stream ended (the client read frame 19 too late)."""
    first, moved = variant("gap40"), variant("gap40-side1m")
    retarget = json.dumps({"type": "retarget", "character": "c",
                           "target": poses(cases.target_clip(b, moved, SETTINGS.target_frames))})
    with Ws(server.ws, encoding="binary") as ws:
        ws.send({"type": "start", "character": "c", "context": poses(cases.context_clip(b)),
                 "target": poses(cases.target_clip(b, first, SETTINGS.target_frames)),
                 "style": poses(cases.style_clips[b]), "frames": SETTINGS.frames, "deterministic": True,
                 "pace": "realtime"})

        def on_frame(w: Ws, frame: dict) -> None:
            if frame["seq"] == SETTINGS.at - 1:  # prepared before: the retarget leaves at once
                w.send(retarget)

        got = ws.run({"c"}, timeout=120.0, on_frame=on_frame)["c"]
    frames = got["frames"]
    assert [f["seq"] for f in frames] == list(range(SETTINGS.frames)) and got["end"]["reason"] == "arrived"
    acks = [m for m in got["messages"] if m["type"] == "retargeted"]
    assert len(acks) <= 1, got["messages"]
    if not acks or acks[0]["from_seq"] > SETTINGS.at + LATE_FRAMES:
        return None
    assert acks[0]["from_seq"] >= SETTINGS.at  # never early
    roots, rotations = poses_of(frames)
    return roots, rotations, acks[0]["from_seq"]


def _stream_all(server: Server, cases: CaseSet) -> tuple[list[Streamed], int]:
    """Every case streamed (:func:`_stream_one`), a case whose retarget came too late again, up to :data:`TRIES`
    times; and how many streams were run again."""
    done: dict[int, Streamed] = {}
    again = 0
    with ThreadPoolExecutor(CONNECTIONS) as pool:
        for attempt in range(TRIES):
            todo = [b for b in range(len(cases)) if b not in done]
            if not todo:
                break
            again += len(todo) if attempt else 0
            for b, result in zip(todo, pool.map(lambda b: _stream_one(server, cases, b), todo)):
                if result is not None:
                    done[b] = result
    late = [b for b in range(len(cases)) if b not in done]
    assert not late, f"cases {late} were retargeted too late {TRIES} times"
    return [done[b] for b in range(len(cases))], again


def test_a_stream_retargeted_at_frame_20_arrives_within_8_cm_through_the_server(server, cases):
    streamed, again = _stream_all(server, cases)
    at = [seq for _, _, seq in streamed]
    print(f"{again} streams run again after a retarget that came too late", Counter(at))
    roots = torch.from_numpy(np.stack([r for r, _, _ in streamed]))
    rotations = torch.from_numpy(np.stack([q for _, q, _ in streamed]))
    target = cases.target_positions(variant("gap40-side1m"))

    def arrival(rot: torch.Tensor, root: torch.Tensor) -> float:
        positions, _ = cases.forward(rot, root)
        return float((positions[:, -1] - target).norm(dim=-1).mean(-1).mean())

    method = BundleMethod(DEFAULT_BUNDLE)
    through_server = arrival(rotations, roots)
    same_frames = arrival(*stream(method, cases, SETTINGS, retarget=True, at=at))
    at_20 = arrival(*stream(method, cases, SETTINGS, retarget=True))
    print(f"{len(cases)} test locomotion cases, {at.count(SETTINGS.at)} retargets from frame {SETTINGS.at} and the "
          f"rest up to {max(at)}: arrival {through_server:.2f} cm through the server, {same_frames:.2f} cm in process "
          f"at the same frames, {at_20:.2f} cm in process at frame {SETTINGS.at}")
    assert through_server == pytest.approx(same_frames, abs=0.05)  # the server streams what the yardstick scores
    assert at_20 < TARGET_CM
