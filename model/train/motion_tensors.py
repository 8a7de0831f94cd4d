"""Training motion held in memory: every take's world positions and rotations, concatenated, with
labels, optional mirrored and time-rescaled copies, and per-frame phase labels once computed.

Windows are addressed by global frame index, so a batch is one gather, not a Python loop.
"""

from __future__ import annotations

import dataclasses
import logging
import re
from collections.abc import Sequence
from dataclasses import dataclass, field

import torch
from tqdm import tqdm

from model.data.preprocessed import MotionCache
from model.motion.clip import Clip
from model.motion.features import temporal_rescale
from model.motion.kinematics import forward_kinematics
from model.motion.mirror import mirror_global, mirror_reflections
from model.motion.rotations import quat_make_continuous, quat_normalize
from model.motion.skeleton import Skeleton

Tensor = torch.Tensor
log = logging.getLogger(__name__)


def mean_skeleton(cache: MotionCache, takes: Sequence[int]) -> Skeleton:
    """The rig with each bone offset averaged over the takes' performers (frame-weighted)."""
    first = cache.skeleton(takes[0])
    total = torch.zeros(first.num_joints, 3, dtype=torch.float64)
    weight = 0.0
    for i in takes:
        sk = cache.skeleton(i)
        if not sk.same_rig(first):
            raise ValueError(f"take {cache.takes[i].take_id} is on another rig than {cache.takes[takes[0]].take_id}")
        n = cache.num_frames(i)
        total += sk.offsets_tensor(torch.float64) * n
        weight += n
    offsets = (total / weight).tolist()
    return Skeleton(names=first.names, parents=first.parents, offsets=tuple(tuple(o) for o in offsets),
                    roles=first.roles, end_sites=first.end_sites, units=first.units)


def _mirror_content(content: str) -> str:
    swap = {"left": "right", "right": "left", "Left": "Right", "Right": "Left"}
    return re.sub(r"left|right|Left|Right", lambda m: swap[m.group(0)], content)


