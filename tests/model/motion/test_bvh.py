"""Tests for model.motion.bvh: lossless BVH round trips and errors with line numbers (Clip conversion: test_bvh_clip.py).

The fixture files are described in bvh_fixtures.py.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from model.motion.bvh import BvhDocument, BvhError, BvhJoint
from tests.model.motion.bvh_fixtures import BANDAI, MIXED
from tests.model.motion.bvh_reference import channel_column, reference_world

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
    assert channel_column(doc, "Neck", "Yposition") == 6 + 3 + 4
    assert doc.motion[:, channel_column(doc, "Neck", "Yposition")] == pytest.approx([25.0] * 5)
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
    # float() reads non-ASCII digits ("\u0669\u0663" is 93 in Arabic-Indic digits); BVH numbers are ASCII (issue 64).
    "non-ASCII digits in motion": (_replace_token(BASE, 19, 1, "\u0669\u0663"), 19,
                                   "'\u0669\u0663' is not a number (joint Hips, channel Yposition)"),
    "non-ASCII digits in offset": (_set_line(BASE, 8, "\t\tOFFSET 0 \u0661\u0660 0"), 8, "is not a number"),
    "non-ASCII digits in frame time": (_set_line(BASE, 18, "Frame Time: 0.\u0660\u0663"), 18, "is not a number"),
    # A rate that overflows (1 / 1e-310 is infinite) or leaves 1 to 1000 fps, in the service's words.
    "tiny frame time": (_set_line(BASE, 18, "Frame Time: 1e-310"), 18,
                        "Frame Time 1e-310 s gives inf fps; accepted: 1 to 1000 fps (Frame Time 0.001 to 1 s)"),
    "long frame time": (_set_line(BASE, 18, "Frame Time: 2"), 18, "gives 0.5 fps; accepted: 1 to 1000 fps"),
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
