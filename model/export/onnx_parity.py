"""Parity of two engines on one bundle: the same transitions run by both, compared joint by joint in the world.

The cases are procedural walks (:func:`model.data.synthetic.synthetic_walk`, no motion data needed) at
several speeds and turning rates, each a 40-frame transition from its last context frame to a target
further along the walk, with its own noise seed; every fifth case is retargeted mid-stream (at frame
20, its target moved 1 m sideways), as a game's stream does. Both engines run every case in one batch.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from model.data.synthetic import synthetic_walk
from model.inference.engine import CharacterBatch, Engine
from model.motion.clip import Clip
from model.motion.kinematics import forward_kinematics

Tensor = torch.Tensor

FRAMES = 40
RETARGET_AT = 20


@dataclass(frozen=True)
class Case:
    context: Clip
    target: Clip
    style: Clip
    seed: int
    retarget: Clip | None  # the new target, given at frame RETARGET_AT


def _moved(clip: Clip, sideways_cm: float) -> Clip:
    roots = clip.root_positions.clone()
    roots[:, 0] += sideways_cm
    return Clip(clip.skeleton, clip.rotations, roots, clip.fps, clip.name)


def parity_cases(count: int = 50, context: int = 10) -> list[Case]:
    """``count`` cases: walks from 60 to 200 cm/s turning -40 to 40 degrees a second; every fifth retargeted."""
    cases = []
    for i in range(count):
        walk = synthetic_walk(frames=context + 190, speed_cm_s=60.0 + 140.0 * ((i * 7) % count) / count,
                              turn_deg_s=-40.0 + 80.0 * ((i * 11) % count) / count, cadence_hz=0.8 + 0.05 * (i % 5),
                              phase=0.37 * i)
        end = context + FRAMES - 8 + (i % 17)  # targets from 8 frames short of the transition's end to 8 beyond
        target = walk.window(end - 1, end)  # the target frame alone, as a game sends it
        cases.append(Case(walk.window(0, context), target, walk.window(context + 60, context + 180), 1000 + i,
                          _moved(target, 100.0) if i % 5 == 4 else None))
    return cases


def run_cases(engine: Engine, cases: list[Case]) -> Tensor:
    """World joint positions ``[cases, FRAMES, J, 3]`` of every case run by ``engine`` in one batch."""
    batch = CharacterBatch(engine)
    chars = []
    for case in cases:
        style, _ = engine.encode_style(case.style)
        ch = engine.prepare(case.context, case.target, FRAMES, style, seed=case.seed)
        batch.add(ch)
        chars.append(ch)
    rows: dict[int, list[tuple[Tensor, Tensor]]] = {id(c): [] for c in chars}
    for frame in range(FRAMES):
        if frame == RETARGET_AT:
            for ch, case in zip(chars, cases):
                if case.retarget is not None:
                    engine.retarget(ch, batch, target=case.retarget)
        out = batch.step()
        for i, ch in enumerate(out.characters):
            rows[id(ch)].append((out.rotations[i], out.root_positions[i]))
        batch.drop_finished()
    offsets = engine.skeleton.offsets_tensor()
    positions = []
    for ch in chars:
        rot = torch.stack([r for r, _ in rows[id(ch)]])
        root = torch.stack([p for _, p in rows[id(ch)]])
        positions.append(forward_kinematics(rot, root, offsets, engine.skeleton.parents)[0])
    return torch.stack(positions)


def largest_joint_error_cm(first: Engine, second: Engine, cases: list[Case] | None = None) -> float:
    """The largest distance (cm) between the two engines' joints over every frame of every case."""
    cases = parity_cases() if cases is None else cases
    return float((run_cases(first, cases) - run_cases(second, cases)).norm(dim=-1).max())
