"""Hostile BVH text against the server's reader: counts past int()'s 4,300 digits or past any sane frame count,
zero channels with a huge frame count, deep nesting, and a fuzz test (any text or file bytes in: a document or
:class:`BvhError`, never another exception). The client's reader is fuzzed alike in tests/clients/test_client_bvh.py."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings

from model.motion.bvh import BvhDocument, BvhError
from tests.model.motion.bvh_strategies import ANY_BVH_TEXT
from tests.model.motion.test_bvh import BASE, _set_line

# ---------------------------------------------------------------------- hostile input: BvhError and nothing else
ZERO_CHANNELS = "HIERARCHY\nROOT Hips\n{\n\tOFFSET 0 0 0\n\tCHANNELS 0\n}\nMOTION\nFrames: %s\nFrame Time: 0.0333333\n"


@pytest.mark.parametrize(("text", "line", "problem"), [
    (ZERO_CHANNELS % ("9" * 4400), 8, "(4400 characters) is more than the 10000000 frames"),
    (ZERO_CHANNELS % "10000000000000000000", 8, "10000000000000000000 is more than the 10000000 frames"),
    (ZERO_CHANNELS % ("0" * 5000 + "10000001"), 8, "10000001 is more than"),
    (_set_line(BASE, 17, "Frames: " + "9" * 4400), 17, "is more than the 10000000 frames"),
    (_set_line(BASE, 5, "\tCHANNELS " + "6" * 4400 + " Xposition"), 5, "(4400 characters) channels but lists 1"),
], ids=["frames-4400-digits-zero-channels", "frames-2^64-zero-channels", "frames-leading-zeros",
        "frames-4400-digits", "channels-4400-digits"])
def test_hostile_counts_are_bvh_errors(text: str, line: int, problem: str) -> None:
    """Counts past int()'s 4,300 digits or past any sane frame count: a BvhError before anything is allocated."""
    with pytest.raises(BvhError) as info:
        BvhDocument.parse(text, source="x.bvh")
    assert info.value.line == line and problem in info.value.problem, str(info.value)
    assert len(str(info.value)) < 300  # the 4,300 digits are not echoed back


def test_counts_with_leading_zeros_are_the_numbers_they_spell() -> None:
    zeros = "0" * 5000  # int() would count these towards its 4,300-digit limit
    text = _set_line(_set_line(BASE, 17, f"Frames: {zeros}3"), 5,
                     f"\tCHANNELS {zeros}6 Xposition Yposition Zposition Zrotation Xrotation Yrotation")
    assert BvhDocument.parse(text) == BvhDocument.parse(BASE)


def test_zero_channels_keep_their_frame_count() -> None:
    doc = BvhDocument.parse(ZERO_CHANNELS % "10000000")
    assert doc.motion.shape == (10_000_000, 0) and doc.motion.nbytes == 0


def test_deep_nesting_is_a_bvh_error() -> None:
    deep = "HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\n" + "".join(f"JOINT j{i}\n{{\nOFFSET 0 0 0\n" for i in range(5000))
    with pytest.raises(BvhError, match="nested too deeply"):
        BvhDocument.parse(deep)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(text=ANY_BVH_TEXT)
def test_any_text_is_a_document_or_a_bvh_error(text: str) -> None:
    try:
        doc = BvhDocument.parse(text, source="x.bvh")
    except BvhError as exc:
        assert exc.source == "x.bvh" and (exc.line is None or 1 <= exc.line <= text.count("\n") + 1), str(exc)
        return
    assert doc.motion.shape == (doc.num_frames, doc.num_channels) and np.isfinite(doc.motion).all()
