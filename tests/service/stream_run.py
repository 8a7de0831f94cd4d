"""What a client saw of a streamed run of several characters: every frame with the wall time it arrived,
where each character resumed after a failover, and the figures of the failover test read from them (gaps
between frames, the motion from one frame to the next, the arrival against the target)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from model.data.synthetic import synthetic_skeleton
from model.motion.clip import Clip
from model.motion.kinematics import forward_kinematics
from tests.service.conftest import bvh, context_clip


@dataclass
class CharacterRun:
    target: Clip
    frames: list[Any] = field(default_factory=list)  # rsmt_client Frame, in arrival order
    arrived_s: list[float] = field(default_factory=list)  # monotonic time each frame was read
    resumed_at: list[int] = field(default_factory=list)  # index of the first frame after each resume
    ended: bool = False

    def positions(self) -> np.ndarray:
        """World joint positions ``[1 + T, J, 3]`` (cm): the context's last pose, then every frame received."""
        ctx = context_clip()
        roots = np.concatenate([ctx.root_positions[-1:].numpy(), np.stack([f.root_position for f in self.frames])])
        rots = np.concatenate([ctx.rotations[-1:].numpy(), np.stack([f.rotations for f in self.frames])])
        return fk(roots, rots)

    def steps(self) -> np.ndarray:
        """``[T, 2]``: per frame, how far the root and the joint that moved most went since the pose before
        (the first: since the context's last pose), in cm."""
        pos = self.positions()
        moved = np.linalg.norm(np.diff(pos, axis=0), axis=-1)  # [T, J]
        return np.stack([moved[:, 0], moved.max(axis=1)], axis=1)

    def arrival_error(self) -> tuple[float, float]:
        """(root, largest joint) distance of the last frame from the target's last pose, in cm."""
        got = self.positions()[-1]
        want = fk(self.target.root_positions[-1:].numpy(), self.target.rotations[-1:].numpy())[0]
        return float(np.linalg.norm(got[0] - want[0])), float(np.linalg.norm(got - want, axis=-1).max())

    def gaps_s(self) -> np.ndarray:
        return np.diff(np.asarray(self.arrived_s))


def fk(roots: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    sk = synthetic_skeleton()
    pos, _ = forward_kinematics(torch.as_tensor(rotations, dtype=torch.float64),
                                torch.as_tensor(roots, dtype=torch.float64), sk.offsets_tensor(torch.float64), sk.parents)
    return pos.numpy()


def stream_characters(client: Any, targets: list[Clip], frames: int, style_id: str,
                      on_frame: Callable[[int], None] | None = None, timeout_s: float = 90.0) -> dict[str, CharacterRun]:
    """Start one character per target on ``client`` (an open ``rsmt_client.StreamClient``; realtime pace,
    ``exact_arrival``) and read until every one has ended; ``on_frame(total frames so far)`` after each frame."""
    runs: dict[str, CharacterRun] = {}
    for i, target in enumerate(targets):
        cid = client.start(bvh(context_clip()), bvh(target), frames, style_id=style_id, seed=i, pace="realtime",
                           exact_arrival=True)
        runs[cid] = CharacterRun(target)
    total, deadline = 0, time.monotonic() + timeout_s
    while not all(r.ended for r in runs.values()) and time.monotonic() < deadline:
        item = client.recv(timeout=30)
        now = time.monotonic()
        if isinstance(item, dict):
            assert item.get("type") != "error", item
            run = runs.get(item.get("character", ""))
            if run is not None and item.get("type") == "end":
                run.ended = True
            elif run is not None and item.get("type") == "started" and item.get("resumed"):
                run.resumed_at.append(len(run.frames))
            continue
        run = runs[item.character]
        run.frames.append(item)
        run.arrived_s.append(now)
        total += 1
        if on_frame is not None:
            on_frame(total)
    return runs