@dataclass
class MotionTensors:
    """Concatenated takes; rows ``take_start[i] : take_start[i] + take_len[i]`` are take ``i``.

    Attributes:
        positions / rotations: ``[N, J, 3]`` world positions (cm) and ``[N, J, 4]`` world rotations.
        take_start / take_len / style / content: ``[n]`` per take (style and content are ids).
        source: per take, ``"orig"``, ``"mirror"`` or ``"rescale"``.
        phase / amplitude / frequency: ``[N, M, 2]``, ``[N, M]``, ``[N, M]`` labels (after labelling).

    The per-frame tensors (positions, rotations, labels) may live on a GPU (see :meth:`to`); the
    per-take bookkeeping stays on the CPU, where windows are listed and drawn.
    """

    skeleton: Skeleton
    positions: Tensor
    rotations: Tensor
    take_start: Tensor
    take_len: Tensor
    style: Tensor
    content: Tensor
    styles: list[str]
    contents: list[str]
    source: list[str] = field(default_factory=list)
    names: list[str] = field(default_factory=list)
    phase: Tensor | None = None
    amplitude: Tensor | None = None
    frequency: Tensor | None = None

    @classmethod
    def from_cache(cls, cache: MotionCache, takes: Sequence[int], skeleton: Skeleton | None = None,
                   augment: bool = True, seed: int = 0, progress: bool = True) -> MotionTensors:
        """FK every take (with its own performer's offsets), plus mirrored and rescaled copies."""
        if not takes:
            raise ValueError("no takes to train on")
        skeleton = skeleton or mean_skeleton(cache, takes)
        # Typical motion settles the mirror convention of single-bone joints (see model.motion.mirror).
        sample = list(takes)[:: max(1, len(takes) // 200)]
        reference = torch.cat([cache.rotations(i)[::4] for i in sample])
        items = [(cache.clip(i), cache.style_id(i), cache.takes[i].content) for i in takes]
        return cls.from_clips(items, list(cache.styles), skeleton, reference, augment, seed, progress)

    @classmethod
    def from_clips(cls, items: Sequence[tuple[Clip, int, str]], styles: list[str], skeleton: Skeleton,
                   reference: Tensor | None = None, augment: bool = True, seed: int = 0,
                   progress: bool = True) -> MotionTensors:
        """From ``(clip, style id, content)`` triples; ``reference`` local rotations settle mirroring."""
        reflections = mirror_reflections(skeleton, reference)
        gen = torch.Generator().manual_seed(seed)
        contents: list[str] = []
        pos_parts, rot_parts, lens, sty, con, src, names = [], [], [], [], [], [], []

        def add(clip: Clip, style: int, content: str, source: str) -> None:
            sk = clip.skeleton
            p, r = forward_kinematics(clip.rotations.double(), clip.root_positions.double(), sk.offsets_tensor(torch.float64),
                                      sk.parents)
            if source == "mirror":
                p, r = mirror_global(p, r, sk, reflections)
            if content not in contents:
                contents.append(content)
            pos_parts.append(p.float())
            rot_parts.append(quat_make_continuous(quat_normalize(r.float()), dim=0))
            lens.append(clip.num_frames)
            sty.append(style)
            con.append(contents.index(content))
            src.append(source)
            names.append(f"{source}:{clip.name}")

        for clip, style, content in tqdm(items, desc="takes", disable=not progress, leave=False):
            add(clip, style, content, "orig")
            if augment:
                add(clip, style, _mirror_content(content), "mirror")
                rescaled = temporal_rescale(clip, gen)
                if rescaled.num_frames >= 2:
                    add(rescaled, style, content, "rescale")
        lens_t = torch.tensor(lens)
        starts = torch.cumsum(lens_t, 0) - lens_t
        return cls(skeleton, torch.cat(pos_parts), torch.cat(rot_parts), starts, lens_t, torch.tensor(sty),
                   torch.tensor(con), list(styles), contents, src, names)

    @property
    def device(self) -> torch.device:
        return self.positions.device

    def to(self, device: torch.device | str) -> MotionTensors:
        """A copy with the per-frame tensors on ``device``; ``self`` when they are there already.

        Take starts, lengths, style and content ids stay on the CPU: window lists and random draws
        are made there with CPU generators, so every device trains on the same batches.
        """
        device = torch.device(device)
        if device.type == "cuda" and device.index is None:  # tensors report "cuda:0", never bare "cuda"
            device = torch.device("cuda", torch.cuda.current_device())
        if self.positions.device == device and (self.phase is None or self.phase.device == device):
            return self

        def move(t: Tensor | None) -> Tensor | None:
            return None if t is None else t.to(device)

        return dataclasses.replace(self, positions=self.positions.to(device), rotations=self.rotations.to(device),
                                   phase=move(self.phase), amplitude=move(self.amplitude), frequency=move(self.frequency))

    @property
    def num_takes(self) -> int:
        return len(self.take_len)

    def window_starts(self, length: int, step: int) -> tuple[Tensor, Tensor]:
        """Global start rows and take indices of every window of ``length`` frames fitting in a take."""
        starts, owners = [], []
        for i in range(self.num_takes):
            n = int(self.take_len[i])
            s0 = int(self.take_start[i])
            for s in range(0, n - length + 1, step):
                starts.append(s0 + s)
                owners.append(i)
        return torch.tensor(starts, dtype=torch.long), torch.tensor(owners, dtype=torch.long)

    def gather(self, starts: Tensor, length: int) -> tuple[Tensor, Tensor]:
        """``(positions [B, L, J, 3], rotations [B, L, J, 4])`` of windows starting at ``starts``."""
        idx = (starts.unsqueeze(1) + torch.arange(length)).to(self.positions.device)
        return self.positions[idx], self.rotations[idx]

    def gather_phase(self, starts: Tensor, length: int) -> tuple[Tensor, Tensor, Tensor]:
        if self.phase is None or self.amplitude is None or self.frequency is None:
            raise ValueError("phase labels are missing: label the data with the phase model first")
        idx = (starts.unsqueeze(1) + torch.arange(length)).to(self.phase.device)
        return self.phase[idx], self.amplitude[idx], self.frequency[idx]

    def gather_at(self, rows: Tensor) -> tuple[Tensor, Tensor]:
        """``(positions [B, L, J, 3], rotations [B, L, J, 4])`` at fractional global ``rows [B, L]``
        (:mod:`model.train.time_warp`): positions interpolated linearly between the neighbouring frames,
        rotations normalised-linearly (neighbouring frames of a take share a sign, see :meth:`from_clips`).
        A fractional row must lie inside one take."""
        i0, i1, w = self._neighbours(rows)
        w = w[..., None, None]  # over joints and components
        pos = torch.lerp(self.positions[i0], self.positions[i1], w)
        rot = torch.lerp(self.rotations[i0], self.rotations[i1], w)
        return pos, rot / rot.norm(dim=-1, keepdim=True).clamp_min(1e-8)

    def gather_phase_at(self, rows: Tensor, speed: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Phase labels at fractional ``rows [B, L]`` of motion replayed at ``speed [B, L]`` capture frames
        per frame: amplitudes interpolated, phase directions interpolated at that amplitude, and the
        frequency (the phase's advance per frame) times the speed."""
        if self.phase is None or self.amplitude is None or self.frequency is None:
            raise ValueError("phase labels are missing: label the data with the phase model first")
        i0, i1, w = self._neighbours(rows)
        wm = w.unsqueeze(-1)  # [B, L, 1] over the phase channels
        amp = torch.lerp(self.amplitude[i0], self.amplitude[i1], wm)
        direction = torch.lerp(self.phase[i0], self.phase[i1], wm.unsqueeze(-1))
        phase = direction / direction.norm(dim=-1, keepdim=True).clamp_min(1e-6) * amp.unsqueeze(-1)
        freq = torch.lerp(self.frequency[i0], self.frequency[i1], wm) * speed.to(amp).unsqueeze(-1)
        return phase, amp, freq

    def _neighbours(self, rows: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """The frames before and after fractional ``rows`` and the weight of the one after, on this device."""
        rows = rows.to(torch.float64)
        i0 = rows.floor().long()
        w = (rows - i0).to(self.positions.dtype)
        i1 = torch.where(w > 0, i0 + 1, i0)
        dev = self.positions.device
        return i0.to(dev), i1.to(dev), w.to(dev)

    def take_slice(self, i: int) -> slice:
        s = int(self.take_start[i])
        return slice(s, s + int(self.take_len[i]))
