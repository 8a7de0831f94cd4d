"""Tests for model.motion.bvh_clip: BVH documents to and from Clips, checked against an independent reference.

The fixture files are described in bvh_fixtures.py.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.motion.bvh import BvhDocument, BvhJoint
from model.motion.bvh_clip import dump_clip, from_clip, load_clip, to_clip
from model.motion.rotations import quat_to_matrix
from model.motion.skeleton import SkeletonError, SkeletonProfile
from tests.model.motion.bvh_fixtures import BANDAI, MIXED
from tests.model.motion.bvh_reference import angle_between_matrices, channel_column, euler_matrix, reference_world, wrapped_diff
from tests.model.motion.rotation_angle import quat_angle

ORDERS = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")

MIXED_PROFILE = SkeletonProfile(
    name="test-mixed", root="Hips", head="Head", left_foot=("Foot_L",), right_foot=("Foot_R",),
    left_hip="Leg_L", right_hip="Leg_R", left_shoulder="Arm_L", right_shoulder="Arm_R",
    mirror=(("(.*)_L", r"\1_R"),),
)
# Every role on one joint: lets a one-joint rig become a Clip.
SINGLE_PROFILE = SkeletonProfile(
    name="test-single", root="Hips", head="Hips", left_foot=("Hips",), right_foot=("Hips",),
    left_hip="Hips", right_hip="Hips", left_shoulder="Hips", right_shoulder="Hips", mirror=(),
)


# ---------------------------------------------------------------------- conversion to and from Clip


def _clip_world_check(doc: BvhDocument, clip, atol: float = 1e-9) -> None:
    """Clip FK equals the reference evaluator on the BVH itself, for every joint the clip keeps."""
    ref = reference_world(doc)
    positions, rotations = clip.global_transforms()
    matrices = quat_to_matrix(rotations).numpy()
    for j, name in enumerate(clip.skeleton.names):
        want_pos, want_rot = ref[name]
        np.testing.assert_allclose(positions[:, j].numpy(), want_pos, rtol=0, atol=atol, err_msg=name)
        assert angle_between_matrices(matrices[:, j], want_rot).max() < 1e-7, name


def test_bandai_rig_folds_joint_root_into_hips() -> None:
    doc = BvhDocument.read(BANDAI)
    clip = to_clip(doc, name="rig", dtype=torch.float64)  # profile auto-detected
    sk = clip.skeleton
    assert sk.roles.profile == "bandai-namco"
    assert len(doc.joints) == 22 and sk.num_joints == 21 and sk.names[0] == "Hips"
    assert "joint_Root" not in sk.names
    assert sk.offsets[0] == (0.0, 0.0, 0.0)
    assert clip.fps == 30.0 and clip.name == "rig" and clip.num_frames == 3
    # joint_Root moves and turns in this fixture, so the Hips world position is not its channels.
    ref = reference_world(doc)
    hips_channels = doc.motion[:, channel_column(doc, "Hips", "Xposition"):][:, :3]
    assert np.abs(ref["Hips"][0] - hips_channels).max() > 1.0
    np.testing.assert_allclose(clip.root_positions.numpy(), ref["Hips"][0], rtol=0, atol=1e-9)
    # Like the real takes, non-root position channels jitter by ~1e-5 cm around the bone length,
    # and the clip keeps their mean: positions agree to that jitter times the chain length.
    _clip_world_check(doc, clip, atol=1e-4)
    # Non-root position channels replace the OFFSET: offsets are the channels' means.
    spine = doc.joint_index("Spine")
    cols = doc.channel_slices()[spine]
    np.testing.assert_allclose(sk.offsets[sk.index("Spine")], doc.motion[:, cols][:, :3].mean(0), atol=1e-12)
    assert {sk.names[j] for j, _ in sk.end_sites} == {"Head", "Hand_L", "Hand_R", "Toes_L", "Toes_R"}


def test_mixed_rig_forward_kinematics_matches_reference() -> None:
    doc = BvhDocument.read(MIXED)
    clip = to_clip(doc, profile=MIXED_PROFILE, dtype=torch.float64)
    assert clip.skeleton.names == doc.names
    assert clip.fps == 120.0  # 0.008333 s is 1/120 rounded
    _clip_world_check(doc, clip)
    ends = dict(clip.skeleton.end_sites)
    assert ends[clip.skeleton.index("Head")] == (0.0, 12.0, 0.0)
    assert ends[clip.skeleton.index("Hand_R")] == (-8.0, 0.0, 0.0)
    # Leg_R has only a Yposition channel: it replaces y, the OFFSET keeps x and z.
    assert clip.skeleton.offsets[clip.skeleton.index("Leg_R")] == pytest.approx((-9.0, -5.0, 0.0))


def test_rotations_survive_to_clip_and_from_clip() -> None:
    doc = BvhDocument.read(MIXED)
    clip = to_clip(doc, profile=MIXED_PROFILE, dtype=torch.float64)
    orders = {j.name: j.rotation_order for j in doc.joints if len(j.rotation_order) == 3}
    out = from_clip(clip, rotation_order=orders)
    assert out.names == doc.names
    assert out.frame_time == pytest.approx(1 / 120)
    in_ref, out_ref = reference_world(doc), reference_world(out)
    for joint in doc.joints:
        written = out.joints[out.joint_index(joint.name)]
        original = doc.motion[:, doc.channel_slices()[doc.joint_index(joint.name)]]
        angles = out.motion[:, out.channel_slices()[out.joint_index(joint.name)]]
        rot_cols = [k for k, c in enumerate(joint.channels) if c.endswith("rotation")]
        m_in = euler_matrix(original[:, rot_cols], joint.rotation_order)
        m_out = euler_matrix(angles[:, -3:], written.rotation_order)
        assert angle_between_matrices(m_in, m_out).max() < 1e-4, joint.name
        if joint.name in orders:
            assert written.rotation_order == joint.rotation_order
            middle = original[:, rot_cols][:, 1]
            away_from_lock = np.abs(np.abs(middle) - 90.0) > 0.1
            diff = wrapped_diff(original[:, rot_cols], angles[:, -3:])
            assert diff[away_from_lock].max() < 1e-4, joint.name
        # World positions agree except where the file animates or replaces bone translation.
        np.testing.assert_allclose(out_ref[joint.name][0], in_ref[joint.name][0], atol=1e-6)
    # And the written document comes back as the same clip.
    again = to_clip(BvhDocument.parse(out.format(precision=None)), profile=MIXED_PROFILE, dtype=torch.float64)
    assert quat_angle(again.rotations, clip.rotations).max() < 1e-9
    np.testing.assert_allclose(again.root_positions.numpy(), clip.root_positions.numpy(), atol=1e-12)


def _single_joint_doc(angles_deg: np.ndarray, order: str) -> BvhDocument:
    channels = ("Xposition", "Yposition", "Zposition") + tuple(f"{a}rotation" for a in order)
    positions = np.tile([1.0, 2.0, 3.0], (len(angles_deg), 1))
    return BvhDocument([BvhJoint("Hips", -1, (0, 0, 0), channels, (0, 1, 0))], 1 / 60, np.hstack([positions, angles_deg]))


angle_triplets = st.tuples(
    st.floats(-180.0, 180.0), st.floats(-90.0, 90.0), st.floats(-180.0, 180.0)
)


@settings(max_examples=150, deadline=None)
@given(order=st.sampled_from(ORDERS), frames=st.lists(angle_triplets, min_size=1, max_size=4))
def test_euler_round_trip_any_order(order: str, frames: list[tuple[float, float, float]]) -> None:
    angles = np.array(frames, dtype=np.float64)
    doc = _single_joint_doc(angles, order)
    clip = to_clip(doc, profile=SINGLE_PROFILE, dtype=torch.float64)
    # The quaternion is the rotation the BVH convention defines (independent numpy matrices).
    np.testing.assert_allclose(quat_to_matrix(clip.rotations[:, 0]).numpy(), euler_matrix(angles, order), atol=1e-12)
    out = from_clip(clip, rotation_order=order)
    assert out.joints[0].rotation_order == order
    written = out.motion[:, 3:]
    assert angle_between_matrices(euler_matrix(angles, order), euler_matrix(written, order)).max() < 1e-4
    away = np.cos(np.deg2rad(angles[:, 1])) > 1e-3
    assert wrapped_diff(angles, written)[away].max(initial=0.0) < 1e-4
    np.testing.assert_array_equal(out.motion[:, :3], doc.motion[:, :3])


def test_joints_outside_the_root_subtree_are_dropped() -> None:
    text = """HIERARCHY
