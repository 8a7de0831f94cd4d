"""What the model reads of a motion, cut from whatever a user has (a whole take, say) before it is sent.

A model reads the last ``context_frames`` of a context, the last frame of a target and the one before it
(its velocity), and a style clip of ``style_clip_frames.min`` to ``.max`` frames, all at its fps
(``GET /v1/model``). The clients cut a payload to that before sending it, so a whole dataset take works
wherever a short clip does:

- a context to its last frames (the server reads no others: the same frames come back);
- a target to its last two frames (likewise);
- a style clip longer than the model's maximum to the middle ``max`` frames. This one changes what the
  model sees, so :class:`Cutter` says so once (a warning on the ``rsmt_client`` logger); cut a clip
  yourself to pick the part (``BvhFile.window``, ``rsmt client styles add --start S --frames N``).

Payloads are the contract's ``Motion`` dicts (:func:`rsmt_client.motion.motion_payload`); one the model
reads whole is returned as it came. No I/O here.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from rsmt_client.bvh import MAX_FPS, MIN_FPS, BvhFile

log = logging.getLogger("rsmt_client")
TARGET_FRAMES = 2  # the target pose and the frame before it (its velocity)
# The header lines that say how long a take is: read without parsing the frames (most payloads are sent whole).
_FRAMES = re.compile(r"^\s*frames\s*:\s*([0-9]{1,18})\s*$", re.I | re.M)
_FRAME_TIME = re.compile(r"^\s*frame\s+time\s*:\s*(\S+)\s*$", re.I | re.M)


@dataclass(frozen=True)
class ModelLimits:
    """The frames a model reads, from its ``GET /v1/model`` description."""

    fps: float
    context_frames: int
    style_min: int
    style_max: int

    @classmethod
    def of(cls, model_info: Mapping[str, Any]) -> ModelLimits | None:
        """None for a description without these fields (an older server): payloads then go as they are."""
        try:
            style = model_info["style_clip_frames"]
            return cls(float(model_info["fps"]), int(model_info["context_frames"]), int(style["min"]),
                       int(style["max"]))
        except (KeyError, TypeError, ValueError):
            return None


def resampled_frames(frames: int, source_fps: float, fps: float) -> int:
    """How many frames ``frames`` at ``source_fps`` become at ``fps``, as the server resamples (from frame 0)."""
    return int((frames - 1) * fps / source_fps + 1e-9) + 1 if frames > 0 else 0


def frames_for(frames: int, source_fps: float, fps: float) -> int:
    """The fewest source frames that resample to at least ``frames`` at ``fps``."""
    n = max(1, math.ceil((frames - 1) * source_fps / fps - 1e-9) + 1)
    while resampled_frames(n, source_fps, fps) < frames:
        n += 1
    return n


def frames_within(frames: int, source_fps: float, fps: float) -> int:
    """The most source frames that resample to at most ``frames`` at ``fps``."""
    n = max(1, math.floor(frames * source_fps / fps + 1e-9))
    while n > 1 and resampled_frames(n, source_fps, fps) > frames:
        n -= 1
    return n


@dataclass(frozen=True)
class Window:
    """Frames ``[start, start + frames)`` of a payload that holds ``total`` frames."""

    start: int
    frames: int
    total: int


def payload_frames(payload: Mapping[str, Any], default_fps: float) -> tuple[int, float]:
    """A payload's frame count and fps (for BVH text, from its ``Frames:`` and ``Frame Time:`` lines when they read
    plainly, else from the parsed file)."""
    if "bvh" in payload:
        text = str(payload["bvh"])
        frames, frame_time = _FRAMES.search(text), _FRAME_TIME.search(text)
        try:
            seconds = float(frame_time.group(1)) if frame_time else 0.0
        except ValueError:
            seconds = 0.0
        if frames is None or not (math.isfinite(seconds) and 1.0 / MAX_FPS <= seconds <= 1.0 / MIN_FPS):
            bvh = BvhFile.parse(text)  # the reader's error names the problem (a Frame Time of 1e-310 s, say)
            return bvh.num_frames, bvh.fps
        fps, whole = 1.0 / seconds, round(1.0 / seconds)
        return int(frames.group(1)), float(whole) if whole >= 1 and abs(fps - whole) <= 1e-4 * fps else fps
    return len(payload.get("rotations") or ()), float(payload.get("fps") or default_fps)


def cut(payload: Mapping[str, Any], window: Window) -> dict[str, Any]:
    """The payload's frames in ``window`` (BVH values kept exactly as read)."""
    if "bvh" in payload:
        bvh = BvhFile.parse(str(payload["bvh"]))
        if bvh.num_frames != window.total:
            raise ValueError(f"the BVH holds {bvh.num_frames} frames but its Frames: line says {window.total}")
        return {**payload, "bvh": bvh.window(window.start, window.frames).format(precision=None)}
    stop = window.start + window.frames
    return {**payload, "root_positions": list(payload["root_positions"])[window.start:stop],
            "rotations": list(payload["rotations"])[window.start:stop]}


class Cutter:
    """Cuts payloads to what one model reads; warns once (per cutter) when it cuts a style clip."""

    def __init__(self, limits: ModelLimits | None) -> None:
        self.limits = limits
        self.warned = False

    def context(self, payload: Mapping[str, Any]) -> dict[str, Any]:
        return self._tail(payload, lambda lim: lim.context_frames)

    def target(self, payload: Mapping[str, Any]) -> dict[str, Any]:
        return self._tail(payload, lambda lim: TARGET_FRAMES)

    def _tail(self, payload: Mapping[str, Any], want: Any) -> dict[str, Any]:
        lim = self.limits
        if lim is None or not _has_frames(payload):
            return dict(payload)
        total, fps = payload_frames(payload, lim.fps)
        keep = frames_for(int(want(lim)), fps, lim.fps)
        if total <= keep:
            return dict(payload)
        return cut(payload, Window(total - keep, keep, total))

    def style(self, payload: Mapping[str, Any]) -> dict[str, Any]:
        lim = self.limits
        if lim is None or not _has_frames(payload):
            return dict(payload)
        total, fps = payload_frames(payload, lim.fps)
        if resampled_frames(total, fps, lim.fps) <= lim.style_max:
            return dict(payload)
        keep = frames_within(lim.style_max, fps, lim.fps)
        window = Window((total - keep) // 2, keep, total)
        if not self.warned:
            self.warned = True
            log.warning("style clip of %d frames at %g fps: the model reads at most %d at %g fps; sending the "
                        "middle %d (frames %d-%d). Cut it yourself to choose the part (rsmt client styles add "
                        "--start S --frames N, or rsmt_client.bvh.BvhFile.window); said once per client.",
                        total, fps, lim.style_max, lim.fps, keep, window.start, window.start + keep - 1)
        return cut(payload, window)


def _has_frames(payload: Mapping[str, Any]) -> bool:
    return "bvh" in payload or ("rotations" in payload and "root_positions" in payload)
