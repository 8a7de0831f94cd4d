"""Skeletons as data: joint names, parents, rest offsets, and the roles derived from joint names.

Roles (root, head, feet, the hips and shoulders that define facing, left/right mirror pairs) come
from a *profile*: a small JSON file mapping role names to joint names. Built-in profiles cover the
Bandai-Namco and 100STYLE rigs; a user writes one for any other rig (see ``profiles/README.md``).
Code asks ``skeleton.feet`` or ``skeleton.mirror``; it never writes a joint index.
"""

from __future__ import annotations

import json
import re
from dataclasses import asdict, dataclass
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import Any

import torch

from model.motion.joint_aliases import NameScheme, closest_scheme, plain_joint_name, renamed

PROFILE_DIR = "profiles"
BUILTIN_PROFILES = ("bandai-namco", "100style")


class SkeletonError(ValueError):
    """A rig that a profile cannot resolve, or an inconsistent skeleton."""


@dataclass(frozen=True)
class SkeletonProfile:
    """Which joint names play which role on one family of rigs.

    Attributes:
        name: identifier, e.g. ``"bandai-namco"``.
        root: the joint that carries the character's translation (usually the hips). Joints above
            it in a file (a ``joint_Root`` at the origin, say) are folded into it on import.
        head: the head joint.
        left_foot / right_foot: ankle then toe joints of each foot (the contact joints).
        left_hip / right_hip / left_shoulder / right_shoulder: the joints whose left-to-right
            vectors define the facing direction.
        mirror: regex substitutions ``[pattern, replacement]`` that turn a left joint name into
            its right counterpart (e.g. ``["(.*)_L$", "\\\\1_R"]``). Tried in order; the first
            pattern that matches the whole name (case ignored, as for roles) gives the twin.
        drop: regexes (whole name, case ignored) of joints removed on import: finger and helper
            joints. A dropped joint's children hang from its parent, its motion folded into them.
        aliases: other rigs' names for the profile's joints (Mixamo, Unreal Mannequin, CMU), by scheme: a rig
            that does not fit the profile's own names is read under the scheme that makes it fit (:func:`fit_names`).
    """

    name: str
    root: str
    head: str
    left_foot: tuple[str, ...]
    right_foot: tuple[str, ...]
    left_hip: str
    right_hip: str
    left_shoulder: str
    right_shoulder: str
    mirror: tuple[tuple[str, str], ...]
    description: str = ""
    drop: tuple[str, ...] = ()
    aliases: tuple[NameScheme, ...] = ()

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SkeletonProfile:
        required = ["name", "root", "head", "left_foot", "right_foot", "left_hip", "right_hip",
                    "left_shoulder", "right_shoulder", "mirror"]
        missing = [k for k in required if k not in data]
        if missing:
            raise SkeletonError(f"skeleton profile lacks the field(s): {', '.join(missing)}")
        try:
            mirror = tuple((str(a), str(b)) for a, b in data["mirror"])
            for pattern, _ in mirror:
                re.compile(pattern)
        except (TypeError, ValueError, re.error) as exc:
            raise SkeletonError(f"profile 'mirror' must be a list of [regex, replacement] pairs: {exc}") from exc
        drop = data.get("drop", [])
        try:
            if isinstance(drop, str):
                raise TypeError("a single string")
            drop = tuple(str(d) for d in drop)
            for pattern in drop:
                re.compile(pattern)
        except (TypeError, re.error) as exc:
            raise SkeletonError(f"profile 'drop' must be a list of joint-name regexes: {exc}") from exc
        try:
            aliases = tuple(NameScheme.from_dict(k, v) for k, v in dict(data.get("aliases", {})).items())
        except (TypeError, ValueError) as exc:
            raise SkeletonError(f"profile 'aliases' must map scheme names to {{joint: name or [names]}}: {exc}") from exc
        return cls(
            name=str(data["name"]), root=str(data["root"]), head=str(data["head"]),
            left_foot=tuple(map(str, data["left_foot"])), right_foot=tuple(map(str, data["right_foot"])),
            left_hip=str(data["left_hip"]), right_hip=str(data["right_hip"]),
            left_shoulder=str(data["left_shoulder"]), right_shoulder=str(data["right_shoulder"]),
            mirror=mirror, description=str(data.get("description", "")), drop=drop, aliases=aliases,
        )

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["mirror"] = [list(p) for p in self.mirror]
        if self.drop:
            d["drop"] = list(self.drop)
        else:  # absent when empty: a profile without drops describes (and caches) as before
            del d["drop"]
        if self.aliases:
            d["aliases"] = {scheme.name: scheme.to_dict() for scheme in self.aliases}
        else:  # as drop
            del d["aliases"]
        return d

    def drops(self, name: str) -> bool:
        """Whether the profile drops the joint ``name`` (namespace prefix and case ignored)."""
        bare = name.rsplit(":", 1)[-1].strip()
        return any(re.fullmatch(p, bare, re.IGNORECASE) for p in self.drop)

    @classmethod
    def load(cls, name_or_path: str | Path) -> SkeletonProfile:
        """A built-in profile by name (``bandai-namco``, ``100style``) or a JSON file by path."""
        path = Path(name_or_path)
        if str(name_or_path) in BUILTIN_PROFILES:
            text = resources.files("model.motion").joinpath(PROFILE_DIR, f"{name_or_path}.json").read_text()
        elif path.is_file():
            text = path.read_text()
        else:
            raise SkeletonError(
                f"no skeleton profile {str(name_or_path)!r}: give a built-in name "
                f"({', '.join(BUILTIN_PROFILES)}) or the path of a profile JSON file"
            )
        try:
            return cls.from_dict(json.loads(text))
        except json.JSONDecodeError as exc:
            raise SkeletonError(f"profile {name_or_path}: invalid JSON ({exc})") from exc


