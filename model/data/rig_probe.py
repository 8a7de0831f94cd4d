"""What ``rsmt data inspect`` says about a rig: one take of it loaded, its units and facing checked."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from model.motion.bvh import BvhDocument, BvhError
from model.motion.bvh_clip import to_clip
from model.motion.rig_facts import UnitsError, conform_clip
from model.motion.skeleton import SkeletonError, SkeletonProfile


@dataclass(frozen=True)
class RigReport:
    """One rig of a data folder, as one of its takes shows it.

    Attributes:
        example: the take that was loaded (relative path).
        takes: how many takes share the rig (same joint names in the file).
        profile: the profile that fits.
        file_joints / joints: joints in the file, and those the model keeps.
        dropped: joints the profile drops (and those outside the root's subtree).
        fps: the take's own frame rate.
        cm_per_unit, head_cm, hips_cm, hips_spread_cm, shoulders_spread_cm: see
            :class:`model.motion.rig_facts.RigFacts`.
        facing: the facing joints, ``left hip/right hip, left shoulder/right shoulder``.
    """

    example: str
    takes: int
    profile: str
    file_joints: int
    joints: int
    dropped: tuple[str, ...]
    fps: float
    cm_per_unit: float
    head_cm: float
    hips_cm: float
    hips_spread_cm: float
    shoulders_spread_cm: float
    facing: str

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["dropped"] = list(self.dropped)
        return {k: round(v, 3) if isinstance(v, float) else v for k, v in out.items()}


def probe_rig(path: Path, example: str, takes: int, profile: SkeletonProfile | None,
              units: str | float) -> RigReport | tuple[str, str]:
    """The rig of the take at ``path``, or ``(problem kind, message)`` when it cannot be used."""
    try:
        doc = BvhDocument.read(path)
        clip = to_clip(doc, profile=profile, name=example)
        clip, facts = conform_clip(clip, units)
    except UnitsError as exc:
        return "units", str(exc)
    except SkeletonError as exc:
        return "rig", str(exc)
    except (BvhError, OSError, ValueError) as exc:
        return "unreadable", str(exc)
    sk = clip.skeleton
    r = sk.roles
    kept = set(sk.names)
    return RigReport(
        example=example, takes=takes, profile=r.profile, file_joints=len(doc.names), joints=sk.num_joints,
        dropped=tuple(n for n in doc.names if n not in kept), fps=round(float(clip.fps), 3),
        cm_per_unit=facts.cm_per_unit, head_cm=facts.head_cm, hips_cm=facts.hips_cm,
        hips_spread_cm=facts.hips_spread_cm, shoulders_spread_cm=facts.shoulders_spread_cm,
        facing=f"{sk.names[r.left_hip]}/{sk.names[r.right_hip]}, {sk.names[r.left_shoulder]}/{sk.names[r.right_shoulder]}",
    )
