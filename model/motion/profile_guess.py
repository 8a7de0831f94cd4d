"""A starting skeleton profile guessed from a BVH file's joint names and hierarchy.

Sides come from naming conventions (``Left…``/``Right…``, ``…_L``/``…_R``, ``L_…``, and the
one-letter prefixes of MotionBuilder/CMU rigs such as ``LHipJoint``/``RHipJoint``), each joint's
twin being the name with the other side. The roles follow from the hierarchy: the ankle is the
left joint named ``foot`` or ``ankle``, the toe its child, the facing hip the ankle's grandparent
(the upper leg) and the facing shoulder the hand's grandparent (the upper arm), so helper joints
that share a point (a CMU rig's ``LeftShoulder``, its ``LHipJoint`` on the hips) are never picked.
The joints below the hands (fingers) and the helper joints (no offset, one child, no rotation) are
listed to drop. What it cannot decide is said, never filled in silently.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from model.motion.bvh import BvhDocument
from model.motion.bvh_clip import to_clip
from model.motion.bvh_parser import ROTATION_CHANNELS
from model.motion.rig_facts import check_facing, head_height, sample_positions
from model.motion.skeleton import SkeletonError, SkeletonProfile, plain_joint_name

# (pattern, replacement, general): a general rule goes in the profile as it is (it matches case-
# insensitively there); the others (a bare one-letter side) would match midline names such as
# LowerBack, so the profile lists the joints they matched by name.
SIDE_RULES = (
    (r"Left(.+)", r"Right\1", True),
    (r"(.+)_L", r"\1_R", True),
    (r"(.+)\.L", r"\1.R", True),
    (r"L_(.+)", r"R_\1", True),
    (r"(.+)Left", r"\1Right", True),
    (r"L([A-Z0-9].*)", r"R\1", False),
    (r"(.*[a-z0-9])L", r"\1R", False),
)
# A helper joint may rotate this much (degrees, any channel) over the file and still be dropped.
STILL_DEGREES = 0.5


@dataclass
class ProfileGuess:
    """The guessed profile (``profile``, a dict in the profile format) and what could not be decided."""

    profile: dict[str, Any]
    undecided: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def _bare(name: str) -> str:
    return name.rsplit(":", 1)[-1].strip()


def mirror_rules(names: list[str]) -> tuple[list[list[str]], dict[int, int]]:
    """Mirror rules for these joint names and the left-to-right pairs they give (by index)."""
    lookup = {plain_joint_name(n): i for i, n in enumerate(names)}
    pairs: dict[int, int] = {}
    used: dict[int, list[str]] = {}
    taken: set[int] = set()
    for i, name in enumerate(names):
        if i in taken:
            continue
        for k, (pattern, repl, general) in enumerate(SIDE_RULES):
            match = re.fullmatch(pattern, _bare(name), re.IGNORECASE if general else 0)
            if not match:
                continue
            j = lookup.get(plain_joint_name(match.expand(repl)))
            if j is not None and j != i:
                pairs[i] = j
                taken |= {i, j}
                used.setdefault(k, []).append(match.group(1))
                break
    rules = []
    for k, (pattern, repl, general) in enumerate(SIDE_RULES):
        if k not in used:
            continue
        if general:
            rules.append([pattern, repl])
        else:
            bases = "|".join(re.escape(b) for b in used[k])
            rules.append([pattern.replace("([A-Z0-9].*)", f"({bases})").replace("(.*[a-z0-9])", f"({bases})"), repl])
    return rules, pairs


def _first(names: list[str], indices: list[int], words: tuple[str, ...], avoid: tuple[str, ...] = ()) -> int | None:
    for i in indices:
        low = _bare(names[i]).lower()
        if any(w in low for w in words) and not any(a in low for a in avoid):
            return i
    return None


def _rotates(doc: BvhDocument, joint: int) -> float:
    """The largest change (degrees) of any rotation channel of ``joint`` over the file."""
    start = doc.channel_slices()[joint].start
    cols = [start + k for k, c in enumerate(doc.joints[joint].channels) if c in ROTATION_CHANNELS]
    if not cols or doc.num_frames == 0:
        return 0.0
    values = doc.motion[:, cols]
    return float(np.abs(values - values.mean(axis=0)).max())


class _Rig:
    """The joint names and hierarchy a guess reads, with the helpers it asks."""

    def __init__(self, doc: BvhDocument) -> None:
        self.doc = doc
        self.names = list(doc.names)
        self.parents = doc.parents
        self.children = doc.children()
        self.rules, self.pairs = mirror_rules(self.names)
        root = next((i for i, n in enumerate(self.names) if re.fullmatch(r"hips?|pelvis", _bare(n), re.IGNORECASE)), None)
        self.root = 0 if root is None else root
        self.root_named = root is not None
        self.inside = [i for i in range(len(self.names)) if self.descends(i, self.root)]
        mirrored = set(self.pairs) | set(self.pairs.values())
        self.lefts = [i for i in sorted(self.pairs) if self.descends(i, self.root)]
        self.midline = [i for i in self.inside if i not in mirrored]

    def descends(self, j: int, ancestor: int) -> bool:
        while j >= 0:
            if j == ancestor:
                return True
            j = self.parents[j]
        return False

    def below(self, j: int) -> list[int]:
        return [c for c in self.inside if c != j and self.descends(c, j)]

    def grandparent(self, j: int) -> int | None:
        """``j``'s grandparent when it is a mirrored joint below the root (the upper limb), else None."""
        g = self.parents[self.parents[j]] if self.parents[j] >= 0 else -1
        return g if g >= 0 and g != self.root and g in self.pairs else None


