"""BVH motion files: a faithful document model (parse, check, format) and conversion to and from :class:`Clip`.

:class:`BvhDocument` keeps a file exactly as written (any single-root hierarchy, any channel set and
order per joint, End Sites, any frame time) so that ``parse -> format -> parse`` is lossless.
:func:`to_clip` interprets it for the model: the profile's root joint becomes joint 0 (joints above it
are folded into it), position channels replace OFFSETs, and rotation channels are intrinsic Euler
angles in degrees applied in the order they are listed. :func:`from_clip` goes back.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from itertools import chain
from pathlib import Path

import numpy as np
import torch

from model.clip import Clip
from model.rotations import (
    DEG,
    axis_angle_to_quat,
    euler_to_quat,
    quat_identity,
    quat_make_continuous,
    quat_mul,
    quat_normalize,
    quat_rotate,
    quat_to_euler,
)
from model.skeleton import BUILTIN_PROFILES, Skeleton, SkeletonError, SkeletonProfile, plain_joint_name, resolve_roles

logger = logging.getLogger(__name__)

Vec3 = tuple[float, float, float]

POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
CHANNEL_NAMES = POSITION_CHANNELS + ROTATION_CHANNELS
# Readers in the wild write "XROTATION" or "xrotation"; names are matched case-insensitively and
# stored in the canonical spelling.
_CANONICAL = {c.lower(): c for c in CHANNEL_NAMES}
_AXIS = {"X": 0, "Y": 1, "Z": 2}

# Python's float() also accepts "1_000" and non-ASCII digits; BVH numbers are plain ASCII decimals.
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_FRAMES = re.compile(r"frames\s*:\s*(.*)", re.IGNORECASE)
_FRAME_TIME = re.compile(r"frame\s+time\s*:\s*(.*)", re.IGNORECASE)

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
    return vals  # type: ignore[return-value]


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
            key = _CANONICAL.get(str(c).lower())
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


@dataclass(eq=False)
class BvhDocument:
    """A BVH file as data.

    Attributes:
        joints: ROOT and JOINT blocks in file order (parents always come before their children).
        frame_time: seconds per frame, as written.
        motion: ``[frames, total_channels]`` float64 channel values as written (degrees for
            rotations), columns in joint order then each joint's channel order.
    """

    joints: list[BvhJoint]
    frame_time: float
    motion: np.ndarray

    def __post_init__(self) -> None:
        self.joints = list(self.joints)
        if not self.joints:
            raise ValueError("a BVH document needs at least one joint")
        names = [j.name for j in self.joints]
        if len(set(names)) != len(names):
            dup = sorted({n for n in names if names.count(n) > 1})
            raise ValueError(f"joint names must be unique; repeated: {', '.join(dup)}")
        if self.joints[0].parent != -1 or any(not 0 <= j.parent < i for i, j in enumerate(self.joints) if i):
            raise ValueError("joints must form one hierarchy in topological order: the root first, parents before children")
        self.frame_time = float(self.frame_time)
        if not (math.isfinite(self.frame_time) and self.frame_time > 0):
            raise ValueError(f"frame_time must be a positive number of seconds, got {self.frame_time}")
        motion = np.asarray(self.motion, dtype=np.float64)
        width = self.num_channels
        if motion.ndim == 1 and motion.size == 0:
            motion = motion.reshape(0, width)
        if motion.ndim != 2 or motion.shape[1] != width:
            raise ValueError(f"motion must be [frames, {width}] for these joints' channels, got {list(motion.shape)}")
        self.motion = motion

    # ------------------------------------------------------------------ structure
    @property
    def names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def parents(self) -> tuple[int, ...]:
        return tuple(j.parent for j in self.joints)

    @property
    def num_frames(self) -> int:
        return int(self.motion.shape[0])

    @property
    def num_channels(self) -> int:
        return sum(len(j.channels) for j in self.joints)

    @property
    def fps(self) -> float:
        """Frames per second, snapped to a whole number when the frame time is a rounded ``1/n``."""
        return _fps_from_frame_time(self.frame_time)

    def channel_slices(self) -> list[slice]:
        """Per joint, the columns of :attr:`motion` that hold its channels."""
        out, start = [], 0
        for j in self.joints:
            out.append(slice(start, start + len(j.channels)))
            start += len(j.channels)
        return out

    def joint_index(self, name: str) -> int:
        for i, j in enumerate(self.joints):
            if j.name == name:
                return i
        raise KeyError(f"no joint named {name!r}")

    def channel_index(self, joint: str, channel: str) -> int:
        """The motion column of one joint's channel."""
        i = self.joint_index(joint)
        key = _CANONICAL.get(channel.lower(), channel)
        try:
            return self.channel_slices()[i].start + self.joints[i].channels.index(key)
        except ValueError:
            raise KeyError(f"joint {joint!r} has no channel {channel!r}") from None

    def children(self) -> list[list[int]]:
        kids: list[list[int]] = [[] for _ in self.joints]
        for i, j in enumerate(self.joints):
            if j.parent >= 0:
                kids[j.parent].append(i)
        return kids

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, BvhDocument):
            return NotImplemented
        return (
            self.joints == other.joints
            and self.frame_time == other.frame_time
            and self.motion.shape == other.motion.shape
            and bool(np.array_equal(self.motion, other.motion))
        )

    # ------------------------------------------------------------------ reading
    @classmethod
    def parse(cls, text: str, source: str = "<string>") -> BvhDocument:
        """Parse BVH text; malformed input raises :class:`BvhError` naming the line and the problem."""
        return _Parser(text, source).parse()

    @classmethod
    def read(cls, path: str | Path) -> BvhDocument:
        path = Path(path)
        raw = path.read_bytes()
        try:
            text = raw.decode("utf-8-sig")
        except UnicodeDecodeError:
            # Some exporters write joint names in a legacy code page; latin-1 never fails.
            text = raw.decode("latin-1")
        return cls.parse(text, source=str(path))

    # ------------------------------------------------------------------ writing
    def format(self, precision: int | None = 6) -> str:
        """BVH text: tab-indented hierarchy, then ``MOTION``, ``Frames:``, ``Frame Time:`` and the frames.

        Motion values get ``precision`` decimals (``None``: the shortest text that reads back
        exactly). OFFSETs and the frame time are always written exactly.
        """
        if not np.isfinite(self.motion).all():
            raise ValueError("motion holds NaN or infinite values, which BVH cannot store")
        kids = self.children()
        lines = ["HIERARCHY"]
        order: list[int] = []
        # Iterative pre-order walk: a writer must not hit the recursion limit on a deep chain.
        stack: list[tuple[int, int, bool]] = [(0, 0, False)]
        while stack:
            j, depth, closing = stack.pop()
            ind = "\t" * depth
            joint = self.joints[j]
            if closing:
                if joint.end_site is not None:
                    lines += [f"{ind}\tEnd Site", f"{ind}\t{{", f"{ind}\t\tOFFSET {_fmt3(joint.end_site)}", f"{ind}\t}}"]
                lines.append(f"{ind}}}")
                continue
            order.append(j)
            lines += [f"{ind}{'ROOT' if depth == 0 else 'JOINT'} {joint.name}", f"{ind}{{",
                      f"{ind}\tOFFSET {_fmt3(joint.offset)}"]
            lines.append(f"{ind}\tCHANNELS {len(joint.channels)}" + "".join(" " + c for c in joint.channels))
            stack.append((j, depth, True))
            stack.extend((k, depth + 1, False) for k in reversed(kids[j]))
        lines += ["MOTION", f"Frames: {self.num_frames}", f"Frame Time: {_num(self.frame_time)}"]
        motion = self.motion
        if order != list(range(len(self.joints))):
            # Joints given in another topological order are written nested, so columns follow.
            slices = self.channel_slices()
            motion = motion[:, [c for j in order for c in range(slices[j].start, slices[j].stop)]]
        if precision is None:
            lines.extend(" ".join(map(repr, row)) for row in motion.tolist())
        else:
            row_fmt = " ".join([f"%.{int(precision)}f"] * motion.shape[1])
            lines.extend(row_fmt % tuple(row) for row in motion.tolist())
        return "\n".join(lines) + "\n"

    def write(self, path: str | Path, precision: int | None = 6) -> None:
        Path(path).write_text(self.format(precision), encoding="utf-8")


