"""BVH motion files as data, in numpy: read them (checked, with errors naming file and line) and write them.

:class:`BvhFile` holds what a file says: joints (name, parent, OFFSET, channels, End Site) in file
order, the frame time and the channel values as written (degrees for rotations). It knows
nothing of any model; :mod:`rsmt_client.motion` turns it into poses and back.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

Vec3 = tuple[float, float, float]
POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
_CHANNELS = {c.lower(): c for c in POSITION_CHANNELS + ROTATION_CHANNELS}  # exporters vary the case
# A plain decimal number: no "nan", "inf", "1_000" or non-ASCII digits, which float() would take.
_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")  # not \d: it matches "٩"
_NOT_IN_NUMBERS = re.compile(r"[^0-9eE+\-.\s]")
_FRAMES = re.compile(r"frames\s*:\s*(\S*)\s*", re.IGNORECASE)
_FRAME_TIME = re.compile(r"frame\s+time\s*:\s*(\S*)\s*", re.IGNORECASE)
# The most frames a file may declare (as the server's reader): frames of a hierarchy without channels are
# empty lines, so nothing in the text bounds their count.
MAX_FRAMES = 10_000_000
_COUNT_DIGITS = 18  # int() refuses numbers past 4,300 digits; no count needs more than a few
# The frame rates a file may declare (Frame Time 0.001 to 1 s), as the server's reader: past them 1 / frame time
# overflows (a Frame Time of 1e-310) or a resampled clip grows without bound.
MIN_FPS, MAX_FPS = 1.0, 1000.0


class BvhError(ValueError):
    """Malformed BVH; ``str(err)`` reads like ``"walk.bvh:12: OFFSET needs 3 numbers, found 2"``."""

    def __init__(self, problem: str, line: int | None = None, source: str = "<string>") -> None:
        self.problem, self.line, self.source = problem, line, source
        super().__init__(f"{source}: {problem}" if line is None else f"{source}:{line}: {problem}")


@dataclass(frozen=True)
class BvhJoint:
    """One ROOT or JOINT block: ``parent`` indexes the joints of the file (-1 for the root)."""

    name: str
    parent: int
    offset: Vec3
    channels: tuple[str, ...] = ()
    end_site: Vec3 | None = None

    @property
    def rotation_axes(self) -> str:
        """The axes of the rotation channels in file order, e.g. ``"ZXY"`` (``""`` when there are none)."""
        return "".join(c[0] for c in self.channels if c in ROTATION_CHANNELS)


@dataclass
class BvhFile:
    """A BVH file: ``joints`` (parents before children), ``frame_time`` (s), ``motion [frames, channels]`` (float64)."""

    joints: list[BvhJoint]
    frame_time: float
    motion: np.ndarray = field(repr=False)

    def __post_init__(self) -> None:
        if not self.joints or self.joints[0].parent != -1:
            raise ValueError("a BVH file needs a root joint first")
        if any(not 0 <= j.parent < i for i, j in enumerate(self.joints) if i):
            raise ValueError("every joint but the first needs a parent listed before it")
        if not (math.isfinite(self.frame_time) and self.frame_time > 0):
            raise ValueError(f"frame time must be a positive number of seconds, got {self.frame_time}")
        width = sum(len(j.channels) for j in self.joints)
        motion = np.asarray(self.motion, dtype=np.float64)
        if motion.ndim == 1 and motion.size == 0:
            motion = motion.reshape(0, width)
        self.motion = motion if width == 0 and motion.ndim == 2 else motion.reshape(-1, width)

    @property
    def num_frames(self) -> int:
        return int(self.motion.shape[0])

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def fps(self) -> float:
        """``1 / frame_time``, or the whole number it rounds (files write 1/30 s as 0.0333333, i.e. 30.0000003 fps)."""
        fps = 1.0 / self.frame_time
        whole = round(fps)
        return float(whole) if whole >= 1 and abs(fps - whole) <= 1e-4 * fps else fps

    def columns(self, joint: int) -> slice:
        """The columns of :attr:`motion` that hold one joint's channels."""
        start = sum(len(j.channels) for j in self.joints[:joint])
        return slice(start, start + len(self.joints[joint].channels))

    def rotation_degrees(self, joint: int) -> tuple[str, np.ndarray]:
        """One joint's rotation axes in file order and their angles ``[frames, len(axes)]`` in degrees."""
        cols = self.columns(joint)
        picked = [n for n, c in enumerate(self.joints[joint].channels) if c in ROTATION_CHANNELS]
        return self.joints[joint].rotation_axes, self.motion[:, cols][:, picked]

    def translations(self, joint: int) -> np.ndarray:
        """One joint's translation per frame ``[frames, 3]``: its OFFSET, each position channel replacing its axis."""
        out = np.tile(np.asarray(self.joints[joint].offset, dtype=np.float64), (self.num_frames, 1))
        cols = self.columns(joint)
        for n, c in enumerate(self.joints[joint].channels):
            if c in POSITION_CHANNELS:
                out[:, "XYZ".index(c[0])] = self.motion[:, cols.start + n]
        return out

    # ------------------------------------------------------------------ reading
    @classmethod
    def parse(cls, text: str, source: str = "<string>") -> BvhFile:
        """Parse BVH text; anything malformed raises :class:`BvhError` naming ``source`` and the line."""
        lines = text.lstrip("\ufeff").split("\n")  # a lone "\r" is blank space within a line, as for the server
        motion_at = next((n for n, line in enumerate(lines) if line.strip().upper() == "MOTION"), None)
        if motion_at is None:
            raise BvhError("no MOTION line: a BVH file is HIERARCHY, the joints, then MOTION and the frames", None, source)
        joints = _Hierarchy(lines[:motion_at], source).parse()
        frame_time, motion = _parse_motion(lines, motion_at + 1, sum(len(j.channels) for j in joints), source)
        return cls(joints, frame_time, motion)

    @classmethod
    def read(cls, path: str | Path) -> BvhFile:
        return cls.parse(read_text(path), source=str(path))

    def window(self, start: int, frames: int | None = None) -> BvhFile:
        """Frames ``[start, start + frames)`` (the file's own frames; ``None``: to the end) as a new file.

        Raises ValueError naming the file's frame count when the range does not lie inside it.
        """
        stop = self.num_frames if frames is None else start + frames
        if start < 0 or (frames is not None and frames < 1) or not start < stop <= self.num_frames:
            want = f"frames {start} to {stop - 1}" if frames is not None else f"frames from {start}"
            raise ValueError(f"{want} are outside the file's {self.num_frames} frames (0 to {self.num_frames - 1}, "
                             f"at {self.fps:g} fps)")
        return BvhFile(self.joints, self.frame_time, self.motion[start:stop].copy())

    # ------------------------------------------------------------------ writing
    def format(self, precision: int | None = 6) -> str:
        """BVH text, joints nested depth first (columns follow); motion values with ``precision`` decimals
        (None: the shortest text that reads back exactly); OFFSETs and the frame time always exact."""
        if not np.isfinite(self.motion).all():
            raise ValueError("motion holds NaN or infinite values, which BVH cannot store")
        children: list[list[int]] = [[] for _ in self.joints]
        for i, j in enumerate(self.joints[1:], 1):
            children[j.parent].append(i)
        lines, order = ["HIERARCHY"], []
        stack: list[tuple[int, int, bool]] = [(0, 0, False)]  # (joint, depth, closing): no recursion limit
        while stack:
            i, depth, closing = stack.pop()
            pad, joint = "\t" * depth, self.joints[i]
            if closing:
                if joint.end_site is not None:
                    lines += [f"{pad}\tEnd Site", f"{pad}\t{{", f"{pad}\t\tOFFSET {_exact(joint.end_site)}", f"{pad}\t}}"]
                lines.append(f"{pad}}}")
                continue
            order.append(i)
            lines += [f"{pad}{'JOINT' if depth else 'ROOT'} {joint.name}", f"{pad}{{", f"{pad}\tOFFSET {_exact(joint.offset)}",
                      f"{pad}\tCHANNELS {len(joint.channels)}" + "".join(f" {c}" for c in joint.channels)]
            stack.append((i, depth, True))
            stack.extend((k, depth + 1, False) for k in reversed(children[i]))
        motion = self.motion[:, [c for i in order for c in range(self.columns(i).start, self.columns(i).stop)]]
        lines += ["MOTION", f"Frames: {self.num_frames}", f"Frame Time: {float(self.frame_time)!r}"]
        if precision is None:
            lines += [" ".join(map(repr, row)) for row in motion.tolist()]
        else:
            row = " ".join([f"%.{int(precision)}f"] * motion.shape[1])
            lines += [row % tuple(values) for values in motion.tolist()]
        return "\n".join(lines) + "\n"

    def write(self, path: str | Path, precision: int | None = 6) -> Path:
        path = Path(path)
        path.write_text(self.format(precision), encoding="utf-8")
        return path


