"""BVH text to data: the joints, frame time and channel values a file holds, checked as they are read.

:func:`parse_bvh_parts` is what :meth:`model.motion.bvh.BvhDocument.parse` calls; errors are
:class:`BvhError` naming the line and the problem. Torch-free.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from itertools import chain
from typing import Any

import numpy as np

Vec3 = tuple[float, float, float]


def vec3(values: Iterable[float]) -> Vec3:
    """Three numbers as a ``Vec3`` (ValueError when there are more or fewer)."""
    x, y, z = values
    return (float(x), float(y), float(z))


POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
CHANNEL_NAMES = POSITION_CHANNELS + ROTATION_CHANNELS
# Readers in the wild write "XROTATION" or "xrotation"; names are matched case-insensitively and
# stored in the canonical spelling.
CANONICAL_CHANNEL = {c.lower(): c for c in CHANNEL_NAMES}
AXIS_INDEX = {"X": 0, "Y": 1, "Z": 2}

# Python's float() also accepts "1_000" and non-ASCII digits ("٩٣"), and so does ``\d`` in a str pattern:
# BVH numbers are plain ASCII decimals.
_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_FRAMES = re.compile(r"frames\s*:\s*(.*)", re.IGNORECASE)
_FRAME_TIME = re.compile(r"frame\s+time\s*:\s*(.*)", re.IGNORECASE)

# The most frames a file may declare. Frames of channel values are bounded by the text itself, but a
# hierarchy without channels has empty frames, so only this bounds what its count asks for.
MAX_FRAMES = 10_000_000
# Decimal digits of the largest count worth reading: int() refuses past 4,300 digits, and no count here
# needs more than a few.
_COUNT_DIGITS = 18

# The frame rates a file may declare: Frame Time 0.001 to 1 s. Past them 1 / frame time overflows (1e-310 gives
# infinity) or a resampled clip grows without bound.
MIN_FPS, MAX_FPS = 1.0, 1000.0

# A position channel of a non-root joint that moves more than this (file units) cannot be kept by
# a Clip, which has one fixed offset per bone.
BONE_TRANSLATION_TOLERANCE = 0.01


class BvhError(ValueError):
    """Malformed BVH input; ``str(err)`` reads ``"walk.bvh:137: expected 132 numbers, found 131"``.

    Attributes:
        line: 1-based line number of the problem, or ``None`` when it has no single line.
        source: the file name (or ``"<string>"``) the text came from.
        problem: the message without the location.
    """

    def __init__(self, problem: str, line: int | None = None, source: str = "<string>") -> None:
        self.problem = problem
        self.line = line
        self.source = source
        where = source if line is None else f"{source}:{line}"
        super().__init__(f"{where}: {problem}")

    # Keeps line and source when errors cross process boundaries.
    def __reduce__(self) -> tuple[type[BvhError], tuple[str, int | None, str]]:
        return (type(self), (self.problem, self.line, self.source))


def _vec3(value: Sequence[float], what: str) -> Vec3:
    vals = tuple(float(v) for v in value)
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
        raise ValueError(f"{what} must be three finite numbers, got {value!r}")
    return vals


@dataclass(frozen=True)
class BvhJoint:
    """One ROOT or JOINT block.

    Attributes:
        name: joint name as written.
        parent: index of the parent joint in :attr:`BvhDocument.joints`, -1 for the root.
        offset: the OFFSET line.
        channels: channel names in file order, e.g. ``("Zrotation", "Xrotation", "Yrotation")``.
        end_site: the OFFSET of the joint's End Site, or ``None`` when it has none.
    """

    name: str
    parent: int
    offset: Vec3
    channels: tuple[str, ...] = ()
    end_site: Vec3 | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "offset", _vec3(self.offset, f"offset of joint {self.name!r}"))
        if self.end_site is not None:
            object.__setattr__(self, "end_site", _vec3(self.end_site, f"End Site of joint {self.name!r}"))
        canon = []
        for c in self.channels:
            key = CANONICAL_CHANNEL.get(str(c).lower())
            if key is None:
                raise ValueError(f"joint {self.name!r}: unknown channel {c!r} (known: {', '.join(CHANNEL_NAMES)})")
            canon.append(key)
        if len(set(canon)) != len(canon):
            raise ValueError(f"joint {self.name!r}: a channel is listed twice in {tuple(self.channels)}")
        object.__setattr__(self, "channels", tuple(canon))
        if not self.name or any(ch.isspace() for ch in self.name[:1] + self.name[-1:]):
            raise ValueError(f"joint name {self.name!r} must be non-empty without surrounding spaces")

    @property
    def rotation_order(self) -> str:
        """Axes of the rotation channels in file order, e.g. ``"ZXY"`` (``""`` when none)."""
        return "".join(c[0] for c in self.channels if c in ROTATION_CHANNELS)


def is_number(text: str) -> bool:
    """Whether ``text`` is a BVH number: a plain ASCII decimal (no ``nan``, ``inf``, ``1_000`` or ``٩٣``)."""
    return _NUMBER.fullmatch(text) is not None


def frame_time_problem(frame_time: float) -> str | None:
    """What is wrong with a Frame Time of ``frame_time`` seconds, or None when its rate is within
    ``MIN_FPS`` to ``MAX_FPS``."""
    if math.isfinite(frame_time) and 1.0 / MAX_FPS <= frame_time <= 1.0 / MIN_FPS:
        return None
    with np.errstate(divide="ignore", over="ignore"):
        rate = float(np.divide(1.0, np.float64(frame_time)))
    return (f"Frame Time {frame_time:g} s gives {rate:g} fps; accepted: {MIN_FPS:g} to {MAX_FPS:g} fps (Frame Time "
            f"{1 / MAX_FPS:g} to {1 / MIN_FPS:g} s)")


def fps_from_frame_time(frame_time: float) -> float:
    """``1 / frame_time``, snapped to the nearest integer when within 1e-4 relative.

    Files store ``1/30`` as ``0.0333333``; taking 30.000003 fps literally would make
    ``Clip.resample(30)`` interpolate every frame and drop the last one.

    Raises:
        ValueError: the rate is not a finite number (a frame time of 1e-310 s), named as the reader names it.
    """
    with np.errstate(divide="ignore", over="ignore"):
        fps = float(np.divide(1.0, np.float64(frame_time)))
    if not math.isfinite(fps):
        raise ValueError(frame_time_problem(frame_time))
    whole = round(fps)
    if whole >= 1 and abs(fps - whole) <= 1e-4 * fps:
        return float(whole)
    return fps


# The items a joint block may hold once each, as named in errors.
_JOINT_PARTS = {"OFFSET": "OFFSET", "CHANNELS": "CHANNELS", "END": "End Site"}


def whole_number(text: str) -> int | None:
    """``text`` as a non-negative integer when it is plain ASCII digits of a sane size, else ``None``.

    Leading zeros are allowed; a count of more than ``_COUNT_DIGITS`` significant digits is ``None``
    (no allocation or ``int()`` ever sees it).
    """
    digits = text.lstrip("0") or "0"  # int() counts leading zeros towards its 4,300-digit limit too
    if not (text.isascii() and text.isdigit()) or len(digits) > _COUNT_DIGITS:
        return None
    return int(digits)


def shorten(text: str, keep: int = 24) -> str:
    """``text`` for an error message: at most ``keep`` characters, the rest counted (a 4,300-digit count
    is not echoed whole)."""
    return text if len(text) <= keep else f"{text[:keep]}... ({len(text)} characters)"


class _Parser:
    """Recursive-descent parser for the hierarchy, bulk numpy conversion for the motion."""

    def __init__(self, text: str, source: str) -> None:
        self.source = source
        if text.startswith("\ufeff"):
            text = text[1:]
        # Split on "\n" only (not str.splitlines) so line numbers match what editors show;
        # a trailing "\r" disappears in str.split().
        self.lines = text.split("\n")
        self.tokens: list[tuple[str, int]] = []
        self.pos = 0
        self.motion_line = -1  # 0-based index of the MOTION line, -1 when there is none
        self.frames_line = 0  # 1-based line of "Frames:", set once it is read
        for i, line in enumerate(self.lines):
            toks = line.split()
            if toks and toks[0].upper() == "MOTION":
                self.tokens.append((toks[0], i + 1))
                self.motion_line = i
                break
            self.tokens.extend((t, i + 1) for t in toks)
        # A joint's entry is None until its block closes; children only need its index.
        self.joints: list[BvhJoint | None] = []
        self.names: set[str] = set()
        self.closed: list[BvhJoint] = []  # the finished joints, for naming motion columns

    def error(self, problem: str, line: int | None) -> BvhError:
        return BvhError(problem, line, self.source)

    # -------------------------------------------------------------- token helpers
    def peek(self) -> tuple[str, int] | None:
        return self.tokens[self.pos] if self.pos < len(self.tokens) else None

    def next(self, expected: str) -> tuple[str, int]:
        tok = self.peek()
        if tok is None:
            raise self.error(f"unexpected end of file: expected {expected}", self.last_line())
        self.pos += 1
        return tok

    def last_line(self) -> int:
        n = len(self.lines)
        while n > 1 and not self.lines[n - 1].strip():
            n -= 1
        return n

    def rest_of_line(self, line: int) -> list[str]:
        """Tokens left on ``line``, stopping before a brace (``OFFSET 0 0 0 }`` is tolerated)."""
        out = []
        while (tok := self.peek()) is not None and tok[1] == line and tok[0] not in ("{", "}"):
            out.append(tok[0])
            self.pos += 1
        return out

    def number(self, tok: str, line: int, what: str) -> float:
        if not _NUMBER.fullmatch(tok):
            raise self.error(f"{what}: {tok!r} is not a number", line)
        return float(tok)

    # -------------------------------------------------------------- grammar
    def parse(self) -> tuple[list[BvhJoint], float, np.ndarray]:
        tok = self.peek()
        if tok is None:
            raise self.error("empty input: expected HIERARCHY", 1)
        if tok[0].upper() != "HIERARCHY":
            raise self.error(f"expected HIERARCHY, found {tok[0]!r}", tok[1])
        self.pos += 1
        word, line = self.next("ROOT")
        if word.upper() != "ROOT":
            raise self.error(f"expected ROOT, found {word!r}", line)
        self.joint(-1, line)
        tok = self.peek()
        if tok is None:
            raise self.error("missing MOTION section after the hierarchy", self.last_line())
        if tok[0].upper() == "ROOT":
            raise self.error("a second ROOT: a BVH file here must hold exactly one hierarchy", tok[1])
        if tok[0].upper() != "MOTION":
            raise self.error(f"expected MOTION after the hierarchy, found {tok[0]!r}", tok[1])
        frames, frame_time, motion_start = self.motion_header()
        joints = [j for j in self.joints if j is not None]  # every block has closed by now
        motion = self.motion(joints, frames, motion_start)
        return joints, frame_time, motion

    def joint(self, parent: int, line: int) -> None:
        kind = "ROOT" if parent < 0 else "JOINT"
        name = self._joint_name(kind, line)
        index = len(self.joints)
        self.joints.append(None)
        parts: dict[str, Any] = {}
        while not self._joint_item(kind, name, index, line, parts):
            pass
        if "OFFSET" not in parts:
            raise self.error(f"{kind} {name} has no OFFSET", line)
        try:
            self.joints[index] = BvhJoint(name, parent, parts["OFFSET"], parts.get("CHANNELS", ()), parts.get("END"))
        except ValueError as exc:  # BvhJoint's own checks; the parser should have caught them
            raise self.error(str(exc), line) from exc

    def _joint_name(self, kind: str, line: int) -> str:
        """The name after ROOT or JOINT (unique in the file), and the opening brace."""
        name_tokens = self.rest_of_line(line)
        if not name_tokens:
            raise self.error(f"{kind} without a name", line)
        name = " ".join(name_tokens)
        if name in self.names:
            raise self.error(f"joint name {name!r} is used twice", line)
        self.names.add(name)
        tok = self.next(f"'{{' to open {kind} {name}")
        if tok[0] != "{":
            raise self.error(f"expected '{{' after {kind} {name}, found {tok[0]!r}", tok[1])
        return name

    def _joint_item(self, kind: str, name: str, index: int, line: int, parts: dict[str, Any]) -> bool:
        """Read one item of a joint block into ``parts``; True at the block's closing brace."""
        tok = self.peek()
        if tok is None:
            raise self.error(f"unexpected end of file: {kind} {name} (line {line}) is never closed with '}}'",
                             self.last_line())
        word, wline = tok
        up = word.upper()
        self.pos += 1
        if up in _JOINT_PARTS:
            if up in parts:
                raise self.error(f"second {_JOINT_PARTS[up]} in {kind} {name}", wline)
            if up == "OFFSET":
                parts[up] = self.offset(wline, f"OFFSET of {name}")
            elif up == "CHANNELS":
                parts[up] = self.channels(wline, name)
            else:
                parts[up] = self.end_site(wline, name)
            return False
        if up == "JOINT":
            self.joint(index, wline)
            return False
        if word == "}":
            return True
        if up == "ROOT":
            raise self.error("a second ROOT: a BVH file here must hold exactly one hierarchy", wline)
        if up == "MOTION":
            raise self.error(f"missing '}}': {kind} {name} (line {line}) is not closed before MOTION", wline)
        raise self.error(f"unexpected {word!r} in {kind} {name}", wline)

    def offset(self, line: int, what: str) -> Vec3:
        vals = self.rest_of_line(line)
        if len(vals) != 3:
            raise self.error(f"{what}: expected 3 numbers, found {len(vals)}", line)
        out = vec3(self.number(v, line, what) for v in vals)
        if not all(math.isfinite(v) for v in out):
            raise self.error(f"{what}: not a finite number", line)
        return out

    def channels(self, line: int, name: str) -> tuple[str, ...]:
        words = self.rest_of_line(line)
        if not words:
            raise self.error(f"CHANNELS of {name}: missing the channel count", line)
        count, names = words[0], words[1:]
        if not (count.isascii() and count.isdigit()):
            raise self.error(f"CHANNELS of {name}: the count {shorten(count)!r} is not a whole number", line)
        declared = whole_number(count)
        canon = []
        for c in names:
            key = CANONICAL_CHANNEL.get(c.lower())
            if key is None:
                raise self.error(f"CHANNELS of {name}: unknown channel {c!r} (known: {', '.join(CHANNEL_NAMES)})", line)
            if key in canon:
                raise self.error(f"CHANNELS of {name}: {key} is listed twice", line)
            canon.append(key)
        if declared != len(names):
            shown = shorten(count.lstrip("0")) if declared is None else declared
            raise self.error(f"CHANNELS of {name}: declares {shown} channels but lists {len(names)}", line)
        return tuple(canon)

    def end_site(self, line: int, name: str) -> Vec3:
        word, wline = self.next("Site")
        if word.upper() != "SITE":
            raise self.error(f"expected 'End Site', found 'End {word}'", wline)
        tok = self.next("'{' to open End Site")
        if tok[0] != "{":
            raise self.error(f"expected '{{' after End Site of {name}, found {tok[0]!r}", tok[1])
        word, wline = self.next(f"OFFSET in the End Site of {name}")
        if word.upper() != "OFFSET":
            raise self.error(f"expected OFFSET in the End Site of {name}, found {word!r}", wline)
        offset = self.offset(wline, f"End Site OFFSET of {name}")
        tok = self.next(f"'}}' to close the End Site of {name}")
        if tok[0] != "}":
            raise self.error(f"expected '}}' to close the End Site of {name}, found {tok[0]!r}", tok[1])
        return offset

    def motion_header(self) -> tuple[int, float, int]:
        """``(frames, frame_time, index of the first motion line)``."""
        i = self.motion_line
        rest = self.lines[i].split()[1:]
        if rest:
            raise self.error(f"unexpected {rest[0]!r} after MOTION", i + 1)
        i = self._next_nonblank(i + 1, "Frames:")
        m = _FRAMES.fullmatch(self.lines[i].strip())
        if not m:
            raise self.error(f"expected 'Frames: <count>', found {self.lines[i].strip()!r}", i + 1)
        count = m.group(1)
        if not (count.isascii() and count.isdigit()):
            raise self.error(f"Frames: {shorten(count)!r} is not a whole number", i + 1)
        frames = whole_number(count)
        if frames is None or frames > MAX_FRAMES:
            raise self.error(f"Frames: {shorten(count.lstrip('0'))} is more than the {MAX_FRAMES} frames a file may "
                             "declare", i + 1)
        self.frames_line = i + 1
        i = self._next_nonblank(i + 1, "Frame Time:")
        m = _FRAME_TIME.fullmatch(self.lines[i].strip())
        if not m:
            raise self.error(f"expected 'Frame Time: <seconds>', found {self.lines[i].strip()!r}", i + 1)
        ft = self.number(m.group(1), i + 1, "Frame Time")
        if not (math.isfinite(ft) and ft > 0):
            raise self.error(f"Frame Time must be a positive number of seconds, found {m.group(1)}", i + 1)
        problem = frame_time_problem(ft)
        if problem is not None:
            raise self.error(problem, i + 1)
        return frames, ft, i + 1

    def _next_nonblank(self, i: int, expected: str) -> int:
        while i < len(self.lines) and not self.lines[i].strip():
            i += 1
        if i >= len(self.lines):
            raise self.error(f"unexpected end of file: expected {expected}", self.last_line())
        return i

    def motion(self, joints: list[BvhJoint], frames: int, start: int) -> np.ndarray:
        body = self.lines[start:]
        while body and not body[-1].strip():
            body.pop()
        self.closed = joints
        width = sum(len(j.channels) for j in joints)
        if width == 0 and not body:
            return np.zeros((frames, 0))
        rows = [ln.split() for ln in body]
        # 1-based line of each row; None while row k is simply line start + k + 1.
        row_lines: list[int] | None = None
        if len(rows) != frames or any(len(r) != width for r in rows):
            rows, row_lines = self._check_shape(rows, frames, width, start)

        def line_of(frame: int) -> int:
            return start + frame + 1 if row_lines is None else row_lines[frame]

        flat = list(chain.from_iterable(rows))
        # Python's float syntax is wider than BVH's (underscores, non-ASCII digits): lines holding
        # such characters are checked token by token.
        values = None
        if not any("_" in ln or not ln.isascii() for ln in body):
            try:
                values = np.array(flat, dtype=np.float64)
            except ValueError:
                pass
        if values is None:
            self._locate_bad_token(rows, line_of)
            try:
                values = np.array(flat, dtype=np.float64)
            except ValueError as exc:  # not expected: the token check is the stricter one
                raise self.error(f"motion data could not be read: {exc}", None) from exc
        values = values.reshape(frames, width)
        finite = np.isfinite(values)
        if not finite.all():
            frame, col = (int(v) for v in np.argwhere(~finite)[0])
            raise self.error(f"{rows[frame][col]!r} is not a finite number ({self._column_name(col)})", line_of(frame))
        return values

    def _column_name(self, col: int) -> str:
        for j in self.closed:
            if col < len(j.channels):
                return f"joint {j.name}, channel {j.channels[col]}"
            col -= len(j.channels)
        return f"column {col}"

    def _check_shape(
        self, rows: list[list[str]], frames: int, width: int, start: int
    ) -> tuple[list[list[str]], list[int]]:
        """Raise for a line with the wrong count or a frame count mismatch; else drop blank lines."""
        kept: list[list[str]] = []
        lines: list[int] = []
        for k, r in enumerate(rows):
            if not r:
                continue  # a stray blank line between frames carries no data
            if len(r) != width:
                raise self.error(f"expected {width} numbers, found {len(r)}", start + k + 1)
            if len(kept) == frames:
                raise self.error(
                    f"more motion lines than the {frames} frames declared on line {self.frames_line}", start + k + 1
                )
            kept.append(r)
            lines.append(start + k + 1)
        if len(kept) < frames:
            raise self.error(
                f"Frames: declares {frames} frames but the motion has {len(kept)} lines "
                f"(the file ends at line {self.last_line()})",
                self.frames_line,
            )
        return kept, lines

    def _locate_bad_token(self, rows: list[list[str]], line_of: Callable[[int], int]) -> None:
        for frame, r in enumerate(rows):
            for col, tok in enumerate(r):
                # NaN and inf are numbers here; the finite check names them afterwards.
                if not _NUMBER.fullmatch(tok) and tok.lower().lstrip("+-") not in ("nan", "inf", "infinity"):
                    raise self.error(f"{tok!r} is not a number ({self._column_name(col)})", line_of(frame))


def parse_bvh_parts(text: str, source: str = "<string>") -> tuple[list[BvhJoint], float, np.ndarray]:
    """The joints, frame time and ``[frames, channels]`` motion of BVH text (see :class:`BvhError`).

    Any text either parses or raises :class:`BvhError`; nothing else escapes (a hierarchy nested past
    the interpreter's recursion limit included).
    """
    try:
        return _Parser(text, source).parse()
    except RecursionError:
        raise BvhError("the hierarchy is nested too deeply to read", None, source) from None
