"""The motion-matching baseline: it lands exactly on the target, draws windows from the training split only, and
finds a window of the database when asked for it."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from model.data.preprocessed import MotionCache
from model.evaluation import CaseSet, build_cases
from model.evaluation.cases import CONTEXT, LAST_CONTEXT, variant
from model.evaluation.methods import Request
from model.evaluation.motion_matching import MotionMatchingMethod, key_joints, smoothstep
from model.evaluation.scoring import to_canonical
from tests.model.motion.rotation_angle import quat_angle

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def method(cache: MotionCache) -> MotionMatchingMethod:
    return MotionMatchingMethod(cache, cache.split.train)


@pytest.mark.parametrize("name", ["gap10", "gap40", "gap40-d-1", "gap40-turn+90", "gap40-dt2"])
def test_lands_exactly_on_the_target(cache: MotionCache, method: MotionMatchingMethod, name: str) -> None:
    cases = CaseSet.load(cache, build_cases(cache, cache.split.val))
    v = variant(name)
    rot, root = method.generate(cases, Request(v))
    assert rot.shape[1] == v.frames and root.shape[1] == v.frames
    target_rot, target_root = cases.targets(v, 1)
    assert torch.equal(root[:, -1], target_root[:, -1])
    assert float(quat_angle(rot[:, -1], target_rot[:, -1]).max()) < 1e-5
    out = to_canonical(cases, rot, root)
    # It starts from the last context frame: the first generated frame is one frame's motion away from it.
    step = (out.positions[:, 1] - out.positions[:, 0]).norm(dim=-1).max()
    assert float(step) < 30.0


def test_draws_windows_from_the_training_split_only(cache: MotionCache, method: MotionMatchingMethod) -> None:
    train = set(cache.split.train)
    assert set(method.owner.tolist()) == train
    for split in ("val", "test"):
        cases = CaseSet.load(cache, build_cases(cache, cache.split[split]))
        method.generate(cases, Request(variant("gap20")))
        assert method.last_choice and {take for take, _ in method.last_choice} <= train


def test_a_training_window_finds_itself_and_plays_back_unchanged(cache: MotionCache) -> None:
    train = list(cache.split.train)
    method = MotionMatchingMethod(cache, train)
    cases = CaseSet.load(cache, build_cases(cache, train)[:6])
    v = variant("gap20")
    rot, root = method.generate(cases, Request(v))
    for (take, frame), case in zip(method.last_choice, cases.cases):
        assert take == case.take and frame == case.start + LAST_CONTEXT
    gt_rot, gt_root = cases.ground_truth_local(v)
    assert float((root - gt_root).abs().max()) < 1e-3
    assert float(quat_angle(rot, gt_rot).max()) < 1e-3
    assert CONTEXT == LAST_CONTEXT + 1


def test_smoothstep_and_key_joints(cache: MotionCache) -> None:
    x = torch.linspace(0, 1, 11)
    s = smoothstep(x)
    assert float(s[0]) == 0.0 and float(s[-1]) == 1.0 and bool((s[1:] >= s[:-1]).all())
    names = [cache.skeleton(0).names[j] for j in key_joints(cache.skeleton(0))]
    assert names == ["Hips", "Head", "Hand_L", "Hand_R", "Foot_L", "Toes_L", "Foot_R", "Toes_R"]


def test_needs_a_training_take(cache: MotionCache, tmp_path: Path) -> None:
    with pytest.raises(ValueError):
        MotionMatchingMethod(cache, [])


def test_a_split_with_one_take_per_style_borrows_its_style_clips_from_the_fallback(cache: MotionCache) -> None:
    one_each: dict[str, int] = {}
    for i in cache.split.val:
        one_each.setdefault(cache.takes[i].style, i)
    takes = sorted(one_each.values())
    assert build_cases(cache, takes) == []  # no other take of the style in the split: no style clip
    train = set(cache.split.train)
    cases = build_cases(cache, takes, clip_fallback=sorted(train))
    assert cases and all(c.style_take in train and c.cross_take in train | set(takes) for c in cases)
    # A split that has its own clips ignores the fallback.
    assert build_cases(cache, cache.split.val) == build_cases(cache, cache.split.val, clip_fallback=sorted(train))