def _num(v: float) -> str:
    # repr is the shortest text that reads back to the same float.
    return repr(float(v))


def _fmt3(v: Vec3) -> str:
    return " ".join(_num(x) for x in v)


def _fps_from_frame_time(frame_time: float) -> float:
    """``1 / frame_time``, snapped to the nearest integer when within 1e-4 relative.

    Files store ``1/30`` as ``0.0333333``; taking 30.000003 fps literally would make
    ``Clip.resample(30)`` interpolate every frame and drop the last one.
    """
    fps = 1.0 / frame_time
    whole = round(fps)
    if whole >= 1 and abs(fps - whole) <= 1e-4 * fps:
        return float(whole)
    return fps


# ====================================================================== parsing


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
    def parse(self) -> BvhDocument:
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
        return BvhDocument(joints, frame_time, motion)

    def joint(self, parent: int, line: int) -> None:
        kind = "ROOT" if parent < 0 else "JOINT"
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
        index = len(self.joints)
        self.joints.append(None)
        offset: Vec3 | None = None
        channels: tuple[str, ...] | None = None
        end_site: Vec3 | None = None
        while True:
            tok = self.peek()
            if tok is None:
                raise self.error(f"unexpected end of file: {kind} {name} (line {line}) is never closed with '}}'",
                                 self.last_line())
            word, wline = tok
            up = word.upper()
            self.pos += 1
            if up == "OFFSET":
                if offset is not None:
                    raise self.error(f"second OFFSET in {kind} {name}", wline)
                offset = self.offset(wline, f"OFFSET of {name}")
            elif up == "CHANNELS":
                if channels is not None:
                    raise self.error(f"second CHANNELS in {kind} {name}", wline)
                channels = self.channels(wline, name)
            elif up == "JOINT":
                self.joint(index, wline)
            elif up == "END":
                if end_site is not None:
                    raise self.error(f"second End Site in {kind} {name}", wline)
                end_site = self.end_site(wline, name)
            elif word == "}":
                break
            elif up == "ROOT":
                raise self.error("a second ROOT: a BVH file here must hold exactly one hierarchy", wline)
            elif up == "MOTION":
                raise self.error(f"missing '}}': {kind} {name} (line {line}) is not closed before MOTION", wline)
            else:
                raise self.error(f"unexpected {word!r} in {kind} {name}", wline)
        if offset is None:
            raise self.error(f"{kind} {name} has no OFFSET", line)
        try:
            self.joints[index] = BvhJoint(name, parent, offset, channels or (), end_site)
        except ValueError as exc:  # BvhJoint's own checks; the parser should have caught them
            raise self.error(str(exc), line) from exc

    def offset(self, line: int, what: str) -> Vec3:
        vals = self.rest_of_line(line)
        if len(vals) != 3:
            raise self.error(f"{what}: expected 3 numbers, found {len(vals)}", line)
        out = tuple(self.number(v, line, what) for v in vals)
        if not all(math.isfinite(v) for v in out):
            raise self.error(f"{what}: not a finite number", line)
        return out  # type: ignore[return-value]

    def channels(self, line: int, name: str) -> tuple[str, ...]:
        words = self.rest_of_line(line)
        if not words:
            raise self.error(f"CHANNELS of {name}: missing the channel count", line)
        count, names = words[0], words[1:]
        if not (count.isascii() and count.isdigit()):
            raise self.error(f"CHANNELS of {name}: the count {count!r} is not a whole number", line)
        canon = []
        for c in names:
            key = _CANONICAL.get(c.lower())
            if key is None:
                raise self.error(f"CHANNELS of {name}: unknown channel {c!r} (known: {', '.join(CHANNEL_NAMES)})", line)
            if key in canon:
                raise self.error(f"CHANNELS of {name}: {key} is listed twice", line)
            canon.append(key)
        if int(count) != len(names):
            raise self.error(f"CHANNELS of {name}: declares {int(count)} channels but lists {len(names)}", line)
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
        if not (m.group(1).isascii() and m.group(1).isdigit()):
            raise self.error(f"Frames: {m.group(1)!r} is not a whole number", i + 1)
        frames = int(m.group(1))
        self.frames_line = i + 1
        i = self._next_nonblank(i + 1, "Frame Time:")
        m = _FRAME_TIME.fullmatch(self.lines[i].strip())
        if not m:
            raise self.error(f"expected 'Frame Time: <seconds>', found {self.lines[i].strip()!r}", i + 1)
        ft = self.number(m.group(1), i + 1, "Frame Time")
        if not (math.isfinite(ft) and ft > 0):
            raise self.error(f"Frame Time must be a positive number of seconds, found {m.group(1)}", i + 1)
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


