"""Evaluation cases: fixed context/target windows cut from the takes of a split, and their variants.

A case is ``SPAN = 50`` consecutive frames of one take, starting at frames ``0, 40, 80, ...`` of
the take (every start with ``start + 50 <= frames``; the reference benchmark also steps by 40):

* frames ``0..9`` are the **context**; frame 9 is the last context pose (the transition's frame 0);
* a gap of ``n`` frames (``n`` in 10, 20, 40) is frames ``10..9+n``; its **target** is frame
  ``9+n`` (its last frame) plus frame ``8+n`` before it, for the target velocity. A method
  generates ``n`` frames, the last of which should be the target. All three gaps share the
  context, so the cases of the three gaps are the same;
* control variants on the 40-frame gap (RSMT paper Sec. 5):
  * target location ``d``: the target's horizontal root position becomes
    ``x9 + d * (x49 - x9)`` and the whole target (both of its frames) is moved by that shift,
    for ``d = 2`` (twice as far) and ``d = -1`` (as far behind); 40 frames are generated;
  * duration ``dt``: ``int(40 * dt)`` frames are generated to the unchanged target, for
    ``dt = 0.5`` and ``dt = 2``;
  * on **locomotion** cases only (:data:`LOCOMOTION` contents): the target **turned** by +90 and
    -90 degrees about its own vertical axis (the target pose's root rotation is turned, its root
    position kept), and the target **moved 1 m sideways**: 100 cm to the left of the horizontal
    direction from frame 9's root to the target's root (the facing of frame 9 where those roots are
    less than 1 cm apart).
  Ground truth exists only for unchanged controls.

The target a method is sent is the target frame **alone** by default (what a game has: a key pose,
no velocity; the LaFAN1 convention); ``target_frames=2`` also sends the frame before it, i.e. the
target's velocity (turned and moved with it). Baselines use the target frame only.

Everything is scored in the **canonical frame of frame 9**, the last context frame (facing +Z,
its root over the origin), not the reference code's frame 10, which is a ground-truth in-between
frame and leaks it.

Each case is paired with two style clips, both deterministic (a hash of the case id ranks the
candidates): a clip of the **same style** from **another take** of the split, and a clip of a
**different style** (chosen per case among the other styles) for the cross-style figures.
Candidates are ranked: takes with at least 120 frames first, then the case's own content
(so a walk is paired with a walk in the requested style), then the hash. A clip is the first 120
frames of its take (fewer when the take is shorter), as the reference's style pool.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property

import torch

from model.data.preprocessed import MotionCache
from model.motion.clip import Clip
from model.motion.features import CanonicalFrame
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_make_continuous, quat_mul, quat_normalize, quat_rotate, yaw_quat
from model.motion.skeleton import Skeleton

Tensor = torch.Tensor

CONTEXT = 10
GAPS = (10, 20, 40)
SPAN = CONTEXT + max(GAPS)
CASE_STEP = 40
STYLE_CLIP_FRAMES = 120
LAST_CONTEXT = CONTEXT - 1
LOCOMOTION = ("walk", "walk-turn-left", "walk-turn-right", "run", "walk-back", "walk-left", "walk-right", "dash")
"""The contents of the data whose takes travel: every acceptance figure is taken on their cases (dataset 2 has
the first four; dataset 1 adds backwards, at an angle to the facing and the dash)."""
SIDE_STEP_CM = 100.0
TURN_DEG = 90.0


@dataclass(frozen=True)
class Variant:
    """One evaluation condition.

    Attributes:
        name: ``gap10``, ``gap20``, ``gap40``, ``gap40-d2``, ``gap40-d-1``, ``gap40-dt0.5``, ``gap40-dt2``,
            ``gap40-turn+90``, ``gap40-turn-90``, ``gap40-side1m``.
        gap: the ground-truth gap; the target is window frame ``9 + gap``.
        d: target-location factor (1 = unchanged).
        dt: duration factor (1 = unchanged); ``frames = int(gap * dt)`` are generated.
        turn: degrees the target is turned about its own vertical axis (0 = unchanged).
        side: cm the target is moved to the left of the context-to-target direction (0 = unchanged).
    """

    name: str
    gap: int
    d: float = 1.0
    dt: float = 1.0
    turn: float = 0.0
    side: float = 0.0

    @property
    def locomotion_only(self) -> bool:
        """Turned and moved targets are asked of the locomotion cases only."""
        return self.turn != 0.0 or self.side != 0.0

    @property
    def frames(self) -> int:
        return int(self.gap * self.dt)

    @property
    def has_ground_truth(self) -> bool:
        return self.d == 1.0 and self.dt == 1.0 and not self.locomotion_only

    @property
    def target_frame(self) -> int:
        """Index of the target frame in the case window."""
        return LAST_CONTEXT + self.gap

    @property
    def label(self) -> str:
        if self.has_ground_truth:
            return f"gap {self.gap}"
        if self.d != 1.0:
            return f"gap {self.gap}, d={self.d:g}"
        if self.turn != 0.0:
            return f"gap {self.gap}, turned {self.turn:+g}°"
        if self.side != 0.0:
            return f"gap {self.gap}, {self.side / 100:g} m sideways"
        return f"gap {self.gap}, dt={self.dt:g}"


GAP_VARIANTS = tuple(Variant(f"gap{g}", g) for g in GAPS)
CONTROL_VARIANTS = (
    Variant("gap40-dt2", 40, dt=2.0),
    Variant("gap40-dt0.5", 40, dt=0.5),
    Variant("gap40-d2", 40, d=2.0),
    Variant("gap40-d-1", 40, d=-1.0),
    Variant("gap40-turn+90", 40, turn=TURN_DEG),
    Variant("gap40-turn-90", 40, turn=-TURN_DEG),
    Variant("gap40-side1m", 40, side=SIDE_STEP_CM),
)
VARIANTS = GAP_VARIANTS + CONTROL_VARIANTS


def variant(name: str) -> Variant:
    for v in VARIANTS:
        if v.name == name:
            return v
    raise KeyError(f"no variant {name!r}: use one of {', '.join(v.name for v in VARIANTS)}")


def stable_hash(*parts: object) -> int:
    """A 63-bit integer fixed by ``parts`` on every machine (``hash()`` of a str is salted)."""
    digest = hashlib.sha256("\0".join(map(str, parts)).encode()).digest()
    return int.from_bytes(digest[:8], "big") >> 1


@dataclass(frozen=True)
class EvalCase:
    """One case: a window of a take and its two style pairings (take indices into the cache)."""

    id: str
    take: int
    start: int
    style: str
    content: str
    style_take: int
    style_frames: int
    cross_style: str
    cross_take: int
    cross_frames: int


def _rank_style_takes(cache: MotionCache, pool: Sequence[int], style: str, content: str, exclude: int,
                      key: str) -> int | None:
    candidates = [j for j in pool if j != exclude and cache.takes[j].style == style]
    if not candidates:
        return None
    return min(candidates, key=lambda j: (cache.num_frames(j) < STYLE_CLIP_FRAMES,
                                          cache.takes[j].content != content,
                                          stable_hash(key, cache.takes[j].take_id)))


def build_cases(cache: MotionCache, takes: Sequence[int], limit: int | None = None,
                step: int = CASE_STEP, only_styles: Sequence[str] = (), clip_fallback: Sequence[int] = (),
                clips_only: Collection[str] = ()) -> list[EvalCase]:
    """The cases of ``takes`` (a split), sorted by take id then start; see the module docstring.

    Takes shorter than :data:`SPAN` give no case but still serve as style clips (when at least
    :data:`SPAN` frames long). A case whose style has no other take in ``takes`` is skipped.
    ``only_styles`` keeps only cases of those styles; style clips (same and other style) still come
    from every take, so a case is the same case with or without the filter.
    ``limit`` keeps that many cases spread evenly over the sorted list (so every style stays in).
    ``clip_fallback`` (e.g. the training split) gives a style's clips where ``takes`` has no other take of it
    (dataset 1 has one take per style and content, so its val and test splits rarely hold two of a style);
    where ``takes`` has one, nothing changes.
    ``clips_only`` names takes (by ``take_id``) that give no case but still serve as style clips: e.g. the clips a
    style was fine-tuned on, so that its figures come from other takes while its zero-shot clip may be one of them.
    """
    order = sorted(takes, key=lambda i: cache.takes[i].take_id)
    pool = [i for i in order if cache.num_frames(i) >= SPAN]
    fallback = [i for i in sorted(clip_fallback, key=lambda i: cache.takes[i].take_id) if cache.num_frames(i) >= SPAN]
    styles = sorted({cache.takes[i].style for i in [*pool, *fallback]})

    def rank(style: str, content: str, exclude: int, key: str) -> int | None:
        found = _rank_style_takes(cache, pool, style, content, exclude, key)
        return found if found is not None or not fallback else _rank_style_takes(cache, fallback, style, content,
                                                                                  exclude, key)

    cases: list[EvalCase] = []
    for i in order:
        n = cache.num_frames(i)
        take = cache.takes[i]
        if (only_styles and take.style not in only_styles) or take.take_id in clips_only:
            continue
        for start in range(0, n - SPAN + 1, step):
            cid = f"{take.take_id}@{start}"
            same = rank(take.style, take.content, i, cid)
            others = [s for s in styles if s != take.style]
            if same is None or not others:
                continue
            cross_style = others[stable_hash("cross", cid) % len(others)]
            cross = rank(cross_style, take.content, i, cid)
            if cross is None:
                continue
            cases.append(EvalCase(
                id=cid, take=i, start=start, style=take.style, content=take.content,
                style_take=same, style_frames=min(STYLE_CLIP_FRAMES, cache.num_frames(same)),
                cross_style=cross_style, cross_take=cross, cross_frames=min(STYLE_CLIP_FRAMES, cache.num_frames(cross)),
            ))
    if limit is not None and 0 < limit < len(cases):
        cases = [cases[(k * len(cases)) // limit] for k in range(limit)]
    return cases


@dataclass
class CaseSet:
    """Cases with their motion as batched tensors (world frame unless named canonical).

    Attributes:
        rotations: ``[B, SPAN, J, 4]`` local quaternions of each case window.
        roots: ``[B, SPAN, 3]`` root positions (cm).
        offsets: ``[B, J, 3]`` the rest offsets of each case's performer.
        skeletons: each case's skeleton (one rig: same names and parents).
        positions / global_rotations: ``[B, SPAN, J, 3|4]`` by forward kinematics.
        frame: the canonical frame of frame 9 of each case.
    """

    cases: list[EvalCase]
    rotations: Tensor
    roots: Tensor
    offsets: Tensor
    skeletons: list[Skeleton]
    positions: Tensor
    global_rotations: Tensor
    frame: CanonicalFrame
    style_clips: list[Clip]
    cross_clips: list[Clip]
    styles: list[str]
    fps: float
    # Per case, the clips of a style set its style is asked with (1-5 clips encoded together, as a registration of
    # several clips is); empty: the case's one style clip. Empty for every case unless sets were given.
    style_sets: list[list[Clip]] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.cases)

    @property
    def skeleton(self) -> Skeleton:
        return self.skeletons[0]

    @classmethod
    def load(cls, cache: MotionCache, cases: Sequence[EvalCase],
             style_sets: Mapping[str, Sequence[int]] | None = None) -> CaseSet:
        """The cases' motion; ``style_sets`` maps a style to the takes whose clips (the first
        :data:`STYLE_CLIP_FRAMES` frames of each) its cases are asked with instead of their one style clip."""
        if not cases:
            raise ValueError("no evaluation cases: the split has no take of at least "
                             f"{SPAN} frames whose style has another take")
        first = cache.skeleton(cases[0].take)
        rots, roots, offs, sks = [], [], [], []
        for c in cases:
            sk = cache.skeleton(c.take)
            if not sk.same_rig(first):
                raise ValueError(f"take {cache.takes[c.take].take_id} is on another rig than "
                                 f"{cache.takes[cases[0].take].take_id}")
            rot = quat_normalize(cache.rotations(c.take)[c.start:c.start + SPAN].float())
            rots.append(quat_make_continuous(rot, dim=0))
            roots.append(cache.root_positions(c.take)[c.start:c.start + SPAN].float())
            offs.append(sk.offsets_tensor())
            sks.append(sk)
        rotations, root_t, offsets = torch.stack(rots), torch.stack(roots), torch.stack(offs)
        pos, grot = forward_kinematics(rotations, root_t, offsets.unsqueeze(1), first.parents)
        frame = CanonicalFrame.at_frame(pos, first, LAST_CONTEXT)

        def clip(take: int, frames: int) -> Clip:
            return cache.clip(take).window(0, frames).to(torch.float32)

        return cls(
            cases=list(cases), rotations=rotations, roots=root_t, offsets=offsets, skeletons=sks,
            positions=pos, global_rotations=grot, frame=frame,
            style_clips=[clip(c.style_take, c.style_frames) for c in cases],
            cross_clips=[clip(c.cross_take, c.cross_frames) for c in cases],
            styles=list(cache.styles), fps=cache.fps,
            style_sets=[[clip(t, min(STYLE_CLIP_FRAMES, cache.num_frames(t))) for t in style_sets.get(c.style, ())]
                        for c in cases] if style_sets else [],
        )

    def subset(self, index: Sequence[int]) -> CaseSet:
        idx = torch.tensor(list(index), dtype=torch.long)
        return CaseSet(
            cases=[self.cases[i] for i in index], rotations=self.rotations[idx], roots=self.roots[idx],
            offsets=self.offsets[idx], skeletons=[self.skeletons[i] for i in index],
            positions=self.positions[idx], global_rotations=self.global_rotations[idx],
            frame=CanonicalFrame(self.frame.yaw[idx], self.frame.origin[idx]),
            style_clips=[self.style_clips[i] for i in index], cross_clips=[self.cross_clips[i] for i in index],
            styles=self.styles, fps=self.fps, style_sets=[self.style_sets[i] for i in index] if self.style_sets else [],
        )

    # ------------------------------------------------------------------ per-variant pieces
    @cached_property
    def locomotion_index(self) -> list[int]:
        """Indices of the cases whose content is a locomotion content (:data:`LOCOMOTION`)."""
        return [i for i, c in enumerate(self.cases) if c.content in LOCOMOTION]

    def target_shift(self, v: Variant) -> Tensor:
        """``[B, 3]`` horizontal shift applied to the target: ``(d - 1) * (x_target - x_9)`` plus ``side`` cm
        to the left of that direction (y = 0)."""
        delta = self.roots[:, v.target_frame] - self.roots[:, LAST_CONTEXT]
        delta = delta * torch.tensor([1.0, 0.0, 1.0])
        shift = (v.d - 1.0) * delta
        if v.side != 0.0:
            length = delta.norm(dim=-1, keepdim=True)
            facing = torch.stack([torch.sin(self.frame.yaw), torch.zeros_like(self.frame.yaw),
                                  torch.cos(self.frame.yaw)], dim=-1)
            direction = torch.where(length >= 1.0, delta / length.clamp_min(1e-6), facing)
            left = torch.stack([direction[:, 2], torch.zeros_like(direction[:, 0]), -direction[:, 0]], dim=-1)
            shift = shift + v.side * left
        return shift

    def _turn(self, v: Variant) -> Tensor:
        """``[B, 4]`` the yaw quaternion the target is turned by."""
        return yaw_quat(torch.full((len(self.cases),), math.radians(v.turn)))

    def targets(self, v: Variant, frames: int = 1) -> tuple[Tensor, Tensor]:
        """The last ``frames`` (1 or 2) frames of the target, ``(local rotations [B, frames, J, 4], roots [B, frames, 3])``,
        turned about the target root's vertical axis and shifted for ``d`` and ``side``."""
        if frames not in (1, 2):
            raise ValueError(f"a target has 1 or 2 frames, not {frames}")
        t = v.target_frame
        rot = self.rotations[:, t + 1 - frames:t + 1]
        root = self.roots[:, t + 1 - frames:t + 1]
        if v.turn != 0.0:
            q = self._turn(v).unsqueeze(1).expand(-1, frames, -1)
            r = self.skeleton.roles.root
            rot = rot.clone()
            rot[:, :, r] = quat_normalize(quat_mul(q, rot[:, :, r]))
            pivot = self.roots[:, t].unsqueeze(1)
            root = pivot + quat_rotate(q, root - pivot)
        return rot, root + self.target_shift(v).unsqueeze(1)

    def target_positions(self, v: Variant) -> Tensor:
        """``[B, J, 3]`` world positions of the (turned, shifted) target pose."""
        pos = self.positions[:, v.target_frame]
        if v.turn != 0.0:
            pivot = self.roots[:, v.target_frame].unsqueeze(1)
            pos = pivot + quat_rotate(self._turn(v).unsqueeze(1).expand(-1, pos.shape[1], -1), pos - pivot)
        return pos + self.target_shift(v).unsqueeze(1)

    def ground_truth(self, v: Variant) -> tuple[Tensor, Tensor]:
        """World ``(positions [B, gap, J, 3], rotations [B, gap, J, 4])`` of frames ``10..9+gap``."""
        if not v.has_ground_truth:
            raise ValueError(f"variant {v.name} has no ground truth")
        sl = slice(CONTEXT, CONTEXT + v.gap)
        return self.positions[:, sl], self.global_rotations[:, sl]

    def ground_truth_local(self, v: Variant) -> tuple[Tensor, Tensor]:
        """Local ``(rotations [B, gap, J, 4], roots [B, gap, 3])`` of frames ``10..9+gap``."""
        if not v.has_ground_truth:
            raise ValueError(f"variant {v.name} has no ground truth")
        sl = slice(CONTEXT, CONTEXT + v.gap)
        return self.rotations[:, sl], self.roots[:, sl]

    def context_clip(self, b: int) -> Clip:
        """Case ``b``'s context frames as a clip (world frame)."""
        return Clip(self.skeletons[b], self.rotations[b, :CONTEXT], self.roots[b, :CONTEXT], self.fps,
                    name=self.cases[b].id)

    def target_clip(self, b: int, v: Variant, frames: int = 1) -> Clip:
        rot, root = self.targets(v, frames)
        return Clip(self.skeletons[b], rot[b], root[b], self.fps, name=f"{self.cases[b].id}:target")

    def forward(self, local_rotations: Tensor, roots: Tensor) -> tuple[Tensor, Tensor]:
        """World ``(positions, rotations)`` of generated frames ``[B, N, J, 4]``, ``[B, N, 3]`` on each case's rig."""
        return forward_kinematics(quat_normalize(local_rotations), roots, self.offsets.unsqueeze(1), self.skeleton.parents)

    @cached_property
    def canonical_positions(self) -> Tensor:
        """``[B, SPAN, J, 3]`` ground-truth positions in the canonical frame of frame 9."""
        return self.frame.positions_to(self.positions)

    @cached_property
    def canonical_rotations(self) -> Tensor:
        return self.frame.rotations_to(self.global_rotations)
