"""Hypothesis strategies of hostile BVH input, shared by the fuzz tests of the server's reader
(``model.motion.bvh``) and the client's (``rsmt_client.bvh``).

Three kinds of text: any text at all; any bytes, decoded as the readers decode files; and text that is
nearly BVH (a well-formed hierarchy and motion, then damaged with BVH's own words and with counts and
numbers no file should hold: thousands of digits, zero channels with a huge frame count, NaN, non-ASCII
digits), so that the fuzzing reaches past the first line.
"""

from __future__ import annotations

from hypothesis import strategies as st

CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")

# Counts and numbers that a careless reader turns into an exception or a huge allocation.
HOSTILE_NUMBERS = (
    "9" * 4400, "0" * 4400 + "7", "10000000000000000000", "18446744073709551616", "99999999999", "-1", "+3",
    "1e999", "-1e999", "nan", "inf", "1_0", "\u0663", "0x10", "1e", ".", "-", "1.2.3", "\u00bd", "", "00", "0",
)
WORDS = ("HIERARCHY", "ROOT", "JOINT", "End", "Site", "{", "}", "OFFSET", "CHANNELS", "MOTION", "Frames:",
         "Frame", "Time:", "\ufeff", "\r", "\t", " ", "\n", "\x00", "\u2028", "\x85", "\ud800") + CHANNELS


def _number(draw: st.DrawFn) -> str:
    return draw(st.sampled_from(HOSTILE_NUMBERS) | st.floats(-1e3, 1e3, allow_nan=False).map(repr)
                | st.integers(0, 12).map(str))


@st.composite
def nearly_bvh(draw: st.DrawFn) -> str:
    """A valid BVH text (1-4 joints, any channels, some frames), then zero to three edits that damage it."""
    joints = draw(st.integers(1, 4))
    lines = ["HIERARCHY"]
    width = 0
    for j in range(joints):
        channels = draw(st.lists(st.sampled_from(CHANNELS), unique=True, max_size=6))
        width += len(channels)
        lines += [f"{'ROOT' if j == 0 else 'JOINT'} j{j}", "{", "OFFSET 0 1 0",
                  f"CHANNELS {len(channels)} {' '.join(channels)}".rstrip()]
    lines += ["End Site", "{", "OFFSET 0 1 0", "}"] + ["}"] * joints
    frames = draw(st.integers(0, 3))
    lines += ["MOTION", f"Frames: {frames}", "Frame Time: 0.0333333"]
    lines += [" ".join(["0.5"] * width) for _ in range(frames)]
    for _ in range(draw(st.integers(0, 3))):
        at = draw(st.integers(0, len(lines) - 1))
        edit = draw(st.sampled_from(["count", "word", "token", "drop", "line"]))
        toks = lines[at].split() or [""]
        counts = [n for n, ln in enumerate(lines) if ln.startswith(("Frames:", "CHANNELS"))]
        if edit == "count" and counts:  # the frame count, or the count of a CHANNELS line, becomes hostile
            target = draw(st.sampled_from(counts))
            head = lines[target].split()
            lines[target] = " ".join([head[0], _number(draw), *head[2:]])
        elif edit == "word":
            lines.insert(at, draw(st.sampled_from(WORDS)))
        elif edit == "token":
            toks[draw(st.integers(0, len(toks) - 1))] = draw(st.sampled_from(WORDS)) if draw(st.booleans()) else _number(draw)
            lines[at] = " ".join(toks)
        elif edit == "drop":
            del lines[at]
        else:
            lines.insert(at, " ".join(_number(draw) for _ in range(draw(st.integers(0, width + 1)))))
    return "\n".join(lines) + draw(st.sampled_from(["\n", "", "\n\n", "\r\n"]))


def decoded(data: bytes) -> str:
    """Bytes as the readers decode a file: UTF-8 (a BOM dropped), else Latin-1."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")


# Everything a fuzz test feeds a BVH reader.
ANY_BVH_TEXT = st.one_of(nearly_bvh(), st.text(max_size=300), st.binary(max_size=300).map(decoded),
                         st.lists(st.sampled_from(WORDS + HOSTILE_NUMBERS)).map(" ".join))