# ====================================================================== to and from Clip


def _fit_profile(doc: BvhDocument, profile: SkeletonProfile | str | Path | None) -> tuple[SkeletonProfile, int, list[int]]:
    """The profile, the file index of its root joint, and the joints kept (root then descendants)."""
    names = doc.names
    plain = [plain_joint_name(n) for n in names]
    candidates = [profile] if profile is not None else list(BUILTIN_PROFILES)
    errors: list[str] = []
    for cand in candidates:
        prof = cand if isinstance(cand, SkeletonProfile) else SkeletonProfile.load(cand)
        try:
            if plain_joint_name(prof.root) not in plain:
                resolve_roles(names, prof)  # raises, listing every joint the rig lacks
                raise SkeletonError(f"no joint {prof.root!r} (root of profile {prof.name!r})")
            root = plain.index(plain_joint_name(prof.root))
            inside = [False] * len(names)
            inside[root] = True
            # File order is topological, so one pass marks the whole subtree.
            for i in range(root + 1, len(names)):
                inside[i] = inside[doc.joints[i].parent]
            kept = [i for i in range(len(names)) if inside[i]]
            resolve_roles(tuple(names[i] for i in kept), prof)
            return prof, root, kept
        except SkeletonError as exc:
            errors.append(str(exc))
    if profile is not None:
        raise SkeletonError(errors[0])
    raise SkeletonError("no built-in skeleton profile fits this rig:\n  " + "\n  ".join(errors))


