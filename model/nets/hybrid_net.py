"""Capture and network together: a transition plays the matching source's window (of its style clip's own frames
first, else of the motion database) where it matches the request well (its match cost at most ``limit``), and the
RSMT sampler makes the motion where the data runs out.

Both run in lockstep for every character: the sampler warms up on the context and steps every frame, reading the
pose the character actually has, so a played character's recurrent state follows the capture it plays. A retarget or
a new duration plans again and decides again: a character whose new request the database does not cover goes on
from the pose it stands in under the sampler, warm. Its state and style context hold the sampler's fields and the
matching source's (:mod:`model.nets.matching_net`), so the engine handles it like any network
(:mod:`model.nets.transition_net`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import ClassVar

import torch
from torch import nn

from model.nets.matching_net import DatabaseStyle, MatchingNet, PlayState
from model.nets.pose_state import PoseState
from model.nets.sampler import SamplerState, StyleContext, TransitionSampler
from model.nets.tensor_record import TensorRecord

Tensor = torch.Tensor
MATCH_COST_LIMIT = 40.0  # the highest window match cost that plays (standardised feature distance; chosen on val)


@dataclass
class HybridState(TensorRecord):
    """The sampler's state (:class:`SamplerState`'s fields), the plan (:class:`PlayState`'s) and ``played [B]``."""

    POSES: ClassVar[tuple[str, ...]] = ("pose",)
    FIXED: ClassVar[tuple[str, ...]] = (*SamplerState.FIXED, "plan_rel", "plan_rot", "plan_root", "frames", "played")

    h: Tensor
    c: Tensor
    pose: PoseState
    phase: Tensor
    target_vec: Tensor
    target_pos: Tensor
    target_rot: Tensor
    target_emb: Tensor
    tta: Tensor
    noise: Tensor
    plan_rel: Tensor
    plan_rot: Tensor
    plan_root: Tensor
    frames: Tensor
    played: Tensor  # [B] bool: the character plays its plan

    def sampler_part(self) -> SamplerState:
        return SamplerState(**{f.name: getattr(self, f.name) for f in fields(SamplerState)})

    def play_part(self) -> PlayState:
        return PlayState(**{f.name: getattr(self, f.name) for f in fields(PlayState)})


@dataclass
class HybridStyle(TensorRecord):
    """The sampler's style context (:class:`StyleContext`'s fields) and the matching source's
    (:class:`DatabaseStyle`'s: the database rows of the style and the style clip's own frames)."""

    TIME_AXES: ClassVar[dict[str, int]] = {**StyleContext.TIME_AXES, **DatabaseStyle.TIME_AXES}

    gamma1: Tensor
    beta1: Tensor
    keys1: Tensor
    values1: Tensor
    gamma2: Tensor
    beta2: Tensor
    keys2: Tensor
    values2: Tensor
    mask: Tensor
    rows: Tensor
    clip_pos: Tensor
    clip_rot: Tensor
    clip_segment: Tensor

    def sampler_part(self) -> StyleContext:
        return StyleContext(**{f.name: getattr(self, f.name) for f in fields(StyleContext)})

    def matching_part(self) -> DatabaseStyle:
        return DatabaseStyle(**{f.name: getattr(self, f.name) for f in fields(DatabaseStyle)})


class HybridNet(nn.Module):
    """The matching source where its match cost is at most ``limit``, the sampler elsewhere (the module's notes)."""

    state_type = HybridState
    style_type = HybridStyle

    def __init__(self, sampler: TransitionSampler, matching: MatchingNet, limit: float) -> None:
        super().__init__()
        self.sampler, self.matching, self.limit = sampler, matching, limit
        self.config = sampler.config

    def encode_style(self, features: Tensor) -> Tensor:
        return features  # each part encodes the clip's features its own way (style_context)

    def style_context(self, code: Tensor) -> HybridStyle:
        ctx = self.sampler.style_context(self.sampler.encode_style(code))
        played = self.matching.style_context(self.matching.encode_style(code))
        return HybridStyle(**{f.name: getattr(ctx, f.name) for f in fields(StyleContext)},
                           **{f.name: getattr(played, f.name) for f in fields(DatabaseStyle)})

    def noise(self, generator: torch.Generator | None) -> Tensor:
        return self.sampler.noise(generator)

    def begin(self, context: PoseState, target: PoseState, frames: Tensor, noise: Tensor, style: HybridStyle, *,
              velocity_known: Tensor | None = None) -> HybridState:
        s = self.sampler.begin(context, target, frames, noise, style.sampler_part(), velocity_known=velocity_known)
        now = context.index((slice(None), -1))
        rel, rot, root, cost = self.matching.plan(now, target, frames.long(), style.rows, style.matching_part())
        return HybridState(**{f.name: getattr(s, f.name) for f in fields(SamplerState)}, plan_rel=rel, plan_rot=rot,
                           plan_root=root, frames=frames.long().clamp(1, self.matching.horizon - 1),
                           played=cost <= self.limit)

    def step(self, state: HybridState, style: HybridStyle) -> tuple[HybridState, dict[str, Tensor]]:
        made, out = self.sampler.step(state.sampler_part(), style.sampler_part())
        played, _ = self.matching.step(state.play_part(), None)  # type: ignore[arg-type]  # it reads no style
        use = state.played
        a, b = played.pose, made.pose
        pose = PoseState(torch.where(use.view(-1, 1, 1), a.rel, b.rel), torch.where(use.view(-1, 1, 1), a.vel, b.vel),
                         torch.where(use.view(-1, 1, 1), a.rot, b.rot), torch.where(use.view(-1, 1), a.root_xz, b.root_xz))
        values = {f.name: getattr(made, f.name) for f in fields(SamplerState)}
        values["pose"] = pose
        return HybridState(**values, plan_rel=state.plan_rel, plan_rot=state.plan_rot, plan_root=state.plan_root,
                           frames=state.frames, played=state.played), out

    def target_fields(self, state: HybridState, target: PoseState, velocity_known: Tensor,
                      frames: Tensor) -> dict[str, Tensor]:
        """The sampler's target, a new plan from where the character stands, and whether it plays it (from any
        database row: the state does not keep its style's)."""
        rows = torch.ones(state.pose.rel.shape[0], self.matching.db.frames, dtype=torch.bool)
        rel, rot, root, cost = self.matching.plan(state.pose, target, frames.long(), rows)
        return {**self.sampler.target_fields(state.sampler_part(), target, velocity_known, frames), "plan_rel": rel,
                "plan_rot": rot, "plan_root": root, "frames": frames.long().clamp(1, self.matching.horizon - 1),
                "played": cost <= self.limit}

    def reencoded(self, state: HybridState) -> dict[str, Tensor]:
        return self.sampler.reencoded(state.sampler_part())