def profile_of(skeleton: Skeleton) -> SkeletonProfile:
    """A profile that reads files on ``skeleton``'s rig: its roles by name, its mirror pairs name by name."""
    r, n = skeleton.roles, skeleton.names
    pairs = [(i, j) for i, j in enumerate(r.mirror) if i < j]
    return SkeletonProfile(
        name=r.profile, root=n[r.root], head=n[r.head], left_foot=tuple(n[j] for j in r.left_foot),
        right_foot=tuple(n[j] for j in r.right_foot), left_hip=n[r.left_hip], right_hip=n[r.right_hip],
        left_shoulder=n[r.left_shoulder], right_shoulder=n[r.right_shoulder],
        mirror=tuple((re.escape(n[i].rsplit(":", 1)[-1]), n[j].rsplit(":", 1)[-1].replace("\\", "\\\\"))
                     for i, j in pairs),
        description=f"the roles of a {skeleton.num_joints}-joint skeleton",
    )


@dataclass(frozen=True)
class SkeletonRoles:
    """Joint indices resolved from a profile for one skeleton."""

    profile: str
    root: int
    head: int
    left_foot: tuple[int, ...]
    right_foot: tuple[int, ...]
    left_hip: int
    right_hip: int
    left_shoulder: int
    right_shoulder: int
    mirror: tuple[int, ...]  # mirror[j] is j's left/right counterpart (itself on the midline)


def _vec3(values: Any) -> tuple[float, float, float]:
    """Three floats from a row of numbers (an offset)."""
    vals = tuple(float(v) for v in values)
    if len(vals) != 3:
        raise SkeletonError(f"an offset has 3 numbers, not {len(vals)}: {vals!r}")
    return vals


def resolve_roles(names: tuple[str, ...], profile: SkeletonProfile) -> SkeletonRoles:
    """Resolve a profile against joint names; the error lists every joint it could not find."""
    lookup = {plain_joint_name(n): i for i, n in enumerate(names)}
    missing: list[str] = []

    def idx(joint: str) -> int:
        i = lookup.get(plain_joint_name(joint))
        if i is None:
            missing.append(joint)
            return -1
        return i

    roles: dict[str, Any] = {
        "root": idx(profile.root), "head": idx(profile.head),
        "left_foot": tuple(idx(j) for j in profile.left_foot),
        "right_foot": tuple(idx(j) for j in profile.right_foot),
        "left_hip": idx(profile.left_hip), "right_hip": idx(profile.right_hip),
        "left_shoulder": idx(profile.left_shoulder), "right_shoulder": idx(profile.right_shoulder),
    }
    if missing:  # the mirror twins of a rig that lacks the roles tell nothing (a thigh_l is not the profile's _L)
        raise SkeletonError(_mismatch(names, profile, missing))
    mirror = list(range(len(names)))
    for i, name in enumerate(names):
        if profile.drops(name):
            continue
        for pattern, repl in profile.mirror:
            bare = name.rsplit(":", 1)[-1]
            match = re.fullmatch(pattern, bare, re.IGNORECASE)
            if match:
                other = match.expand(repl)
                j = lookup.get(plain_joint_name(other))
                if j is None:
                    missing.append(f"{other} (mirror of {name})")
                else:
                    mirror[i], mirror[j] = j, i
                break
    if missing:
        raise SkeletonError(_mismatch(names, profile, missing))
    return SkeletonRoles(profile=profile.name, mirror=tuple(mirror), **roles)