def read_text(path: str | Path) -> str:
    """A file's text: UTF-8 (a BOM is dropped), else Latin-1, which some exporters use for joint names."""
    raw = Path(path).read_bytes()
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def _whole_number(text: str) -> int | None:
    """Plain ASCII digits as an int, or None when they are not digits or too many to be a sane count."""
    digits = text.lstrip("0") or "0"  # int() counts leading zeros towards its limit too
    if not (text.isascii() and text.isdigit()) or len(digits) > _COUNT_DIGITS:
        return None
    return int(digits)


def _short(text: str, keep: int = 24) -> str:
    """``text`` for an error message, at most ``keep`` characters of it."""
    return text if len(text) <= keep else f"{text[:keep]}... ({len(text)} characters)"


def _exact(values: Sequence[float]) -> str:
    return " ".join(repr(float(v)) for v in values)


@dataclass
class _Draft:
    name: str
    parent: int
    line: int
    offset: Vec3 | None = None
    channels: tuple[str, ...] | None = None
    end_site: Vec3 | None = None


class _Hierarchy:
    """The HIERARCHY section, read token by token (each token knows its line)."""

    def __init__(self, lines: Sequence[str], source: str) -> None:
        self.tokens = [(tok, n) for n, line in enumerate(lines, 1) for tok in line.split()]
        self.at = 0
        self.source = source
        self.last_line = len(lines)
        self.drafts: list[_Draft] = []

    def error(self, problem: str, line: int | None) -> BvhError:
        return BvhError(problem, line, self.source)

    def take(self, wanted: str) -> tuple[str, int]:
        if self.at >= len(self.tokens):
            raise self.error(f"expected {wanted}, found the MOTION line", self.last_line + 1)
        self.at += 1
        return self.tokens[self.at - 1]

    def keyword(self, word: str) -> int:
        tok, line = self.take(word)
        if tok.upper() != word.upper():
            raise self.error(f"expected {word}, found {tok!r}", line)
        return line

    def words(self, line: int) -> list[tuple[str, int]]:
        """The tokens left on ``line`` up to a brace (a statement's arguments)."""
        out = []
        while self.at < len(self.tokens) and self.tokens[self.at][1] == line and self.tokens[self.at][0] not in ("{", "}"):
            out.append(self.tokens[self.at])
            self.at += 1
        return out

    def vec3(self, what: str, line: int) -> Vec3:
        words = self.words(line)
        if len(words) != 3:
            raise self.error(f"{what} needs 3 numbers on its line, found {len(words)}", line)
        values = []
        for tok, _ in words:
            value = float(tok) if _NUMBER.fullmatch(tok) else math.nan
            if not math.isfinite(value):
                raise self.error(f"{what}: expected a number, found {tok!r}", line)
            values.append(value)
        return values[0], values[1], values[2]

    def parse(self) -> list[BvhJoint]:
        self.keyword("HIERARCHY")
        self.open(-1, self.keyword("ROOT"))
        stack = [0]
        while stack:
            tok, line = self.take(f"'}}' closing joint {self.drafts[stack[-1]].name!r}")
            key = tok.upper()
            if key == "}":
                self.close(self.drafts[stack.pop()], line)
            elif key == "JOINT":
                stack.append(self.open(stack[-1], line))
            else:
                self.item(key, tok, line, self.drafts[stack[-1]])
        if self.at < len(self.tokens):
            tok, line = self.tokens[self.at]
            raise self.error(f"unexpected {tok!r} after the root joint's closing brace (one hierarchy per file)", line)
        return [BvhJoint(d.name, d.parent, d.offset or (0.0, 0.0, 0.0), d.channels or (), d.end_site) for d in self.drafts]

    def open(self, parent: int, line: int) -> int:
        name = " ".join(tok for tok, _ in self.words(line))
        if not name:
            raise self.error("a joint needs a name after ROOT or JOINT", line)
        if any(d.name == name for d in self.drafts):
            raise self.error(f"joint name {name!r} is used twice", line)
        self.keyword("{")
        self.drafts.append(_Draft(name, parent, line))
        return len(self.drafts) - 1

    def close(self, draft: _Draft, line: int) -> None:
        if draft.offset is None:
            raise self.error(f"joint {draft.name!r} (line {draft.line}) has no OFFSET", line)

    def item(self, key: str, tok: str, line: int, draft: _Draft) -> None:
        if key == "OFFSET":
            if draft.offset is not None:
                raise self.error(f"joint {draft.name!r} has a second OFFSET", line)
            draft.offset = self.vec3("OFFSET", line)
        elif key == "CHANNELS":
            if draft.channels is not None:
                raise self.error(f"joint {draft.name!r} has a second CHANNELS line", line)
            draft.channels = self.channels(line)
        elif key == "END":
            if draft.end_site is not None:
                raise self.error(f"joint {draft.name!r} has a second End Site", line)
            self.keyword("Site")
            self.keyword("{")
            draft.end_site = self.vec3("End Site OFFSET", self.keyword("OFFSET"))
            self.keyword("}")
        else:
            raise self.error(f"unexpected {tok!r} in joint {draft.name!r}: expected OFFSET, CHANNELS, JOINT, "
                             "End Site or '}'", line)

    def channels(self, line: int) -> tuple[str, ...]:
        words = [tok for tok, _ in self.words(line)]
        if not words or not (words[0].isascii() and words[0].isdigit()):
            raise self.error(f"CHANNELS: expected a channel count, found {_short(words[0]) if words else 'nothing'!r}",
                             line)
        count, names = _whole_number(words[0]), words[1:]
        if len(names) != count:
            shown = _short(words[0].lstrip("0")) if count is None else count
            raise self.error(f"CHANNELS {shown} is followed by {len(names)} channel names on its line", line)
        out: list[str] = []
        for name in names:
            canon = _CHANNELS.get(name.lower())
            if canon is None:
                raise self.error(f"CHANNELS {count}: {name!r} is not one of {', '.join(_CHANNELS.values())}", line)
            if canon in out:
                raise self.error(f"channel {canon} is listed twice", line)
            out.append(canon)
        return tuple(out)


