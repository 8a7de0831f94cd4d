"""Foot plant: a foot that stands still too high above the floor is brought down to its style's rise, and only then."""

from __future__ import annotations

import math

import pytest
import torch

from model.data.synthetic import synthetic_walk
from model.inference.output.foot_plant import PLANT_CAP, FootPlant, FootPlantStep
from model.inference.output.frame import StepParts
from model.inference.output.leg_chains import LegChains
from model.inference.output.pipeline import FrameSteps, OutputPipeline
from model.inference.output.settings import OutputConfig
from model.inference.traced_step import CompiledFrameOutput
from model.motion.kinematics import forward_kinematics
from model.motion.planted_feet import FREE_CM_S, PLANTED_CM_S, planted_rise, planted_weight
from model.motion.rotations import quat_to_sixd
from model.nets.pose_state import state_from_positions

FRAMES = 12
RAISED_CM = 8.0


@pytest.fixture(scope="module")
def walk():
    return synthetic_walk(frames=30)


def _hovering(walk, speed_cm_frame: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
    """FRAMES frames of one standing pose whose left ankle is bent up RAISED_CM, the body moving ``speed_cm_frame``
    along x a frame: rotations ``[T, J, 4]`` and roots ``[T, 3]``."""
    sk = walk.skeleton
    legs = LegChains(sk)
    rot, root = walk.rotations[:1], walk.root_positions[:1]
    pos, grot = legs.poses(rot, root)
    target = pos[:, -1].clone()
    target[:, 0, 1] += RAISED_CM
    lifted = legs.bend(rot, pos, grot, target, torch.tensor([[True, False]]))
    roots = root.repeat(FRAMES, 1)
    roots[:, 0] += speed_cm_frame * torch.arange(FRAMES)
    return lifted.repeat(FRAMES, 1, 1), roots


def _run(walk, rot, root, cap: float, traced: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """The frames after the first two through the foot plant alone (the first two are its context)."""
    sk = walk.skeleton
    parts = StepParts(sk, 30.0, OutputConfig(foot_plant=True))
    step = FootPlantStep.build(parts)
    assert step is not None
    output = FrameSteps(sk, {"foot_plant": step})
    fn = CompiledFrameOutput(output) if traced else output
    gpos, grot = forward_kinematics(rot, root, sk.offsets_tensor(), sk.parents)
    states = state_from_positions(gpos.unsqueeze(0), quat_to_sixd(grot).unsqueeze(0), sk.roles.root)
    mem = {**output.start(rot[:2], root[:2]), PLANT_CAP: torch.tensor([cap])}
    rots, roots = [], []
    for t in range(2, FRAMES):
        r, p, mem = fn(states.index((slice(None), t)), torch.zeros(1), torch.zeros(1, 3),
                       torch.full((1,), FRAMES - 1 - t), mem)
        rots.append(r[0])
        roots.append(p[0])
    return torch.stack(rots), torch.stack(roots)


def _lowest(walk, rot, root) -> torch.Tensor:
    """Each foot's lowest joint height ``[T, 2]``."""
    sk = walk.skeleton
    plant = FootPlant(sk, 30.0, LegChains(sk))
    return plant.lowest(plant.legs.kinematics(rot, root)[0])


def test_planted_weight_is_one_when_still_and_zero_when_free():
    w = planted_weight(torch.tensor([0.0, PLANTED_CM_S, (PLANTED_CM_S + FREE_CM_S) / 2, FREE_CM_S, 300.0]))
    assert w.tolist() == pytest.approx([1.0, 1.0, 0.5, 0.0, 0.0])


def test_a_still_foot_in_the_air_comes_down_to_its_style_rise_and_the_other_is_untouched(walk):
    rot, root = _hovering(walk)
    before = _lowest(walk, rot, root)
    floor = float(before[:2].min())
    assert float(before[0, 0]) - floor > RAISED_CM - 1.0  # the left foot hovers
    cap = 1.5
    out_rot, out_root = _run(walk, rot, root, cap)
    after = _lowest(walk, out_rot, out_root)
    assert torch.allclose(after[:, 0], torch.full_like(after[:, 0], floor + cap), atol=0.05)  # down to the rise
    assert torch.allclose(after[:, 1], before[2:, 1], atol=1e-4)  # the foot on the floor stays
    assert torch.equal(out_root, root[2:])  # the body is not moved
    left = [walk.skeleton.roles.left_foot[0]]
    pos_in = forward_kinematics(rot, root, walk.skeleton.offsets_tensor(), walk.skeleton.parents)[0][2:, left]
    pos_out = forward_kinematics(out_rot, out_root, walk.skeleton.offsets_tensor(), walk.skeleton.parents)[0][:, left]
    assert torch.allclose(pos_out[..., [0, 2]], pos_in[..., [0, 2]], atol=0.05)  # straight down, not over the ground


def test_free_feet_and_a_character_without_a_measured_rise_are_left_alone(walk):
    for rot, root, cap in (*_hovering(walk, speed_cm_frame=3.0), 1.5), (*_hovering(walk), math.inf):
        out_rot, out_root = _run(walk, rot, root, cap)
        assert torch.allclose(_lowest(walk, out_rot, out_root), _lowest(walk, rot[2:], root[2:]), atol=1e-4)


def test_the_traced_foot_plant_brings_feet_down_as_eager_does(walk):
    rot, root = _hovering(walk)
    eager = _run(walk, rot, root, 1.0)
    traced = _run(walk, rot, root, 1.0, traced=True)
    assert torch.allclose(eager[0], traced[0], atol=1e-4) and torch.allclose(eager[1], traced[1], atol=1e-4)


def test_the_pipeline_runs_it_last_and_only_when_asked(walk):
    sk = walk.skeleton
    assert OutputPipeline(sk, 30.0, OutputConfig()).step("foot_plant") is None
    on = OutputPipeline(sk, 30.0, OutputConfig(foot_plant=True, foot_lock=True, floor=True))
    assert list(on.frame.steps)[-1] == "foot_plant"
    assert OutputConfig.from_dict(OutputConfig(foot_plant=True).to_dict()).foot_plant
    assert OutputConfig(foot_plant=True).with_overrides(floor=True).foot_plant
    assert not OutputConfig(foot_plant=True).with_overrides(foot_plant=False).foot_plant
    assert OutputConfig().with_overrides(foot_plant=True).foot_plant


def test_the_capture_rise_is_that_of_its_still_feet():
    """Joints: left ankle, left toe, right ankle, right toe; the left foot still, its toe 3 cm up; the right
    foot's toe on the floor (y = 0), swinging at 300 cm/s, then standing."""
    pos = torch.zeros(10, 4, 3)
    pos[:, [0, 2], 1] = 8.0
    pos[:, 1, 1] = 3.0
    pos[:, [2, 3], 0] = 10.0 * torch.arange(10.0).unsqueeze(-1)
    feet = ((0, 1), (2, 3))
    assert planted_rise(pos, feet, 30.0) == pytest.approx(3.0)  # the swinging foot is not planted
    pos[:, 1, 1] = 12.0  # the left foot's lowest joint is now its ankle, 8 cm up
    assert planted_rise(pos, feet, 30.0) == pytest.approx(8.0)
    pos[5:, [2, 3], 0] = 40.0  # the right foot stands from frame 5, on the floor: the left one still counts
    assert planted_rise(pos, feet, 30.0) == pytest.approx(8.0)
    pos[:, :2, 0] = 10.0 * torch.arange(10.0).unsqueeze(-1)  # the left foot swings too: only the right one plants
    assert planted_rise(pos, feet, 30.0) == pytest.approx(0.0)
    assert planted_rise(pos[:1], feet, 30.0) == 0.0


def test_an_engine_says_when_its_foot_plant_can_move_no_foot(caplog):
    import logging

    from model.inference.bundle import DEFAULT_BUNDLE, Bundle
    from model.inference.engine import Engine
    from model.inference.overrides import Overrides

    bundle = Bundle.load(DEFAULT_BUNDLE)  # its gait limits predate the planted rise
    with caplog.at_level(logging.WARNING, logger="model.inference.engine"):
        Engine(bundle, threads=1)
        assert not caplog.records  # off: nothing to say
        engine = Engine(bundle, threads=1, overrides=Overrides(foot_plant=True))
    assert engine.pipeline.step("foot_plant") is not None
    assert [r.getMessage() for r in caplog.records] == [
        f"the foot plant is on but {bundle.meta.name}'s gait limits give no style a planted rise: it moves no foot "
        "(rsmt bundle gait-limits measures them)"]
