"""Tests for model.motion.bvh: lossless BVH round trips, errors with line numbers, and Clip conversion.

The fixtures in tests/fixtures are synthetic (random angles, made-up offsets):
``mixed_channels.bvh`` mixes channel orders and sets per joint; ``bandai_namco_rig.bvh`` has the
Bandai-Namco joint names and layout, with a moving, turning ``joint_Root`` above ``Hips``.
"""

from __future__ import annotations

import logging
import math
import re
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.motion.bvh import BvhDocument, BvhError, BvhJoint
from model.motion.bvh_clip import dump_clip, from_clip, load_clip, to_clip
from model.motion.rotations import quat_angle, quat_to_matrix
from model.motion.skeleton import SkeletonError, SkeletonProfile

FIXTURES = Path(__file__).resolve().parents[2] / "fixtures"
MIXED = FIXTURES / "mixed_channels.bvh"
BANDAI = FIXTURES / "bandai_namco_rig.bvh"

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


# ---------------------------------------------------------------------- an independent reference


def _axis_matrix(axis: str, degrees: np.ndarray) -> np.ndarray:
    a = np.deg2rad(degrees)
    c, s = np.cos(a), np.sin(a)
    m = np.zeros(a.shape + (3, 3))
    i = "XYZ".index(axis)
    j, k = (i + 1) % 3, (i + 2) % 3
    m[..., i, i] = 1.0
    m[..., j, j] = c
    m[..., k, k] = c
    m[..., k, j] = s
    m[..., j, k] = -s
    return m


def _euler_matrix(degrees: np.ndarray, order: str) -> np.ndarray:
    """``R = R_order[0](a0) @ R_order[1](a1) @ ...``, for any number of listed axes."""
    m = np.broadcast_to(np.eye(3), degrees.shape[:-1] + (3, 3)).copy()
    for n, axis in enumerate(order):
        m = m @ _axis_matrix(axis, degrees[..., n])
    return m


def reference_world(doc: BvhDocument) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """World ``(positions [T, 3], rotations [T, 3, 3])`` per joint name, straight from BVH semantics.

    Each joint's local transform is ``Translate(t) @ Rotate``, with ``t`` the OFFSET whose
    components are replaced by the joint's position channels, and ``Rotate`` the product of its
    rotation channels in the order listed. 4x4 matrices, composed parent first.
    """
    frames = doc.num_frames
    world: list[np.ndarray] = []
    col = 0
    out = {}
    for joint in doc.joints:
        values = doc.motion[:, col:col + len(joint.channels)]
        col += len(joint.channels)
        t = np.tile(np.array(joint.offset), (frames, 1))
        rot_cols, rot_axes = [], ""
        for k, ch in enumerate(joint.channels):
            if ch.endswith("position"):
                t[:, "XYZ".index(ch[0])] = values[:, k]
            else:
                rot_cols.append(k)
                rot_axes += ch[0]
        local = np.tile(np.eye(4), (frames, 1, 1))
        local[:, :3, :3] = _euler_matrix(values[:, rot_cols], rot_axes)
        local[:, :3, 3] = t
        m = local if joint.parent < 0 else world[joint.parent] @ local
        world.append(m)
        out[joint.name] = (m[:, :3, 3], m[:, :3, :3])
    return out