def _local_rotations(doc: BvhDocument, joints: Sequence[int]) -> torch.Tensor:
    """Local rotation quaternions ``[T, len(joints), 4]`` (float64) from the rotation channels.

    Joints sharing an axis order are converted in one batched call: per-joint calls dominated
    the import time of the real data set.
    """
    frames = doc.num_frames
    out = quat_identity((frames, len(joints)), torch.float64)
    slices = doc.channel_slices()
    groups: dict[str, tuple[list[int], list[list[int]]]] = {}
    eye = torch.eye(3, dtype=torch.float64)
    for n, j in enumerate(joints):
        start = slices[j].start
        rot = [(c[0], start + k) for k, c in enumerate(doc.joints[j].channels) if c in ROTATION_CHANNELS]
        axes = "".join(a for a, _ in rot)
        if len(axes) == 3:
            members, cols = groups.setdefault(axes, ([], []))
            members.append(n)
            cols.append([c for _, c in rot])
        elif axes:
            # One or two rotation channels: compose them in file order, like the three-channel case.
            radians = torch.from_numpy(doc.motion[:, [c for _, c in rot]]) / DEG
            q = out[:, n]
            for m, a in enumerate(axes):
                q = quat_mul(q, axis_angle_to_quat(eye[_AXIS[a]].expand(frames, 3), radians[:, m]))
            out[:, n] = q
    for axes, (members, cols) in groups.items():
        radians = torch.from_numpy(doc.motion[:, cols]) / DEG  # [T, G, 3]
        out[:, members] = euler_to_quat(radians, axes)
    return out


