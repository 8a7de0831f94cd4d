"""Checks on the real Bandai-Namco takes (skipped with a reason when the data is absent)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from model.motion.bvh_clip import load_clip
from model.motion.features import facing_yaw, features_to_local
from model.motion.kinematics import forward_kinematics
from model.motion.mirror import mirror_reflections
from tests.model.motion.clip_forms import bone_lengths, clip_features, mirror_clip

pytestmark = [pytest.mark.real_data, pytest.mark.usefixtures("one_thread")]


@pytest.fixture(scope="module")
def takes(shared_data: Path) -> list[Path]:
    files = sorted((shared_data / "data").glob("*.bvh"))
    assert len(files) > 2000, f"expected the 2601 shared takes, found {len(files)}"
    return files


def _sample(files: list[Path], n: int) -> list[Path]:
    return files[:: max(1, len(files) // n)]


def test_bodies_are_plausible(takes):
    for path in _sample(takes, 120):
        clip = load_clip(path)
        sk = clip.skeleton
        pos = clip.global_positions()
        toes = pos[:, [sk.index("Toes_L"), sk.index("Toes_R")], 1]
        ankles = pos[:, [sk.index("Foot_L"), sk.index("Foot_R")], 1]
        toe_level = toes.min().item()
        # The toe joints rest ~4 cm above the floor, the ankles ~12 cm (data README).
        assert 0.0 <= toe_level <= 8.0, (path.name, toe_level)
        assert 8.0 <= ankles.min().item() <= 16.0, path.name
        # "Head" is the skull base: 125-140 cm above the toe level for these adult performers.
        head = (pos[:, sk.roles.head, 1] - toe_level).median().item()
        assert 120.0 <= head <= 160.0, (path.name, head)
        hips = (pos[:, sk.roles.root, 1] - toe_level).median().item()
        assert 70.0 <= hips <= 100.0, (path.name, hips)
        # Joints stay connected: every bone keeps its rest length.
        lengths = (pos[:, 1:] - pos[:, list(sk.parents[1:])]).norm(dim=-1)
        rest = bone_lengths(sk)[1:]
        assert torch.allclose(lengths, rest.expand_as(lengths), atol=1e-2)


def _total_turn(clip) -> float:
    yaw = facing_yaw(clip.global_positions(), clip.skeleton)
    step = torch.remainder(yaw[1:] - yaw[:-1] + math.pi, 2 * math.pi) - math.pi
    return step.sum().item()


def test_mirroring_a_left_turn_gives_a_right_turn(takes):
    lefts = [p for p in takes if "_walk-turn-left_" in p.name][:5]
    assert lefts
    reference = torch.cat([load_clip(p).rotations for p in _sample(takes, 40)])
    for path in lefts:
        clip = load_clip(path, dtype=torch.float64)
        turn = _total_turn(clip)
        assert turn > math.radians(45), f"{path.name} turns {math.degrees(turn):.0f} degrees"
        reflections = mirror_reflections(clip.skeleton, reference)
        mirrored = mirror_clip(clip, reflections)
        assert _total_turn(mirrored) == pytest.approx(-turn, abs=1e-3)
        back = mirror_clip(mirrored, reflections)
        assert (back.global_positions() - clip.global_positions()).abs().max() < 1e-5


def test_features_round_trip_to_skeleton(takes):
    worst = 0.0
    for path in _sample(takes, 60):
        clip = load_clip(path)
        feats, frame = clip_features(clip, reference_frame=min(9, clip.num_frames - 1))
        local, root = features_to_local(feats.positions, feats.rotations_6d, clip.skeleton, frame)
        sk = clip.skeleton
        pos, _ = forward_kinematics(local, root, sk.offsets_tensor(), sk.parents)
        worst = max(worst, (pos - clip.global_positions()).norm(dim=-1).max().item())
    assert worst < 0.1, f"features -> local -> FK is off by {worst:.4f} cm"