def _angle_between_matrices(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angle of ``a^T b`` in degrees, accurate for tiny angles (chord formula)."""
    chord = np.linalg.norm(a - b, axis=(-2, -1)) / (2.0 * math.sqrt(2.0))
    return np.rad2deg(2.0 * np.arcsin(np.clip(chord, 0.0, 1.0)))


def _wrapped_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs((a - b + 180.0) % 360.0 - 180.0)


# ---------------------------------------------------------------------- parse and format


def test_parse_mixed_fixture_structure() -> None:
    doc = BvhDocument.read(MIXED)
    assert doc.names == ("Hips", "Spine", "Neck", "Head", "Arm_L", "Hand_L", "Arm_R", "Hand_R",
                         "Leg_L", "Foot_L", "Leg_R", "Foot_R")
    assert doc.parents == (-1, 0, 1, 2, 1, 4, 1, 6, 0, 8, 0, 10)
    j = {joint.name: joint for joint in doc.joints}
    assert j["Spine"].rotation_order == "YXZ"
    assert j["Head"].rotation_order == "XYZ"
    assert j["Neck"].channels == ("Zrotation", "Yrotation", "Xrotation", "Xposition", "Yposition", "Zposition")
    assert j["Hand_L"].channels == () and j["Hand_R"].channels == ()  # no CHANNELS line / CHANNELS 0
    assert j["Leg_R"].channels[0] == "Yposition"
    assert j["Head"].end_site == (0.0, 12.0, 0.0)
    assert j["Spine"].end_site is None
    assert j["Hips"].offset == (1.5, 90.0, -3.0)
    assert doc.frame_time == 0.008333
    assert doc.motion.shape == (5, 34) and doc.motion.dtype == np.float64
    assert doc.channel_index("Neck", "Yposition") == 6 + 3 + 4
    assert doc.motion[:, doc.channel_index("Neck", "Yposition")] == pytest.approx([25.0] * 5)
    slices = doc.channel_slices()
    assert [s.stop - s.start for s in slices] == [len(jt.channels) for jt in doc.joints]


@pytest.mark.parametrize("path", [MIXED, BANDAI], ids=lambda p: p.stem)
@pytest.mark.parametrize("precision", [6, None])
def test_parse_format_parse_is_identical(path: Path, precision: int | None) -> None:
    doc = BvhDocument.read(path)
    text = doc.format(precision)
    again = BvhDocument.parse(text)
    assert again.joints == doc.joints
    assert again.frame_time == doc.frame_time
    # The fixtures hold at most 6 decimals, so even the fixed-precision text reads back exactly.
    np.testing.assert_array_equal(again.motion, doc.motion)
    assert again == doc
    assert again.format(precision) == text


def test_format_rounds_motion_to_precision_only() -> None:
    doc = BvhDocument.read(MIXED)
    noisy = BvhDocument(doc.joints, doc.frame_time, doc.motion + 1.23456789e-5)
    back = BvhDocument.parse(noisy.format(precision=6))
    assert np.abs(back.motion - noisy.motion).max() <= 0.5e-6 + 1e-12
    exact = BvhDocument.parse(noisy.format(precision=None))
    np.testing.assert_array_equal(exact.motion, noisy.motion)


def test_format_layout() -> None:
    doc = BvhDocument.read(MIXED)
    lines = doc.format().split("\n")
    assert lines[0] == "HIERARCHY" and lines[1] == "ROOT Hips" and lines[2] == "{"
    assert lines[3] == "\tOFFSET 1.5 90.0 -3.0"
    assert "\tJOINT Spine" in lines and "\t\t\t\tEnd Site" in lines
    assert "\t\t\t\tCHANNELS 0" in lines  # Hand_L had no CHANNELS line; written explicitly
    m = lines.index("MOTION")
    assert lines[m + 1] == "Frames: 5"
    assert lines[m + 2] == "Frame Time: 0.008333"
    assert len(lines[m + 3].split()) == 34 and lines[-1] == ""
    assert all(not ln.startswith(" ") for ln in lines)  # tabs, never spaces, for indentation


def test_crlf_tabs_blank_lines_and_keyword_case_are_tolerated() -> None:
    text = MIXED.read_text()
    doc = BvhDocument.parse(text)
    assert BvhDocument.parse(text.replace("\n", "\r\n")) == doc
    lines = text.split("\n")
    m = lines.index("MOTION")
    lines.insert(m + 4, "   ")  # a stray blank line between two frames
    lines[m + 1] = "Frames:\t5"
    lines[3] = lines[3].replace("OFFSET", "offset")
    lines[4] = lines[4].replace("Xposition", "XPOSITION")
    assert BvhDocument.parse("\ufeff" + "\n".join(lines) + "\n\n\n") == doc


def test_joints_in_another_topological_order_are_written_nested() -> None:
    # Breadth-first order: A and B (children of R) before A1 (child of A).
    joints = [
        BvhJoint("R", -1, (0, 0, 0), ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")),
        BvhJoint("A", 0, (1, 0, 0), ("Zrotation", "Xrotation", "Yrotation")),
        BvhJoint("B", 0, (-1, 0, 0), ("Xrotation",)),
        BvhJoint("A1", 1, (1, 0, 0), ("Yrotation", "Xrotation", "Zrotation"), end_site=(1, 0, 0)),
    ]
    motion = np.arange(2 * 13, dtype=np.float64).reshape(2, 13)
    doc = BvhDocument(joints, 0.05, motion)
    back = BvhDocument.parse(doc.format())
    assert back.names == ("R", "A", "A1", "B")
    for name in doc.names:
        got = back.motion[:, back.channel_slices()[back.joint_index(name)]]
        want = doc.motion[:, doc.channel_slices()[doc.joint_index(name)]]
        np.testing.assert_array_equal(got, want)
    back_world = reference_world(back)
    for name, (pos, _) in reference_world(doc).items():
        np.testing.assert_allclose(back_world[name][0], pos)


def test_document_checks_its_invariants() -> None:
    root = BvhJoint("R", -1, (0, 0, 0), ("Xposition", "Yposition", "Zposition"))
    with pytest.raises(ValueError, match="motion must be"):
        BvhDocument([root], 0.1, np.zeros((2, 4)))
    with pytest.raises(ValueError, match="unknown channel"):
        BvhJoint("J", 0, (0, 0, 0), ("Wrotation",))
    with pytest.raises(ValueError, match="topological"):
        BvhDocument([root, BvhJoint("J", 2, (0, 0, 0))], 0.1, np.zeros((1, 3)))
    with pytest.raises(ValueError, match="unique"):
        BvhDocument([root, BvhJoint("R", 0, (0, 0, 0))], 0.1, np.zeros((1, 3)))
    with pytest.raises(ValueError, match="frame_time"):
        BvhDocument([root], 0.0, np.zeros((1, 3)))
    with pytest.raises(ValueError, match="NaN"):
        BvhDocument([root], 0.1, np.full((1, 3), np.nan)).format()
    empty = BvhDocument([root], 0.1, np.zeros((0, 3)))
    assert BvhDocument.parse(empty.format()) == empty


# ---------------------------------------------------------------------- malformed input

BASE = """HIERARCHY
ROOT Hips
{
\tOFFSET 0 0 0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
\tJOINT Head
\t{
\t\tOFFSET 0 10 0
\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0 5 0
\t\t}
\t}
}
MOTION
Frames: 3
Frame Time: 0.0333333
0.0 90.0 0.0 1.0 2.0 3.0 4.0 5.0 6.0
0.1 90.1 0.2 1.5 2.5 3.5 4.5 5.5 6.5
0.2 90.2 0.4 2.0 3.0 4.0 5.0 6.0 7.0
"""


def _set_line(text: str, number: int, new: str) -> str:
    lines = text.split("\n")
    lines[number - 1] = new
    return "\n".join(lines)


def _replace_token(text: str, number: int, index: int, token: str) -> str:
    lines = text.split("\n")
    toks = lines[number - 1].split()
    toks[index] = token
    lines[number - 1] = " ".join(toks)
    return "\n".join(lines)


MALFORMED = {
    "truncated mid-line": (BASE[: BASE.rindex("4.0 5.0")], 21, "expected 9 numbers, found 5"),
    "truncated at a line end": ("\n".join(BASE.split("\n")[:20]) + "\n", 17, "declares 3 frames but the motion has 2"),
    "extra motion line": (BASE + "0 0 0 0 0 0 0 0 0\n", 22, "more motion lines than the 3 frames"),
    "too many numbers": (_set_line(BASE, 20, "0 " * 10), 20, "expected 9 numbers, found 10"),
    "channel count": (_set_line(BASE, 5, "\tCHANNELS 5 Xposition Yposition Zposition Zrotation Xrotation Yrotation"),
                      5, "declares 5 channels but lists 6"),
    "channel count not a number": (_set_line(BASE, 9, "\t\tCHANNELS three Zrotation Xrotation Yrotation"),
                                   9, "not a whole number"),
    "unknown channel": (_set_line(BASE, 9, "\t\tCHANNELS 3 Zrotation Xrot Yrotation"), 9, "unknown channel 'Xrot'"),
    "repeated channel": (_set_line(BASE, 9, "\t\tCHANNELS 3 Zrotation Zrotation Yrotation"), 9, "listed twice"),
    "word in motion": (_replace_token(BASE, 20, 4, "abc"), 20, "'abc' is not a number (joint Hips, channel Xrotation)"),
    "underscore number": (_replace_token(BASE, 19, 8, "1_0"), 19, "'1_0' is not a number"),
    "nan in motion": (_replace_token(BASE, 19, 7, "nan"), 19, "'nan' is not a finite number (joint Head, channel Xrotation)"),
    "inf in motion": (_replace_token(BASE, 21, 0, "-inf"), 21, "'-inf' is not a finite number"),
    "word in offset": (_set_line(BASE, 8, "\t\tOFFSET 0 ten 0"), 8, "'ten' is not a number"),
    "nan in offset": (_set_line(BASE, 8, "\t\tOFFSET 0 nan 0"), 8, "is not a number"),
    "short offset": (_set_line(BASE, 8, "\t\tOFFSET 0 10"), 8, "expected 3 numbers, found 2"),
    "missing opening brace": (_set_line(BASE, 7, ""), 8, "expected '{' after JOINT Head, found 'OFFSET'"),
    "missing closing brace": (_set_line(BASE, 14, ""), 16, "ROOT Hips (line 2) is not closed before MOTION"),
    "never closed": ("\n".join(BASE.split("\n")[:9]) + "\n", 9, "JOINT Head (line 6) is never closed"),
    "second ROOT after the first": (_set_line(BASE, 15, "}\nROOT Other\n{\n\tOFFSET 0 0 0\n}"), 16, "a second ROOT"),
    "ROOT inside a joint": (_set_line(BASE, 6, "\tROOT Head"), 6, "a second ROOT"),
    "missing MOTION": (_set_line(BASE, 16, ""), 17, "expected MOTION after the hierarchy, found 'Frames:'"),
    "hierarchy only": ("\n".join(BASE.split("\n")[:15]) + "\n", 15, "missing MOTION"),
    "frames not a number": (_set_line(BASE, 17, "Frames: three"), 17, "'three' is not a whole number"),
    "missing Frames": (_set_line(BASE, 17, "Frame Time: 0.0333333"), 17, "expected 'Frames: <count>'"),
    "zero frame time": (_set_line(BASE, 18, "Frame Time: 0"), 18, "positive number of seconds"),
    "bad frame time": (_set_line(BASE, 18, "Frame Time: fast"), 18, "'fast' is not a number"),
    "no HIERARCHY": (BASE.replace("HIERARCHY\n", "\n", 1), 2, "expected HIERARCHY, found 'ROOT'"),
    "empty": ("", 1, "empty input"),
    "duplicate name": (_set_line(BASE, 6, "\tJOINT Hips"), 6, "joint name 'Hips' is used twice"),
    "nameless joint": (_set_line(BASE, 6, "\tJOINT"), 6, "JOINT without a name"),
    "End Site without OFFSET": (_set_line(BASE, 12, ""), 13, "expected OFFSET in the End Site of Head, found '}'"),
    "stray word": (_set_line(BASE, 9, "\t\tROTATE 3"), 9, "unexpected 'ROTATE' in JOINT Head"),
    "joint without OFFSET": (_set_line(BASE, 8, ""), 6, "JOINT Head has no OFFSET"),
}


def test_base_text_is_valid() -> None:
    doc = BvhDocument.parse(BASE)
    assert doc.motion.shape == (3, 9) and doc.names == ("Hips", "Head")


@pytest.mark.parametrize("case", sorted(MALFORMED), ids=str)
def test_malformed_input_names_line_and_problem(case: str) -> None:
    text, line, problem = MALFORMED[case]
    with pytest.raises(BvhError) as info:
        BvhDocument.parse(text, source="walk.bvh")
    err = info.value
    assert err.line == line, str(err)
    assert err.source == "walk.bvh"
    assert str(err).startswith(f"walk.bvh:{line}: "), str(err)
    assert problem in err.problem, str(err)
    assert isinstance(err, ValueError)


def test_read_reports_the_path(tmp_path: Path) -> None:
    path = tmp_path / "walk.bvh"
    path.write_text(MALFORMED["truncated mid-line"][0])
    with pytest.raises(BvhError, match=rf"^{re.escape(str(path))}:21: expected 9 numbers, found 5$"):
        BvhDocument.read(path)


def test_bvh_error_survives_pickling() -> None:
    import pickle

    err = pickle.loads(pickle.dumps(BvhError("bad", 3, "x.bvh")))
    assert (err.line, err.source, str(err)) == (3, "x.bvh", "x.bvh:3: bad")


# ---------------------------------------------------------------------- conversion to and from Clip


def _clip_world_check(doc: BvhDocument, clip, atol: float = 1e-9) -> None:
    """Clip FK equals the reference evaluator on the BVH itself, for every joint the clip keeps."""
    ref = reference_world(doc)
    positions, rotations = clip.global_transforms()
    matrices = quat_to_matrix(rotations).numpy()
    for j, name in enumerate(clip.skeleton.names):
        want_pos, want_rot = ref[name]
        np.testing.assert_allclose(positions[:, j].numpy(), want_pos, rtol=0, atol=atol, err_msg=name)
        assert _angle_between_matrices(matrices[:, j], want_rot).max() < 1e-7, name


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
    hips_channels = doc.motion[:, doc.channel_index("Hips", "Xposition"):][:, :3]
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
        m_in = _euler_matrix(original[:, rot_cols], joint.rotation_order)
        m_out = _euler_matrix(angles[:, -3:], written.rotation_order)
        assert _angle_between_matrices(m_in, m_out).max() < 1e-4, joint.name
        if joint.name in orders:
            assert written.rotation_order == joint.rotation_order
            middle = original[:, rot_cols][:, 1]
            away_from_lock = np.abs(np.abs(middle) - 90.0) > 0.1
            diff = _wrapped_diff(original[:, rot_cols], angles[:, -3:])
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
    np.testing.assert_allclose(quat_to_matrix(clip.rotations[:, 0]).numpy(), _euler_matrix(angles, order), atol=1e-12)
    out = from_clip(clip, rotation_order=order)
    assert out.joints[0].rotation_order == order
    written = out.motion[:, 3:]
    assert _angle_between_matrices(_euler_matrix(angles, order), _euler_matrix(written, order)).max() < 1e-4
    away = np.cos(np.deg2rad(angles[:, 1])) > 1e-3
    assert _wrapped_diff(angles, written)[away].max(initial=0.0) < 1e-4
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
    col = doc.channel_index("Neck", "Xposition")
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
