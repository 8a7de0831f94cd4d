"""Properties of the gait measures: toe skate, backward share, airborne runs, toe rest height."""

from __future__ import annotations

import math

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.data.synthetic import synthetic_skeleton
from model.motion import gait
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_identity, yaw_quat

SK = synthetic_skeleton()
TOES = gait.toe_joints(SK)


def _walk(frames: int, step: tuple[float, float], yaw: float, lift: float = 0.0) -> torch.Tensor:
    """``[1, frames, J, 3]`` the rest pose facing ``yaw``, its root moving ``step`` (x, z) cm per frame, raised by ``lift``."""
    rot = quat_identity((frames, len(SK.names)))
    rot[:, SK.roles.root] = yaw_quat(torch.full((frames,), yaw))
    t = torch.arange(frames, dtype=torch.float32)
    root = torch.stack([t * step[0], torch.full_like(t, 90.0 + lift), t * step[1]], -1)
    pos, _ = forward_kinematics(rot, root, SK.offsets_tensor(), SK.parents)
    return pos.unsqueeze(0)


def _rest(pos: torch.Tensor) -> float:
    return float(pos[0, 0, list(TOES), 1].min())


@settings(max_examples=25, deadline=None)
@given(st.floats(-math.pi, math.pi), st.integers(2, 40))
def test_planted_toes_do_not_skate(yaw: float, frames: int) -> None:
    pos = _walk(frames, (0.0, 0.0), yaw)
    assert float(gait.toe_skate(pos, TOES, _rest(pos))) == 0.0


@settings(max_examples=25, deadline=None)
@given(st.floats(0.5, 5.0), st.floats(-math.pi, math.pi))
def test_a_sliding_planted_foot_skates_at_its_speed(speed: float, yaw: float) -> None:
    pos = _walk(20, (speed * math.sin(yaw), speed * math.cos(yaw)), yaw)
    assert abs(float(gait.toe_skate(pos, TOES, _rest(pos))) - speed) < 1e-3


def test_toes_above_the_contact_height_do_not_count() -> None:
    pos = _walk(20, (0.0, 3.0), 0.0, lift=2.6)
    assert float(gait.toe_skate(pos, TOES, _rest(_walk(1, (0, 0), 0.0)))) == 0.0


@settings(max_examples=25, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(1.5, 8.0), st.booleans())
def test_backward_share_is_one_against_the_facing_and_zero_along_it(yaw: float, speed: float, back: bool) -> None:
    sign = -1.0 if back else 1.0
    pos = _walk(30, (sign * speed * math.sin(yaw), sign * speed * math.cos(yaw)), yaw)
    share = gait.backward_share(pos, SK, fps=30.0)
    assert float(share[0]) == (1.0 if back else 0.0)


def test_backward_share_is_nan_when_the_hips_stand_still() -> None:
    assert math.isnan(float(gait.backward_share(_walk(10, (0.0, 0.5), 0.0), SK, fps=30.0)[0]))  # 15 cm/s


def test_longest_airborne_run_counts_frames_with_both_toes_up() -> None:
    ground = _walk(30, (0.0, 1.0), 0.0)
    up = _walk(30, (0.0, 1.0), 0.0, lift=20.0)
    mixed = ground.clone()
    mixed[:, 5:12] = up[:, 5:12]
    mixed[:, 20:23] = up[:, 20:23]
    rest = _rest(ground)
    assert gait.longest_airborne(torch.cat([ground, mixed, up]), TOES, rest).tolist() == [0, 7, 30]
    one_foot = ground.clone()
    one_foot[:, :, TOES[0], 1] += 30.0
    assert int(gait.longest_airborne(one_foot, TOES, rest)[0]) == 0