def _mismatch(names: tuple[str, ...], profile: SkeletonProfile, missing: list[str]) -> str:
    """The error for a rig the profile does not resolve: what it lacks, and in the names the rig seems to use."""
    text = f"the rig does not match skeleton profile {profile.name!r}: missing joint(s) {', '.join(missing)}."
    near = closest_scheme(names, profile.aliases)
    theirs: list[str] = []
    if near is not None:
        scheme, known = near
        changes = scheme.renames(names)
        have = {plain_joint_name(changes.get(i, n)) for i, n in enumerate(names)}
        theirs = [scheme.name_of(j) for j in _role_joints(profile) if plain_joint_name(j) not in have]
    if near is not None and theirs:
        shown = ", ".join(known[:6]) + (", ..." if len(known) > 6 else "")
        text += (f" Its names look like {scheme.name} names ({shown}), which this profile also reads: under them it "
                 f"lacks {', '.join(theirs)}.")
    elif profile.aliases:
        text += f" It also reads {', '.join(s.name for s in profile.aliases)} names (docs/retargeting.md)."
    return text + " Rename the joints or write a profile for this rig (see model/motion/profiles/README.md)."


def _role_joints(profile: SkeletonProfile) -> list[str]:
    """The joints the profile gives a role, each once, in the order errors list them."""
    named = [profile.root, profile.head, *profile.left_foot, *profile.right_foot, profile.left_hip, profile.right_hip,
             profile.left_shoulder, profile.right_shoulder]
    return list(dict.fromkeys(named))


def fit_names(names: tuple[str, ...], profile: SkeletonProfile) -> tuple[tuple[str, ...], NameScheme | None]:
    """``names`` as the profile reads them: as they are when it resolves them, else renamed by the alias scheme
    that makes them resolve (and that scheme); raises :func:`resolve_roles`'s error when neither does."""
    try:
        resolve_roles(names, profile)
        return names, None
    except SkeletonError:
        found = renamed(names, profile.aliases, lambda out: _resolves(out, profile))
        if found is None:
            raise
        return found


def _resolves(names: tuple[str, ...], profile: SkeletonProfile) -> bool:
    try:
        resolve_roles(names, profile)
    except SkeletonError:
        return False
    return True