def _local_translation(doc: BvhDocument, j: int) -> torch.Tensor:
    """Per-frame translation ``[T, 3]``: the OFFSET, with each position channel replacing its axis."""
    joint = doc.joints[j]
    t = np.tile(np.asarray(joint.offset, dtype=np.float64), (doc.num_frames, 1))
    start = doc.channel_slices()[j].start
    for k, c in enumerate(joint.channels):
        if c in POSITION_CHANNELS:
            t[:, _AXIS[c[0]]] = doc.motion[:, start + k]
    return torch.from_numpy(t)


def _static_offsets(doc: BvhDocument, joints: Sequence[int], clip_name: str) -> list[Vec3]:
    """Fixed bone offsets: the OFFSET, with position channels replaced by their mean over frames."""
    slices = doc.channel_slices()
    offsets = []
    for j in joints:
        joint = doc.joints[j]
        offset = list(joint.offset)
        found = [(_AXIS[c[0]], slices[j].start + k, c) for k, c in enumerate(joint.channels) if c in POSITION_CHANNELS]
        if found and doc.num_frames:
            values = doc.motion[:, [col for _, col, _ in found]]
            means = values.mean(axis=0)
            deviations = np.abs(values - means).max(axis=0)
            for (axis, _, channel), mean, deviation in zip(found, means.tolist(), deviations.tolist()):
                offset[axis] = mean
                if deviation > BONE_TRANSLATION_TOLERANCE:
                    logger.warning(
                        "%s: joint %s channel %s moves by up to %.4g from its mean %.4g; a Clip keeps "
                        "one fixed offset per bone, so the mean is used",
                        clip_name or "BVH", joint.name, channel, deviation, mean,
                    )
        offsets.append(tuple(offset))
    return offsets  # type: ignore[return-value]


def to_clip(
    doc: BvhDocument,
    profile: SkeletonProfile | str | Path | None = None,
    name: str = "",
    dtype: torch.dtype = torch.float32,
) -> Clip:
    """Interpret a BVH document as a :class:`Clip` on the rig that ``profile`` describes.

    The profile's root joint (auto-detected from the built-in profiles when ``profile`` is None)
    becomes joint 0: joints above it are folded into its world transform exactly, joints outside
    its subtree are dropped. Position channels replace OFFSET components. A non-root joint's
    position channels become its fixed offset (their mean); if they move by more than
    ``BONE_TRANSLATION_TOLERANCE`` a warning is logged, since a Clip cannot animate bone lengths.
    Everything is computed in float64 and converted to ``dtype`` at the end.
    """
    prof, root, kept = _fit_profile(doc, profile)
    frames = doc.num_frames

    lineage = [root]  # the root and its ancestors, file root last
    while doc.joints[lineage[-1]].parent >= 0:
        lineage.append(doc.joints[lineage[-1]].parent)
    lineage.reverse()
    local = _local_rotations(doc, lineage[:-1] + kept)  # ancestors, then the root and its subtree
    ancestors = len(lineage) - 1
    pos = torch.zeros(frames, 3, dtype=torch.float64)
    rot = quat_identity((frames,), torch.float64)
    for n, a in enumerate(lineage):
        pos = pos + quat_rotate(rot, _local_translation(doc, a))
        rot = quat_mul(rot, local[:, n])
    quats = local[:, ancestors:].clone()
    quats[:, 0] = rot
    offsets: list[Vec3] = [(0.0, 0.0, 0.0)] + _static_offsets(doc, kept[1:], name)

    new_index = {j: n for n, j in enumerate(kept)}
    parents = [-1] + [new_index[doc.joints[j].parent] for j in kept[1:]]
    end_sites = tuple((new_index[j], doc.joints[j].end_site) for j in kept if doc.joints[j].end_site is not None)
    skeleton = Skeleton.build(
        [doc.joints[j].name for j in kept], parents, offsets, profile=prof, end_sites=end_sites  # type: ignore[arg-type]
    )
    if frames:
        # Sign continuity over time so finite differences and interpolation behave.
        quats = quat_make_continuous(quat_normalize(quats), dim=0)
    return Clip(
        skeleton=skeleton,
        rotations=quats.to(dtype),
        root_positions=pos.to(dtype),
        fps=_fps_from_frame_time(doc.frame_time),
        name=name,
    )