def _header(lines: Sequence[str], at: int, pattern: re.Pattern[str], what: str, source: str) -> tuple[str, int]:
    """The value of a ``Frames:`` / ``Frame Time:`` line: the next non-blank line from ``at``, and the line after it."""
    while at < len(lines) and not lines[at].strip():
        at += 1
    found = pattern.fullmatch(lines[at].strip()) if at < len(lines) else None
    if found is None or not found.group(1):
        if at < len(lines):
            raise BvhError(f"expected '{what}: ...', found {lines[at].strip()!r}", at + 1, source)
        raise BvhError(f"expected '{what}: ...', found the end of the file", len(lines), source)  # its last line
    return found.group(1), at + 1


def _frame_count(lines: Sequence[str], at: int, source: str) -> tuple[int, int]:
    """The ``Frames:`` line's count from ``at``, and the index after that line (also its 1-based line number)."""
    value, at = _header(lines, at, _FRAMES, "Frames", source)
    if not (value.isascii() and value.isdigit()):
        raise BvhError(f"Frames: expected a whole number, found {_short(value)!r}", at, source)
    frames = _whole_number(value)
    if frames is None or frames > MAX_FRAMES:
        raise BvhError(f"Frames: {_short(value.lstrip('0'))} is more than the {MAX_FRAMES} frames a file may declare",
                       at, source)
    return frames, at


