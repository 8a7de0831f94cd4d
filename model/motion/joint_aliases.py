"""Other rigs' names for a profile's joints: a file whose joints carry Mixamo, Unreal Mannequin or CMU names is
read as if it carried the profile's own, and a rig that fits no names is told which ones it lacks in its own.

A profile lists its name schemes under ``aliases`` (``profiles/bandai-namco.json``): for each scheme, each
profile joint's names in it, the first one a rig has winning (Mixamo's chest is ``Spine2``, or ``Spine1`` on a
rig with fewer spine joints). Names compare as everywhere in the project: case and namespace prefix ignored.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass


def plain_joint_name(name: str) -> str:
    """Joint names compare without a namespace prefix (``mixamorig:Hips``) and case-insensitively."""
    return name.rsplit(":", 1)[-1].strip().lower()


@dataclass(frozen=True)
class NameScheme:
    """One naming convention's names for a profile's joints.

    Attributes:
        name: the convention, as messages name it (``"Mixamo"``).
        joints: ``(profile joint, its names in this convention)``, the first name a rig has winning.
    """

    name: str
    joints: tuple[tuple[str, tuple[str, ...]], ...]

    @classmethod
    def from_dict(cls, name: str, data: Mapping[str, str | Sequence[str]]) -> NameScheme:
        """``{"UpperLeg_L": "LeftUpLeg", "Chest": ["Spine2", "Spine1"], ...}`` (a name or a list of them)."""
        if not isinstance(data, Mapping):
            raise ValueError(f"aliases {name!r}: expected an object mapping the profile's joints to their names")
        joints = []
        for joint, names in data.items():
            listed = (names,) if isinstance(names, str) else tuple(names)
            if not listed or not all(isinstance(n, str) and n.strip() for n in listed):
                raise ValueError(f"aliases {name!r}: {joint!r} needs a name or a list of names")
            joints.append((str(joint), tuple(listed)))
        return cls(str(name), tuple(joints))

    def to_dict(self) -> dict[str, list[str]]:
        return {joint: list(names) for joint, names in self.joints}

    def renames(self, names: Sequence[str]) -> dict[int, str]:
        """The rig's joints (by index) this scheme names, each with the profile joint it is.

        A joint is renamed to the profile's exact spelling (``mixamorig:Hips`` and ``head`` too); a profile name the
        rig gives another joint is left to that joint (no two joints end up with one name).
        """
        index = {plain_joint_name(n): i for i, n in enumerate(names)}
        out: dict[int, str] = {}
        for joint, aliases in self.joints:
            found = next((index[plain_joint_name(a)] for a in aliases
                          if plain_joint_name(a) in index and index[plain_joint_name(a)] not in out), None)
            if found is None or names[found] == joint:
                continue
            if index.get(plain_joint_name(joint), found) == found:
                out[found] = joint
        return out

    def recognised(self, names: Sequence[str]) -> list[str]:
        """The rig's joint names this scheme knows, in the rig's order."""
        known = {plain_joint_name(a) for _, aliases in self.joints for a in aliases}
        return [n for n in names if plain_joint_name(n) in known]

    def name_of(self, joint: str) -> str:
        """``joint``'s (a profile joint's) first name in this scheme, or ``joint`` itself when the scheme has none."""
        return next((aliases[0] for j, aliases in self.joints if plain_joint_name(j) == plain_joint_name(joint)), joint)


def renamed(names: Sequence[str], schemes: Sequence[NameScheme],
            fits: Callable[[tuple[str, ...]], bool]) -> tuple[tuple[str, ...], NameScheme] | None:
    """``names`` with one scheme's aliases turned into the profile's names, for the scheme that renames most
    and gives names that ``fits`` (the profile resolves them); None when none does."""
    ranked = sorted(schemes, key=lambda s: -len(s.renames(names)))  # stable: the profile's order breaks ties
    for scheme in ranked:
        changes = scheme.renames(names)
        if not changes:
            continue
        out = tuple(changes.get(i, n) for i, n in enumerate(names))
        if fits(out):
            return out, scheme
    return None


def closest_scheme(names: Sequence[str], schemes: Sequence[NameScheme]) -> tuple[NameScheme, list[str]] | None:
    """The scheme that knows the most of the rig's names (at least two, and more than the profile's own names
    would explain), and those names; None for a rig none of them describes."""
    best = max(schemes, key=lambda s: len(s.recognised(names)), default=None)
    if best is None:
        return None
    known = best.recognised(names)
    own = {plain_joint_name(j) for j, _ in best.joints}
    if len(known) < 2 or all(plain_joint_name(n) in own for n in known):
        return None
    return best, known
