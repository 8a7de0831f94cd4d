"""The way back from the style encoder's input to a clip's global motion: exact up to where and which way the clip
starts, and a new segment where joined clips meet."""

from __future__ import annotations

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.data.synthetic import synthetic_walk
from model.motion.clip import Clip
from model.motion.features import facing_yaw, local_frame_features
from model.motion.features_inverse import global_frames
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_mul, quat_normalize, quat_rotate, yaw_quat

Tensor = torch.Tensor


def _global(clip: Clip) -> tuple[Tensor, Tensor]:
    sk = clip.skeleton
    return forward_kinematics(quat_normalize(clip.rotations), clip.root_positions, sk.offsets_tensor(), sk.parents)


def _from_first_kept(clip: Clip) -> tuple[Tensor, Tensor]:
    """Frames 1.. of ``clip`` turned and moved so frame 1 faces +Z over the origin (what the inverse rebuilds)."""
    pos, rot = _global(clip)
    sk = clip.skeleton
    ground = pos[1, sk.roles.root] * torch.tensor([1.0, 0.0, 1.0])
    turn = yaw_quat(-facing_yaw(pos[1], sk)).expand(pos.shape[0] - 1, pos.shape[1], 4)
    return quat_rotate(turn, pos[1:] - ground), quat_mul(turn, rot[1:])


def _same_rotations(a: Tensor, b: Tensor) -> float:
    return float(torch.minimum((a - b).abs().amax(-1), (a + b).abs().amax(-1)).max())


@settings(max_examples=25, deadline=None)
@given(speed=st.floats(40.0, 250.0), turn=st.floats(-120.0, 120.0), cadence=st.floats(0.5, 1.6),
       yaw=st.floats(-180.0, 180.0), stride=st.floats(5.0, 40.0), x=st.floats(-500.0, 500.0))
def test_the_features_give_back_the_clip_s_motion(speed: float, turn: float, cadence: float, yaw: float, stride: float,
                                                  x: float) -> None:
    walk = synthetic_walk(frames=90, speed_cm_s=speed, turn_deg_s=turn, cadence_hz=cadence, start_yaw_deg=yaw,
                          stride_deg=stride)
    walk = Clip(walk.skeleton, walk.rotations, walk.root_positions + torch.tensor([x, 0.0, -x]), walk.fps)
    pos, rot = _global(walk)
    back_pos, back_rot, segment = global_frames(local_frame_features(pos, rot, walk.skeleton), walk.skeleton)
    want_pos, want_rot = _from_first_kept(walk)
    assert float((back_pos - want_pos).abs().max()) < 0.01  # cm, float32 sums over 89 frames
    assert _same_rotations(back_rot, want_rot) < 1e-4
    assert segment.tolist() == [0] * 89


def test_joined_clips_are_separate_segments_each_given_back() -> None:
    a = synthetic_walk(frames=60, speed_cm_s=150.0, turn_deg_s=30.0)
    b = synthetic_walk(frames=50, speed_cm_s=70.0, turn_deg_s=-40.0, cadence_hz=0.7, start_yaw_deg=90.0)
    joined = torch.cat([local_frame_features(*_global(c), c.skeleton) for c in (a, b)])
    pos, _, segment = global_frames(joined, a.skeleton)
    assert segment.tolist() == [0] * 59 + [1] * 49
    assert float((pos[:59] - _from_first_kept(a)[0]).abs().max()) < 0.01
    # The second clip starts wherever the first left off, but its own motion is exact from there.
    second = pos[59:]
    want = _from_first_kept(b)[0]
    sk = a.skeleton
    ground = second[0, sk.roles.root] * torch.tensor([1.0, 0.0, 1.0])
    turn = yaw_quat(-facing_yaw(second[0], sk)).expand_as(second[..., :1].expand(-1, -1, 4))
    assert float((quat_rotate(turn, second - ground) - want).abs().max()) < 0.01