def _limbs(rig: _Rig, roles: dict[str, Any], undecided: list[str]) -> int | None:
    """Fill in the feet, facing hips and shoulders; returns the left hand (or None)."""
    names, pairs = rig.names, rig.pairs
    ankle = _first(names, rig.lefts, ("foot", "ankle"), ("toe", "ball", "end"))
    hand = _first(names, rig.lefts, ("hand", "wrist"), ("finger", "thumb", "index", "middle", "ring", "pinky", "end"))
    feet: list[int] = []
    if ankle is None:
        undecided.append("left_foot/right_foot: no left joint is named foot or ankle; write [ankle, toe] per side")
    else:
        toe = _first(names, rig.below(ankle), ("toe", "ball"))
        toe = toe if toe is not None else (rig.children[ankle][0] if rig.children[ankle] else None)
        if toe is None or toe not in pairs:
            undecided.append(f"toe: the ankle {names[ankle]} has no mirrored child; write the toe joints")
        else:
            feet = [ankle, toe]
    roles["left_foot"] = [names[j] for j in feet]
    roles["right_foot"] = [names[pairs[j]] for j in feet]
    if hand is None:
        undecided.append("left_shoulder/right_shoulder: no left joint is named hand or wrist; write the upper arms")
    for key, end in (("hip", ankle), ("shoulder", hand)):
        joint = None if end is None else rig.grandparent(end)
        if end is not None and joint is None:
            undecided.append(f"left_{key}/right_{key}: {names[end]} has no mirrored grandparent below the root; "
                             "write the joints")
        roles[f"left_{key}"] = names[joint] if joint is not None else ""
        roles[f"right_{key}"] = names[pairs[joint]] if joint is not None else ""
    return hand


def _drops(rig: _Rig, roles: dict[str, Any], hand: int | None, notes: list[str]) -> list[str]:
    """The joints below the hands, and the zero-offset helpers with one child that do not rotate."""
    names = rig.names
    drop = [names[c] for side in ((hand, rig.pairs[hand]) if hand is not None else ()) for c in rig.below(side)]
    named = {roles["head"], *roles["left_foot"], *roles["right_foot"], roles["left_hip"], roles["right_hip"],
             roles["left_shoulder"], roles["right_shoulder"]}
    moving = []
    for i in rig.inside:
        if i == rig.root or names[i] in drop or names[i] in named or len(rig.children[i]) != 1:
            continue
        if any(abs(v) > 1e-6 for v in rig.doc.joints[i].offset):
            continue
        turn = _rotates(rig.doc, i)
        if turn <= STILL_DEGREES:
            drop.append(names[i])
        else:
            moving.append(f"{names[i]} ({turn:.0f} deg)")
    if moving:
        notes.append("kept zero-offset joints that rotate in this file (dropping them would lose motion): "
                     + ", ".join(moving))
    return drop


def guess_profile(doc: BvhDocument, name: str = "my-rig") -> ProfileGuess:
    """Guess a profile for the rig of ``doc`` (see the module docstring)."""
    rig = _Rig(doc)
    names = rig.names
    undecided: list[str] = []
    notes: list[str] = []
    if not rig.root_named:
        notes.append(f"no joint is named Hips or Pelvis: the root is the file's root {names[0]!r}")
    head = _first(names, rig.midline, ("head",), ("end", "top", "site", "nub"))
    if head is None:
        undecided.append("head: no midline joint is named head; write the head joint")
    roles: dict[str, Any] = {"name": name, "description": f"guessed by rsmt profile guess from {len(names)} joints",
                             "root": names[rig.root], "head": names[head] if head is not None else ""}
    hand = _limbs(rig, roles, undecided)
    roles["mirror"] = rig.rules
    if not rig.rules:
        undecided.append("mirror: no left/right naming convention found; write [regex, replacement] rules")
    roles["drop"] = [re.escape(_bare(n)) for n in _drops(rig, roles, hand, notes)]
    guess = ProfileGuess(roles, undecided, notes)
    if not undecided:
        _check(doc, guess)
    return guess


def _check(doc: BvhDocument, guess: ProfileGuess) -> None:
    """Load the file with the guessed profile and check its facing joints stand apart."""
    try:
        clip = to_clip(doc, SkeletonProfile.from_dict(guess.profile), name="guess")
        positions = sample_positions(clip)
        check_facing(positions, clip.skeleton, head_height(positions, clip.skeleton))
    except SkeletonError as exc:
        guess.undecided.append(f"the guess does not load: {exc}")
