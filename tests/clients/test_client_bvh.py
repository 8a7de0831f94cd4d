"""The client's own BVH reader and writer (``rsmt_client.bvh``, numpy only) against the project's reader
(``model.motion.bvh`` / ``bvh_clip``, torch): same joints, quaternions and root positions; round trips;
malformed text refused with an error naming the line, exactly when the project's reader refuses it."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from rsmt_client import BvhError, Poses, load_bvh_poses, motion_payload, poses_to_bvh, read_bvh
from rsmt_client.bvh import BvhFile
from rsmt_client.quaternions import euler_to_quat, quat_to_euler

from model.data.synthetic import synthetic_skeleton, synthetic_walk
from model.motion.bvh import BvhDocument
from model.motion.bvh import BvhError as ProjectBvhError
from model.motion.bvh_clip import load_clip
from model.motion.skeleton import SkeletonProfile
from tests.model.motion.bvh_strategies import ANY_BVH_TEXT

FIXTURES = sorted((Path(__file__).resolve().parents[1] / "fixtures").glob("*.bvh"))
ORDERS = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")


def file_root_profile(path_or_text: str | Path) -> SkeletonProfile:
    """A profile whose every role is the file's root joint: the project's reader then keeps the whole rig as it is."""
    doc = BvhDocument.parse(path_or_text) if isinstance(path_or_text, str) else BvhDocument.read(path_or_text)
    r = doc.names[0]
    return SkeletonProfile(name="file-root", root=r, head=r, left_foot=(r,), right_foot=(r,), left_hip=r, right_hip=r,
                           left_shoulder=r, right_shoulder=r, mirror=())


def assert_same_rotations(a: np.ndarray, b: np.ndarray, atol: float) -> None:
    """Equal quaternions up to the sign of each."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    assert a.shape == b.shape
    worst = np.minimum(np.abs(a - b).max(-1), np.abs(a + b).max(-1)).max(initial=0.0)
    assert worst <= atol, worst


def model_info(skeleton) -> dict:
    """What GET /v1/model says of a skeleton."""
    return {"skeleton": {"joints": [{"name": n, "parent": int(p), "offset": list(o)}
                                    for n, p, o in zip(skeleton.names, skeleton.parents, skeleton.offsets)]}}


# ---------------------------------------------------------------------- reading, against the project's reader

@pytest.mark.parametrize("path", FIXTURES, ids=lambda p: p.name)
@pytest.mark.parametrize("fps", [None, 50.0])
def test_reader_matches_the_project_reader(path: Path, fps: float | None) -> None:
    clip = load_clip(path, profile=file_root_profile(path), fps=fps, dtype=torch.float64)
    poses = load_bvh_poses(path, fps=fps)
    assert poses.joints == tuple(clip.skeleton.names) == BvhDocument.read(path).names
    assert poses.num_frames == clip.num_frames > 0 and poses.fps == clip.fps
    assert_same_rotations(poses.rotations, clip.rotations.numpy(), atol=1e-6)
    np.testing.assert_allclose(poses.root_positions, clip.root_positions.numpy(), rtol=1e-6, atol=1e-6)
    # Text works as well as a path, and the document itself reads as the project's does.
    again = load_bvh_poses(path.read_text(), fps=fps)
    np.testing.assert_array_equal(again.rotations, poses.rotations)
    ours, theirs = BvhFile.read(path), BvhDocument.read(path)
    assert [(j.name, j.parent, j.offset, j.channels, j.end_site) for j in ours.joints] == \
        [(j.name, j.parent, j.offset, j.channels, j.end_site) for j in theirs.joints]
    np.testing.assert_array_equal(ours.motion, theirs.motion)
    assert ours.frame_time == theirs.frame_time and ours.fps == theirs.fps


def test_signs_are_continuous_over_time() -> None:
    poses = load_bvh_poses(FIXTURES[0])
    dots = np.sum(poses.rotations[1:] * poses.rotations[:-1], axis=-1)
    assert (dots >= 0).all()