def _check_order(order: str) -> str:
    up = order.upper()
    if sorted(up) != ["X", "Y", "Z"]:
        raise ValueError(f"rotation order {order!r} must use X, Y and Z once each, e.g. 'ZXY'")
    return up


def from_clip(clip: Clip, rotation_order: str | Mapping[str, str] = "ZXY") -> BvhDocument:
    """A BVH document for ``clip``: root with 3 position + 3 rotation channels, others 3 rotations.

    ``rotation_order`` is one axis string for every joint, or a mapping from joint name to axis
    string (joints it does not name use ``"ZXY"``). OFFSETs are the skeleton's; leaf joints get
    an End Site (the skeleton's, or zeros). Joints are written in nested (depth-first) order.
    """
    sk = clip.skeleton
    if isinstance(rotation_order, str):
        orders = [_check_order(rotation_order)] * sk.num_joints
    else:
        orders = [_check_order(rotation_order.get(n, "ZXY")) for n in sk.names]
    ends = dict(sk.end_sites)
    order: list[int] = []
    stack = [0]
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(reversed(sk.children[j]))
    new_index = {j: n for n, j in enumerate(order)}

    quats = clip.rotations.to(torch.float64)
    columns = [clip.root_positions.to(torch.float64).numpy()]
    joints = []
    for j in order:
        chans = tuple(f"{a}rotation" for a in orders[j])
        if j == 0:
            chans = POSITION_CHANNELS + chans
        end = ends.get(j)
        if end is None and not sk.children[j]:
            end = (0.0, 0.0, 0.0)
        offset = (0.0, 0.0, 0.0) if j == 0 else sk.offsets[j]
        parent = -1 if j == 0 else new_index[sk.parents[j]]
        joints.append(BvhJoint(sk.names[j], parent, offset, chans, end))
        columns.append((quat_to_euler(quats[:, j], orders[j]) * DEG).numpy())
    return BvhDocument(joints, 1.0 / clip.fps, np.concatenate(columns, axis=1))


# ====================================================================== convenience


def load_clip(
    source: str | Path,
    profile: SkeletonProfile | str | Path | None = None,
    fps: float | None = None,
    dtype: torch.dtype = torch.float32,
) -> Clip:
    """A clip from a BVH path or BVH text (text starts with ``HIERARCHY``), resampled to ``fps`` if given."""
    if isinstance(source, str) and source.lstrip("\ufeff \t\r\n")[:9].upper() == "HIERARCHY":
        doc, name = BvhDocument.parse(source), ""
    else:
        path = Path(source)
        doc, name = BvhDocument.read(path), path.stem
    clip = to_clip(doc, profile=profile, name=name, dtype=torch.float64)
    if fps is not None:
        clip = clip.resample(fps)
    return clip.to(dtype)


def dump_clip(clip: Clip, rotation_order: str | Mapping[str, str] = "ZXY", precision: int | None = 6) -> str:
    """BVH text for ``clip`` (see :func:`from_clip`)."""
    return from_clip(clip, rotation_order).format(precision)