def _frame_time(lines: Sequence[str], at: int, source: str) -> tuple[float, int]:
    """The ``Frame Time:`` line's seconds from ``at``, within the accepted frame rates, and the index after it."""
    value, at = _header(lines, at, _FRAME_TIME, "Frame Time", source)
    if not _NUMBER.fullmatch(value) or not (math.isfinite(float(value)) and float(value) > 0):
        raise BvhError(f"Frame Time: expected a positive number of seconds, found {value!r}", at, source)
    if not 1.0 / MAX_FPS <= float(value) <= 1.0 / MIN_FPS:
        with np.errstate(divide="ignore", over="ignore"):
            rate = float(np.divide(1.0, np.float64(value)))
        raise BvhError(f"Frame Time {float(value):g} s gives {rate:g} fps; accepted: {MIN_FPS:g} to {MAX_FPS:g} fps "
                       f"(Frame Time {1 / MAX_FPS:g} to {1 / MIN_FPS:g} s)", at, source)
    return float(value), at


def _frame_values(rows: Sequence[tuple[int, str]], frames: int, width: int, source: str) -> np.ndarray:
    """The frame lines ``(line number, text)`` as a frames x width array of finite numbers."""
    flat: list[str] = []
    for n, line in rows:
        values = line.split()
        if len(values) != width:
            raise BvhError(f"expected {width} numbers (one per channel), found {len(values)}", n, source)
        flat += values
    try:
        if any(_NOT_IN_NUMBERS.search(line) for _, line in rows):
            raise ValueError("not a plain number")
        motion = np.array(flat, dtype=np.float64).reshape(frames, width)
    except ValueError:  # only now, look for the culprit token by token
        culprit = next(((n, v) for n, line in rows for v in line.split() if not _NUMBER.fullmatch(v)), None)
        line_no, bad = culprit if culprit is not None else (None, "a value")
        raise BvhError(f"{bad!r} is not a number", line_no, source) from None
    if not np.isfinite(motion).all():
        row = int(np.argwhere(~np.isfinite(motion))[0][0])
        raise BvhError("a value is too large for a float", rows[row][0], source)
    return motion


def _parse_motion(lines: Sequence[str], at: int, width: int, source: str) -> tuple[float, np.ndarray]:
    frames, frames_line = _frame_count(lines, at, source)
    seconds, at = _frame_time(lines, frames_line, source)
    rows = [(n, line) for n, line in enumerate(lines[at:], at + 1) if line.strip()]
    if width == 0 and not rows:  # frames without channels are empty lines, as blank as the end of a file
        return seconds, np.zeros((frames, 0))
    if len(rows) != frames:
        where = rows[frames][0] if len(rows) > frames else frames_line  # the first extra line, or the count
        raise BvhError(f"Frames says {frames} but {len(rows)} frame lines follow", where, source)
    return seconds, _frame_values(rows, frames, width, source)