ROOT World
{
\tOFFSET 0 0 0
\tCHANNELS 3 Xposition Yposition Zposition
\tJOINT Camera
\t{
\t\tOFFSET 0 150 -300
\t\tCHANNELS 1 Yrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0 0 1
\t\t}
\t}
\tJOINT Hips
\t{
\t\tOFFSET 5 0 0
\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0 10 0
\t\t}
\t}
}
MOTION
Frames: 2
Frame Time: 0.04
1 2 3 45 10 20 30
2 2 3 46 11 21 31
"""
    doc = BvhDocument.parse(text)
    clip = to_clip(doc, profile=SINGLE_PROFILE, dtype=torch.float64)
    assert clip.skeleton.names == ("Hips",)
    assert clip.skeleton.end_sites == ((0, (0.0, 10.0, 0.0)),)
    assert clip.fps == 25.0
    np.testing.assert_allclose(clip.root_positions.numpy(), [[6, 2, 3], [7, 2, 3]])
    _clip_world_check(doc, clip)


def test_animated_bone_translation_warns(caplog: pytest.LogCaptureFixture) -> None:
    doc = BvhDocument.read(MIXED)
    motion = doc.motion.copy()
    col = channel_column(doc, "Neck", "Xposition")
    motion[:, col] = [0.0, 0.5, 1.0, 0.5, 0.0]
    with caplog.at_level(logging.WARNING, logger="model.motion.bvh_clip"):
        clip = to_clip(BvhDocument(doc.joints, doc.frame_time, motion), profile=MIXED_PROFILE, name="moving")
    records = [r for r in caplog.records if r.name == "model.motion.bvh_clip"]
    assert len(records) == 1
    message = records[0].getMessage()
    assert "Neck" in message and "Xposition" in message and "0.6" in message and "moving" in message
    assert clip.skeleton.offsets[clip.skeleton.index("Neck")][0] == pytest.approx(0.4)


def test_constant_bone_translation_does_not_warn(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="model.motion.bvh_clip"):
        to_clip(BvhDocument.read(BANDAI))
        to_clip(BvhDocument.read(MIXED), profile=MIXED_PROFILE)
    assert not [r for r in caplog.records if r.name == "model.motion.bvh_clip"]


def test_profile_errors() -> None:
    doc = BvhDocument.read(MIXED)
    with pytest.raises(SkeletonError, match="no built-in skeleton profile fits"):
        to_clip(doc)
    with pytest.raises(SkeletonError, match="missing joint"):
        to_clip(BvhDocument.read(MIXED), profile="100style")
    clip = to_clip(BvhDocument.read(BANDAI), profile="bandai-namco")
    assert clip.skeleton.roles.profile == "bandai-namco"


@pytest.mark.parametrize("fps_in,expected", [(0.0333333, 30.0), (0.008333, 120.0), (0.04, 25.0), (1 / 29.97, 29.97)])
def test_fps_from_frame_time(fps_in: float, expected: float) -> None:
    doc = _single_joint_doc(np.zeros((2, 3)), "ZXY")
    doc.frame_time = fps_in
    assert to_clip(doc, profile=SINGLE_PROFILE).fps == pytest.approx(expected, rel=1e-12)


def test_from_clip_layout_and_validation() -> None:
    clip = to_clip(BvhDocument.read(BANDAI), dtype=torch.float32)
    doc = from_clip(clip, rotation_order="yxz")
    assert doc.joints[0].channels == ("Xposition", "Yposition", "Zposition", "Yrotation", "Xrotation", "Zrotation")
    assert all(j.channels == ("Yrotation", "Xrotation", "Zrotation") for j in doc.joints[1:])
    assert doc.joints[0].offset == (0.0, 0.0, 0.0)
    leaves = {doc.names[i] for i, kids in enumerate(doc.children()) if not kids}
    assert {j.name for j in doc.joints if j.end_site is not None} == leaves
    assert doc.frame_time == pytest.approx(1 / 30)
    assert doc.motion.shape == (3, 3 + 3 * 21)
    with pytest.raises(ValueError, match="rotation order"):
        from_clip(clip, rotation_order="XXY")


def test_load_and_dump_clip(tmp_path: Path) -> None:
    from_path = load_clip(BANDAI)
    assert from_path.name == "bandai_namco_rig" and from_path.rotations.dtype == torch.float32
    text = BANDAI.read_text()
    from_text = load_clip("\n  " + text, dtype=torch.float64)
    assert from_text.name == "" and from_text.rotations.dtype == torch.float64
    assert quat_angle(from_text.rotations, from_path.rotations.double()).max() < 1e-6

    slow = load_clip(MIXED, profile=MIXED_PROFILE, fps=60)
    assert slow.fps == 60 and slow.num_frames == 3  # 5 frames at 120 fps span 4/120 s

    dumped = dump_clip(from_path)
    (tmp_path / "out.bvh").write_text(dumped)
    back = load_clip(tmp_path / "out.bvh", dtype=torch.float64)
    assert back.skeleton.names == from_path.skeleton.names
    assert quat_angle(back.rotations, from_path.rotations.double()).max() < 1e-5
    np.testing.assert_allclose(back.global_positions().numpy(), from_path.global_positions().double().numpy(), atol=1e-3)


# ---------------------------------------------------------------------- the real takes


@pytest.mark.real_data
def test_every_real_take_parses_and_converts(shared_data: Path, caplog: pytest.LogCaptureFixture, record_property) -> None:
    files = sorted((shared_data / "data").glob("*.bvh"))
    assert files, f"no .bvh takes under {shared_data / 'data'}"
    # Torch's intra-op threads only add synchronisation to these small per-take tensors (and
    # stall badly when the cores are shared); one thread is several times faster here.
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    parse_s = convert_s = 0.0
    frames = 0
    try:
        with caplog.at_level(logging.WARNING, logger="model.motion.bvh_clip"):
            for path in files:
                t0 = time.perf_counter()
                doc = BvhDocument.read(path)
                t1 = time.perf_counter()
                clip = to_clip(doc, name=path.stem)
                t2 = time.perf_counter()
                parse_s += t1 - t0
                convert_s += t2 - t1
                frames += clip.num_frames
                assert doc.names[:2] == ("joint_Root", "Hips") and len(doc.joints) == 22, path.name
                assert doc.num_channels == 132 and doc.num_frames > 0, path.name
                assert clip.skeleton.num_joints == 21 and clip.skeleton.names[0] == "Hips", path.name
                assert clip.fps == 30.0, path.name
                # Position channels replace the OFFSET: adding them would put the hips ~180 cm up.
                hips_height = float(clip.root_positions[:, 1].median())
                assert 40.0 < hips_height < 130.0, (path.name, hips_height)
                assert torch.isfinite(clip.rotations).all() and torch.isfinite(clip.root_positions).all()
    finally:
        torch.set_num_threads(threads)
    assert not [r.getMessage() for r in caplog.records if r.name == "model.motion.bvh_clip"]
    record_property("bvh_parse_seconds", round(parse_s, 2))
    record_property("bvh_to_clip_seconds", round(convert_s, 2))
    print(f"\n{len(files)} takes, {frames} frames: parse {parse_s:.1f} s, to_clip {convert_s:.1f} s")