@dataclass(frozen=True)
class Skeleton:
    """A joint hierarchy in topological order with rest offsets and resolved roles.

    Attributes:
        names: joint names, root first; ``parents[j] < j``.
        parents: parent index per joint (-1 for the root).
        offsets: ``(J, 3)`` translation of each joint in its parent's frame, in ``units``.
        end_sites: ``(joint index, offset)`` of BVH End Sites, kept so exports are faithful.
        roles: the profile's roles resolved to indices.
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: tuple[tuple[float, float, float], ...]
    roles: SkeletonRoles
    end_sites: tuple[tuple[int, tuple[float, float, float]], ...] = ()
    units: str = "cm"
    up_axis: str = "y"
    handedness: str = "right"

    def __post_init__(self) -> None:
        n = len(self.names)
        if len(self.parents) != n or len(self.offsets) != n:
            raise SkeletonError("names, parents and offsets must have one entry per joint")
        if len(set(self.names)) != n:
            raise SkeletonError("joint names must be unique")
        if n == 0 or self.parents[0] != -1 or any(not 0 <= p < j for j, p in enumerate(self.parents) if j):
            raise SkeletonError("joints must be in topological order with the root first")

    # ------------------------------------------------------------------ construction
    @classmethod
    def build(
        cls,
        names: tuple[str, ...] | list[str],
        parents: tuple[int, ...] | list[int],
        offsets: Any,
        profile: SkeletonProfile | str | Path | None = None,
        end_sites: tuple[tuple[int, tuple[float, float, float]], ...] = (),
        units: str = "cm",
    ) -> Skeleton:
        """Build a skeleton, resolving roles with ``profile`` or the first built-in that fits."""
        names = tuple(names)
        offs = tuple(_vec3(row) for row in torch.as_tensor(offsets, dtype=torch.float64).tolist())
        roles = detect_roles(names, profile)
        return cls(names=names, parents=tuple(int(p) for p in parents), offsets=offs, roles=roles,
                   end_sites=tuple(end_sites), units=units)

    # ------------------------------------------------------------------ derived facts
    @property
    def num_joints(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """Index of a joint by name (namespace prefix and case ignored)."""
        key = plain_joint_name(name)
        for i, n in enumerate(self.names):
            if plain_joint_name(n) == key:
                return i
        raise SkeletonError(f"no joint named {name!r} in this skeleton")

    @property
    def feet(self) -> tuple[int, ...]:
        """Contact joints: left ankle and toe, then right ankle and toe."""
        return self.roles.left_foot + self.roles.right_foot

    @property
    def mirror(self) -> tuple[int, ...]:
        return self.roles.mirror

    @property
    def legs(self) -> tuple[tuple[int, int, int], ...]:
        """``(hip, knee, ankle)`` of the left leg, then the right: the ankle is each foot role's first
        joint, the knee and hip its parent and grandparent (the two bones that leg IK bends)."""
        legs = []
        for foot in (self.roles.left_foot, self.roles.right_foot):
            ankle = foot[0]
            knee = self.parents[ankle]
            hip = self.parents[knee] if knee >= 0 else -1
            if hip < 0:
                raise ValueError(f"the ankle {self.names[ankle]!r} has no two-bone leg above it")
            legs.append((hip, knee, ankle))
        return tuple(legs)

    def chain_to(self, joint: int) -> tuple[int, ...]:
        """The joints from the root down to ``joint``, both included."""
        chain = [joint]
        while self.parents[chain[-1]] >= 0:
            chain.append(self.parents[chain[-1]])
        return tuple(reversed(chain))

    @cached_property
    def children(self) -> tuple[tuple[int, ...], ...]:
        kids: list[list[int]] = [[] for _ in self.names]
        for j, p in enumerate(self.parents):
            if p >= 0:
                kids[p].append(j)
        return tuple(tuple(k) for k in kids)

    def offsets_tensor(self, dtype: torch.dtype = torch.float32) -> torch.Tensor:
        """Rest offsets as a ``(J, 3)`` tensor."""
        return torch.tensor(self.offsets, dtype=dtype)

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, Any]:
        return {
            "format": 1,
            "units": self.units,
            "up_axis": self.up_axis,
            "handedness": self.handedness,
            "profile": self.roles.profile,
            "joints": [
                {"name": n, "parent": p, "offset": list(o)}
                for n, p, o in zip(self.names, self.parents, self.offsets)
            ],
            "end_sites": [{"joint": j, "offset": list(o)} for j, o in self.end_sites],
            "roles": asdict(self.roles),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Skeleton:
        try:
            joints = data["joints"]
            roles_data = dict(data["roles"])
            for key in ("left_foot", "right_foot", "mirror"):
                roles_data[key] = tuple(roles_data[key])
            return cls(
                names=tuple(j["name"] for j in joints),
                parents=tuple(int(j["parent"]) for j in joints),
                offsets=tuple(_vec3(j["offset"]) for j in joints),
                roles=SkeletonRoles(**roles_data),
                end_sites=tuple((int(e["joint"]), _vec3(e["offset"])) for e in data.get("end_sites", [])),
                units=data.get("units", "cm"),
                up_axis=data.get("up_axis", "y"),
                handedness=data.get("handedness", "right"),
            )
        except (KeyError, TypeError) as exc:
            raise SkeletonError(f"invalid skeleton description: {exc!r}") from exc

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=1))

    @classmethod
    def load(cls, path: str | Path) -> Skeleton:
        return cls.from_dict(json.loads(Path(path).read_text()))

    def same_rig(self, other: Skeleton) -> bool:
        """Same joint names and parents (offsets may differ between performers)."""
        return self.names == other.names and self.parents == other.parents


def detect_roles(names: tuple[str, ...], profile: SkeletonProfile | str | Path | None = None) -> SkeletonRoles:
    """Resolve roles with the given profile, or with the first built-in profile that fits."""
    if profile is not None:
        prof = profile if isinstance(profile, SkeletonProfile) else SkeletonProfile.load(profile)
        return resolve_roles(names, prof)
    errors = []
    for name in BUILTIN_PROFILES:
        try:
            return resolve_roles(names, SkeletonProfile.load(name))
        except SkeletonError as exc:
            errors.append(str(exc))
    raise SkeletonError("no built-in skeleton profile fits this rig:\n  " + "\n  ".join(errors))
