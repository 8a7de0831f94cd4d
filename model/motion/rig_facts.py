"""Facts about a rig read from its motion, checked before training: its units and its facing joints.

The model works in centimetres (its foot-contact thresholds, losses and floor are in cm at 30
fps), so a take in metres or inches is converted on import. The units are told (``cm``, ``m``,
``mm``, ``inch`` or a number: centimetres per file unit) or found (``auto``) from the character's
*head height*: the head joint's height above the lowest foot joint, median over the frames. A
take whose units cannot be told is refused with the option that fixes it.

The facing is ``up x across`` with ``across`` running from the left hip and shoulder joints to the
right ones; joints that share a point (a CMU rig's ``LeftShoulder``/``RightShoulder``, its hip
helpers sitting on the hips) give no direction, so each pair must stand apart.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from model.motion.clip import Clip
from model.motion.skeleton import Skeleton, SkeletonError

CM_PER_UNIT = {"cm": 1.0, "m": 100.0, "mm": 0.1, "inch": 2.54}
UNIT_CHOICES = ("auto", *CM_PER_UNIT)
# Head heights (in each unit) that read as an adult or child standing: first match wins, and the
# bands do not overlap once converted (m: 50-250 cm, inch: 89-229 cm, cm: 90-250 cm, mm: 50-250 cm).
AUTO_BANDS = (("m", 0.5, 2.5), ("inch", 35.0, 90.0), ("cm", 90.0, 250.0), ("mm", 500.0, 2500.0))
# After conversion, a head this high (cm) is a person; anything else is a wrong unit.
PLAUSIBLE_HEAD_CM = (40.0, 260.0)
# Facing pairs closer than this fraction of the head height share a point.
MIN_PAIR_SPREAD = 0.03
SAMPLE_FRAMES = 64


class UnitsError(ValueError):
    """A take whose units cannot be told or give an implausible character."""


def parse_units(text: str | float) -> str | float:
    """``auto``, a unit name, or a positive number of centimetres per file unit."""
    if isinstance(text, int | float):
        value = float(text)
    else:
        name = str(text).strip().lower()
        if name in ("in", "inches"):
            name = "inch"
        if name in UNIT_CHOICES:
            return name
        try:
            value = float(name)
        except ValueError:
            raise UnitsError(f"units must be one of {', '.join(UNIT_CHOICES)} or centimetres per file unit "
                             f"(a number such as 5.64), not {text!r}") from None
    if not value > 0:
        raise UnitsError(f"centimetres per file unit must be positive, not {value}")
    return value


def sample_positions(clip: Clip) -> torch.Tensor:
    """Global positions ``[S, J, 3]`` of up to :data:`SAMPLE_FRAMES` frames spread over the clip."""
    if clip.num_frames == 0:
        raise UnitsError(f"{clip.name or 'the take'} has no frames")
    frames = torch.linspace(0, clip.num_frames - 1, min(SAMPLE_FRAMES, clip.num_frames)).round().long().unique()
    part = replace(clip, rotations=clip.rotations[frames], root_positions=clip.root_positions[frames])
    return part.global_positions().to(torch.float64)


def head_height(positions: torch.Tensor, skeleton: Skeleton) -> float:
    """Median height of the head joint over the lowest foot joint (the file's units)."""
    r = skeleton.roles
    lowest = positions[:, list(skeleton.feet), 1].min(dim=-1).values
    return float((positions[:, r.head, 1] - lowest).median())


def hips_height(positions: torch.Tensor, skeleton: Skeleton) -> float:
    """Median height of the root joint over the lowest foot joint (the file's units)."""
    lowest = positions[:, list(skeleton.feet), 1].min(dim=-1).values
    return float((positions[:, skeleton.roles.root, 1] - lowest).median())


def cm_per_unit(setting: str | float, height: float, where: str = "the take") -> float:
    """The scale to centimetres for a take whose head stands ``height`` file units high.

    Raises:
        UnitsError: ``auto`` finds no unit, or the told unit makes an implausible character; the
            message says which ``--units`` would fix it.
    """
    setting = parse_units(setting)
    if setting == "auto":
        for unit, low, high in AUTO_BANDS:
            if low <= height < high:
                return CM_PER_UNIT[unit]
        guess = 160.0 / height if height > 0 else float("nan")
        raise UnitsError(
            f"{where}: the head stands {height:.4g} file units above the feet, which is no human height in "
            f"cm, m, mm or inches; give the units: for a character whose head is about 160 cm high, "
            f"--units {guess:.3g} (centimetres per file unit; a CMU rig's is 5.64)")
    scale = setting if isinstance(setting, float) else CM_PER_UNIT[setting]
    cm = height * scale
    if not PLAUSIBLE_HEAD_CM[0] <= cm <= PLAUSIBLE_HEAD_CM[1]:
        raise UnitsError(f"{where}: with units {setting} the head stands {cm:.4g} cm above the feet, no human "
                         f"height; check the units (--units auto reads them from the height)")
    return scale


def scale_clip(clip: Clip, factor: float) -> Clip:
    """The clip with every length (offsets, End Sites, root positions) times ``factor``, marked as cm."""
    sk = clip.skeleton
    offsets = tuple((x * factor, y * factor, z * factor) for x, y, z in sk.offsets)
    ends = tuple((j, (x * factor, y * factor, z * factor)) for j, (x, y, z) in sk.end_sites)
    return replace(clip, skeleton=replace(sk, offsets=offsets, end_sites=ends, units="cm"),
                   root_positions=clip.root_positions * factor)


def check_facing(positions: torch.Tensor, skeleton: Skeleton, height: float) -> dict[str, float]:
    """The mean distance of each facing pair (hips, shoulders) over the frames, in the file's units.

    Raises:
        SkeletonError: a pair stands closer than :data:`MIN_PAIR_SPREAD` of the head height, or the
            left-to-right direction they give is vertical: the facing would be undefined.
    """
    r, names = skeleton.roles, skeleton.names
    spread = {}
    for label, left, right in (("hips", r.left_hip, r.right_hip), ("shoulders", r.left_shoulder, r.right_shoulder)):
        distance = float((positions[:, right] - positions[:, left]).norm(dim=-1).mean())
        spread[label] = distance
        if not distance > MIN_PAIR_SPREAD * height:
            below = [names[c] for c in (*skeleton.children[left][:1], *skeleton.children[right][:1])]
            hint = f" (their children {' and '.join(below)}?)" if len(below) == 2 else ""
            raise SkeletonError(
                f"the facing joints {names[left]} and {names[right]} ({label}) stand {distance:.3g} units apart, "
                f"under {MIN_PAIR_SPREAD:.0%} of the head height {height:.3g}: they share a point and give no "
                f"facing. Name joints that stand apart in the profile{hint}")
    across = (positions[:, r.right_hip] - positions[:, r.left_hip]) + (positions[:, r.right_shoulder]
                                                                       - positions[:, r.left_shoulder])
    horizontal = float(across[:, [0, 2]].norm(dim=-1).median())
    if not horizontal > MIN_PAIR_SPREAD * height:
        raise SkeletonError(f"the facing joints' left-to-right direction is vertical ({horizontal:.3g} units "
                            "across): the rig is not Y-up or the profile's hips and shoulders are wrong")
    return spread


@dataclass(frozen=True)
class RigFacts:
    """What :func:`conform_clip` found out about a take's rig.

    Attributes:
        cm_per_unit: the scale applied (1 for a take in cm).
        head_cm / hips_cm: head and root joint heights over the lowest foot (median over frames), in cm.
        hips_spread_cm / shoulders_spread_cm: distance between the facing joints of each pair, cm.
    """

    cm_per_unit: float
    head_cm: float
    hips_cm: float
    hips_spread_cm: float
    shoulders_spread_cm: float


def conform_clip(clip: Clip, units: str | float = "auto") -> tuple[Clip, RigFacts]:
    """The clip in centimetres with its rig checked (units, facing), and the facts found.

    Raises:
        UnitsError: the units are unknown or implausible.
        SkeletonError: the facing joints give no direction.
    """
    positions = sample_positions(clip)
    height = head_height(positions, clip.skeleton)
    scale = cm_per_unit(units, height, clip.name or "the take")
    spread = check_facing(positions, clip.skeleton, height)
    facts = RigFacts(cm_per_unit=scale, head_cm=height * scale, hips_cm=hips_height(positions, clip.skeleton) * scale,
                     hips_spread_cm=spread["hips"] * scale, shoulders_spread_cm=spread["shoulders"] * scale)
    return (clip if scale == 1.0 else scale_clip(clip, scale)), facts