# ---------------------------------------------------------------------- writing

@pytest.mark.parametrize("order", ORDERS)
def test_write_read_round_trip(order: str, tmp_path: Path) -> None:
    sk = synthetic_skeleton()
    rng = np.random.default_rng(len(order) + ORDERS.index(order))
    q = rng.normal(size=(7, sk.num_joints, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    roots = rng.normal(scale=50.0, size=(7, 3))
    text = poses_to_bvh(model_info(sk), roots, q, 30.0, rotation_order=order, precision=None)
    back = load_bvh_poses(text)
    assert back.joints == tuple(sk.names) and back.fps == 30.0
    assert_same_rotations(back.rotations, q, atol=1e-6)
    np.testing.assert_allclose(back.root_positions, roots, rtol=1e-6, atol=1e-5)
    # The project's reader reads the written file the same way, on the same skeleton.
    clip = load_clip(text, profile=file_root_profile(text), dtype=torch.float64)
    assert_same_rotations(clip.rotations.numpy(), q, atol=1e-9)
    np.testing.assert_allclose(clip.skeleton.offsets[1:], sk.offsets[1:])
    # Poses.save_bvh writes the same text (6 decimals by default, still within 1e-6 of the rotation).
    saved = Poses(roots, q, 30.0).save_bvh(tmp_path / "p.bvh", model_info(sk), rotation_order=order)
    assert_same_rotations(load_bvh_poses(saved).rotations, q.astype(np.float32), atol=1e-6)


def test_joints_out_of_nested_order_are_written_nested() -> None:
    info = {"skeleton": {"joints": [{"name": "root", "parent": -1, "offset": [0, 0, 0]},
                                    {"name": "a", "parent": 0, "offset": [1, 0, 0]},
                                    {"name": "b", "parent": 0, "offset": [0, 1, 0]},
                                    {"name": "a2", "parent": 1, "offset": [0, 0, 1]}]}}
    q = euler_to_quat(np.array([[[0, 0, 0], [10, 20, 30], [40, 50, 60], [70, 80, 10]]], dtype=float), "ZXY")
    back = load_bvh_poses(poses_to_bvh(info, np.zeros((1, 3)), q, 30.0))
    assert back.joints == ("root", "a", "a2", "b")
    assert_same_rotations(back.rotations[0], q[0][[0, 1, 3, 2]], atol=1e-6)


def test_clip_payload_is_the_clip() -> None:
    """A clip-like object (here the project's Clip) goes out as BVH that reads back to the same clip."""
    clip = synthetic_walk(12).to(torch.float64)
    text = motion_payload(clip)["bvh"]
    back = load_clip(text, dtype=torch.float64)
    assert tuple(back.skeleton.names) == tuple(clip.skeleton.names) and back.fps == clip.fps
    assert_same_rotations(back.rotations.numpy(), clip.rotations.numpy(), atol=1e-6)
    np.testing.assert_allclose(back.root_positions.numpy(), clip.root_positions.numpy(), atol=1e-6)
    np.testing.assert_allclose(back.skeleton.offsets, clip.skeleton.offsets)


def test_writer_refuses_what_bvh_cannot_hold() -> None:
    info = model_info(synthetic_skeleton())
    j = len(info["skeleton"]["joints"])
    good = np.tile([0.0, 0.0, 0.0, 1.0], (2, j, 1))
    with pytest.raises(ValueError, match="rotation order"):
        poses_to_bvh(info, np.zeros((2, 3)), good, 30.0, rotation_order="XXY")
    with pytest.raises(ValueError, match="expected rotations"):
        poses_to_bvh(info, np.zeros((2, 3)), good[:, 1:], 30.0)
    with pytest.raises(ValueError, match="fps"):
        poses_to_bvh(info, np.zeros((2, 3)), good, 0.0)
    with pytest.raises(ValueError, match="zero or not finite"):
        poses_to_bvh(info, np.zeros((2, 3)), np.zeros_like(good), 30.0)
    with pytest.raises(ValueError, match="NaN"):
        poses_to_bvh(info, np.full((2, 3), np.nan), good, 30.0)


# ---------------------------------------------------------------------- Euler angles

def _quaternions(min_value: float = -1.0) -> st.SearchStrategy[np.ndarray]:
    return st.lists(st.floats(min_value, 1.0), min_size=4, max_size=4).filter(
        lambda v: float(np.linalg.norm(v)) > 1e-3).map(lambda v: np.asarray(v) / np.linalg.norm(v))


@settings(max_examples=300, deadline=None)
@given(q=_quaternions(), order=st.sampled_from(ORDERS))
def test_euler_round_trip(q: np.ndarray, order: str) -> None:
    angles = quat_to_euler(q, order)
    assert -90.0 - 1e-9 <= angles[1] <= 90.0 + 1e-9
    assert_same_rotations(euler_to_quat(angles, order), q, atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(a=st.floats(-180, 180), c=st.floats(-180, 180), sign=st.sampled_from([-1.0, 1.0]), order=st.sampled_from(ORDERS),
       wobble=st.sampled_from([0.0, 1e-7, -1e-7, 1e-4]))
def test_euler_round_trip_at_gimbal_lock(a: float, c: float, sign: float, order: str, wobble: float) -> None:
    q = euler_to_quat(np.array([a, sign * (90.0 - abs(wobble)), c]), order)
    assert_same_rotations(euler_to_quat(quat_to_euler(q, order), order), q, atol=1e-7)


# ---------------------------------------------------------------------- malformed input

GOOD = FIXTURES[0].read_text()
LINES = GOOD.split("\n")


def _with_line(n: int, text: str) -> str:
    return "\n".join(LINES[:n - 1] + [text] + LINES[n:])


def _line_of(prefix: str) -> int:
    return next(n for n, line in enumerate(LINES, 1) if line.strip().startswith(prefix))


MALFORMED = {
    "empty": ("", None, "no MOTION line"),
    "no hierarchy keyword": (GOOD.replace("HIERARCHY", "HIERARCH", 1), 1, "expected HIERARCHY"),
    "bad offset": (_with_line(_line_of("OFFSET"), "OFFSET 1 x 3"), _line_of("OFFSET"), "expected a number, found 'x'"),
    "short offset": (_with_line(_line_of("OFFSET"), "OFFSET 1 2"), _line_of("OFFSET"), "OFFSET needs 3 numbers"),
    "offset with more": (_with_line(_line_of("OFFSET"), "OFFSET 1 2 3 4"), _line_of("OFFSET"), "found 4"),
    "short channels": (_with_line(_line_of("CHANNELS"), "CHANNELS 3 Xrotation"), _line_of("CHANNELS"), "1 channel names"),
    "unknown channel": (_with_line(_line_of("CHANNELS"), "CHANNELS 1 Wrotation"), _line_of("CHANNELS"), "'Wrotation'"),
    "channel twice": (_with_line(_line_of("CHANNELS"), "CHANNELS 2 Xrotation xrotation"), _line_of("CHANNELS"), "twice"),
    "frames mismatch": (GOOD.replace("Frames: ", "Frames: 1", 1), _line_of("Frames:"), "Frames says"),
    "short frame line": (_with_line(len(LINES) - 1, "1 2 3"), len(LINES) - 1, "found 3"),
    "nan value": (_with_line(len(LINES) - 1, LINES[-2].replace(LINES[-2].split()[0], "nan", 1)), len(LINES) - 1,
                  "'nan' is not a number"),
    "huge value": (_with_line(len(LINES) - 1, LINES[-2].replace(LINES[-2].split()[0], "1e999", 1)), len(LINES) - 1,
                   "too large"),
    "bad frame time": (GOOD.replace("Frame Time: ", "Frame Time: -", 1), _line_of("Frame Time"), "positive"),
    # float() reads non-ASCII digits ("\u0669\u0663" is 93); BVH numbers are ASCII, as for the server (issue 64).
    "non-ASCII offset": (_with_line(_line_of("OFFSET"), "OFFSET 1 \u0669\u0663 3"), _line_of("OFFSET"),
                         "expected a number, found '\u0669\u0663'"),
    "non-ASCII frame time": (_with_line(_line_of("Frame Time"), "Frame Time: 0.\u0660\u0663"), _line_of("Frame Time"),
                             "positive"),
    "non-ASCII value": (_with_line(len(LINES) - 1, LINES[-2].replace(LINES[-2].split()[0], "\u0669\u0663", 1)),
                        len(LINES) - 1, "'\u0669\u0663' is not a number"),
    # 1 / 1e-310 overflows: refused with the server's words instead of an OverflowError on the way to fps.
    "tiny frame time": (_with_line(_line_of("Frame Time"), "Frame Time: 1e-310"), _line_of("Frame Time"),
                        "Frame Time 1e-310 s gives inf fps; accepted: 1 to 1000 fps"),
    "two roots": (GOOD.replace("MOTION", "ROOT extra\n{\nOFFSET 0 0 0\n}\nMOTION", 1), _line_of("MOTION"),
                  "unexpected 'ROOT'"),
    "unclosed joint": (GOOD.replace("}\nMOTION", "MOTION", 1), _line_of("MOTION") - 1, "closing joint"),
}


@pytest.mark.parametrize("name", sorted(MALFORMED))
def test_malformed_text_names_the_line(name: str, tmp_path: Path) -> None:
    text, line, words = MALFORMED[name]
    path = tmp_path / "broken.bvh"
    path.write_text(text)
    with pytest.raises(BvhError) as err:
        read_bvh(path)
    assert words in str(err.value) and err.value.source == str(path)
    assert str(err.value).startswith(f"{path}:") and (line is None or err.value.line == line)
    with pytest.raises(ValueError):  # the project's reader refuses the same text
        BvhDocument.parse(text)


@st.composite
def _mutations(draw: st.DrawFn) -> str:
    text = draw(st.sampled_from([p.read_text() for p in FIXTURES]))
    for _ in range(draw(st.integers(1, 3))):
        at = draw(st.integers(0, len(text)))
        edit = draw(st.sampled_from(["delete", "insert", "replace"]))
        piece = draw(st.sampled_from(list("{} \n\t0123456789.-+eExXyYzZ:_#,\r")
                                     + ["nan", "OFFSET", "JOINT", "End Site", "CHANNELS 3", "MOTION", "\ufeff", "é"]))
        if edit == "delete":
            text = text[:at] + text[at + draw(st.integers(1, 40)):]
        else:
            text = text[:at] + piece + text[at + (edit == "replace"):]
    return text


def _reads_as_the_server_reads(text: str, project_error: type[Exception]) -> None:
    """The client's reader gives a file exactly when the project's reader (the server's) does, and otherwise a
    BvhError naming a line of the text or none; the project's refusal must be ``project_error``."""
    try:
        BvhDocument.parse(text)
        project_accepts = True
    except project_error:
        project_accepts = False
    try:
        parsed = BvhFile.parse(text, source="x.bvh")
    except BvhError as exc:
        assert not project_accepts, f"refused what the server reads: {exc}"
        assert exc.line is None or 1 <= exc.line <= text.count("\n") + 1
        return
    assert project_accepts, "read what the server refuses"
    assert parsed.motion.shape == (parsed.num_frames, sum(len(j.channels) for j in parsed.joints))


@settings(max_examples=400, deadline=None)
@given(text=_mutations())
def test_damaged_files_fail_cleanly_and_as_the_server_would(text: str) -> None:
    """Damaged text either reads or raises BvhError naming a line of the text, and exactly when the project's
    reader (which the server uses) refuses it too."""
    _reads_as_the_server_reads(text, ValueError)


# ---------------------------------------------------------------------- hostile input: BvhError and nothing else
ZERO_CHANNELS = "HIERARCHY\nROOT Hips\n{\n\tOFFSET 0 0 0\n\tCHANNELS 0\n}\nMOTION\nFrames: %s\nFrame Time: 0.0333333\n"


@pytest.mark.parametrize(("text", "line", "words"), [
    (ZERO_CHANNELS % ("9" * 4400), 8, "(4400 characters) is more than the 10000000 frames"),
    (ZERO_CHANNELS % "10000000000000000000", 8, "10000000000000000000 is more than the 10000000 frames"),
    (_with_line(_line_of("Frames:"), "Frames: " + "9" * 4400), _line_of("Frames:"), "is more than the 10000000 frames"),
    (_with_line(_line_of("CHANNELS"), "CHANNELS " + "6" * 4400 + " Xposition"), _line_of("CHANNELS"),
     "(4400 characters) is followed by 1 channel names"),
], ids=["frames-4400-digits-zero-channels", "frames-2^64-zero-channels", "frames-4400-digits", "channels-4400-digits"])
def test_hostile_counts_are_bvh_errors(text: str, line: int, words: str) -> None:
    with pytest.raises(BvhError) as err:
        BvhFile.parse(text, source="x.bvh")
    assert err.value.line == line and words in str(err.value) and len(str(err.value)) < 300, str(err.value)
    with pytest.raises(ValueError):  # the project's reader refuses the same text
        BvhDocument.parse(text)


@pytest.mark.parametrize(("tail", "line", "wanted"), [("MOTION\n", 12, "Frames"), ("MOTION\nFrames: 0\n", 13, "Frame Time"),
                                                   ("MOTION", 11, "Frames")])
def test_a_file_that_ends_early_names_its_last_line(tail: str, line: int, wanted: str) -> None:
    """A header missing at the end of the file is reported on the file's last line, never past it."""
    text = "HIERARCHY\nROOT j0\n{\nOFFSET 0 1 0\nCHANNELS 0\nEnd Site\n{\nOFFSET 0 1 0\n}\n}\n" + tail
    with pytest.raises(BvhError, match=f"expected '{wanted}: ...', found the end of the file") as err:
        BvhFile.parse(text, source="x.bvh")
    assert err.value.line == line == text.count("\n") + 1


def test_zero_channels_and_leading_zeros_read_as_the_server_reads_them() -> None:
    for text in (ZERO_CHANNELS % "0", ZERO_CHANNELS % "12", ZERO_CHANNELS % ("0" * 5000 + "12")):
        ours, theirs = BvhFile.parse(text), BvhDocument.parse(text)
        assert ours.motion.shape == theirs.motion.shape == (theirs.num_frames, 0)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(text=ANY_BVH_TEXT)
def test_any_text_reads_or_is_a_bvh_error_as_on_the_server(text: str) -> None:
    """Fuzzing: any text (or file bytes) gives a file or BvhError, never another exception, and exactly when
    the project's reader (itself fuzzed in tests/model/motion/test_bvh_hostile.py) accepts it."""
    _reads_as_the_server_reads(text, ProjectBvhError)


def test_the_cutter_refuses_a_frame_time_that_overflows_in_the_readers_words() -> None:
    """Issue 64: a Frame Time of 1e-310 reached round(inf) in the cutter (an OverflowError under rsmt client)."""
    from rsmt_client.motion_cuts import Cutter, ModelLimits

    tiny = re.sub(r"Frame Time: .*", "Frame Time: 1e-310", GOOD)
    cutter = Cutter(ModelLimits(fps=30.0, context_frames=10, style_min=16, style_max=240))
    for cut in (cutter.context, cutter.target, cutter.style):
        with pytest.raises(BvhError, match="Frame Time 1e-310 s gives inf fps; accepted: 1 to 1000 fps"):
            cut({"bvh": tiny})
