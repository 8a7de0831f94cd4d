"""BVH documents to and from :class:`Clip`: how the model reads a file's rig and motion.


:func:`to_clip` interprets a :class:`~model.motion.bvh.BvhDocument` for the model: the profile's
root joint becomes joint 0 (joints above it are folded into it), position channels replace
OFFSETs, and rotation channels are intrinsic Euler angles in degrees applied in the order they are
listed. :func:`from_clip` goes back.
"""
from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import torch

from model.motion.bvh import BvhDocument, BvhJoint
from model.motion.bvh_parser import (
    AXIS_INDEX,
    BONE_TRANSLATION_TOLERANCE,
    POSITION_CHANNELS,
    ROTATION_CHANNELS,
    Vec3,
    fps_from_frame_time,
    vec3,
)
from model.motion.clip import Clip
from model.motion.rotations import (
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
from model.motion.skeleton import (
    BUILTIN_PROFILES,
    Skeleton,
    SkeletonError,
    SkeletonProfile,
    fit_names,
    plain_joint_name,
    resolve_roles,
)

logger = logging.getLogger(__name__)
def _fit_profile(doc: BvhDocument, profile: SkeletonProfile | str | Path | None
                 ) -> tuple[SkeletonProfile, int, list[int], BvhDocument]:
    """The profile, the file index of its root joint, the joints kept (root then descendants), and the document
    with its joints under the profile's names where it carries another rig's (the profile's ``aliases``)."""
    candidates = [c if isinstance(c, SkeletonProfile) else SkeletonProfile.load(c)
                  for c in ([profile] if profile is not None else BUILTIN_PROFILES)]
    errors: list[str] = []
    # The names as they are first, against every candidate: another rig's names only when no profile's own fit.
    for aliased in (False, True):
        for prof in candidates:
            try:
                fitted = _renamed(doc, prof) if aliased else doc
                root, kept = _fit_one(fitted, prof)
                return prof, root, kept, fitted
            except SkeletonError as exc:
                if not aliased:
                    errors.append(str(exc))
    if profile is not None:
        raise SkeletonError(errors[0])
    raise SkeletonError("no built-in skeleton profile fits this rig:\n  " + "\n  ".join(errors))


def _renamed(doc: BvhDocument, prof: SkeletonProfile) -> BvhDocument:
    """``doc`` with its joints named as ``prof`` names them (raises when no alias scheme of ``prof`` fits)."""
    names, scheme = fit_names(doc.names, prof)
    if scheme is None:
        return doc
    logger.info("reading %s joint names as profile %r's", scheme.name, prof.name)
    joints = [dataclasses.replace(j, name=n) for j, n in zip(doc.joints, names)]
    return BvhDocument(joints, doc.frame_time, doc.motion)


def _fit_one(doc: BvhDocument, prof: SkeletonProfile) -> tuple[int, list[int]]:
    """The file index of ``prof``'s root joint and the joints kept; raises when the profile does not fit."""
    names = doc.names
    plain = [plain_joint_name(n) for n in names]
    if plain_joint_name(prof.root) not in plain:
        resolve_roles(names, prof)  # raises, listing every joint the rig lacks
        raise SkeletonError(f"no joint {prof.root!r} (root of profile {prof.name!r})")
    root = plain.index(plain_joint_name(prof.root))
    inside = [False] * len(names)
    inside[root] = True
    # File order is topological, so one pass marks the whole subtree.
    for i in range(root + 1, len(names)):
        inside[i] = inside[doc.joints[i].parent]
    kept = [i for i in range(len(names)) if inside[i] and (i == root or not prof.drops(names[i]))]
    _check_drops(prof, names, root)
    resolve_roles(tuple(names[i] for i in kept), prof)
    return root, kept


def _check_drops(prof: SkeletonProfile, names: Sequence[str], root: int) -> None:
    """A profile may not drop its own root or a joint that plays a role."""
    if prof.drops(names[root]):
        raise SkeletonError(f"profile {prof.name!r} drops its own root joint {names[root]!r}")
    named = [prof.head, *prof.left_foot, *prof.right_foot, prof.left_hip, prof.right_hip, prof.left_shoulder,
             prof.right_shoulder]
    dropped = [j for j in named if prof.drops(j)]
    if dropped:
        raise SkeletonError(f"profile {prof.name!r} drops joint(s) it gives a role: {', '.join(dropped)}")


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
                q = quat_mul(q, axis_angle_to_quat(eye[AXIS_INDEX[a]].expand(frames, 3), radians[:, m]))
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
            t[:, AXIS_INDEX[c[0]]] = doc.motion[:, start + k]
    return torch.from_numpy(t)


def _static_offsets(doc: BvhDocument, joints: Sequence[int], clip_name: str) -> list[Vec3]:
    """Fixed bone offsets: the OFFSET, with position channels replaced by their mean over frames."""
    slices = doc.channel_slices()
    offsets = []
    moving: list[str] = []  # one warning per document, not one per bone
    for j in joints:
        joint = doc.joints[j]
        offset = list(joint.offset)
        found = [(AXIS_INDEX[c[0]], slices[j].start + k, c) for k, c in enumerate(joint.channels) if c in POSITION_CHANNELS]
        if found and doc.num_frames:
            values = doc.motion[:, [col for _, col, _ in found]]
            means = values.mean(axis=0)
            deviations = np.abs(values - means).max(axis=0)
            for (axis, _, channel), mean, deviation in zip(found, means.tolist(), deviations.tolist()):
                offset[axis] = mean
                if deviation > BONE_TRANSLATION_TOLERANCE:
                    moving.append(f"{joint.name} {channel} by up to {deviation:.4g} from its mean {mean:.4g}")
        offsets.append(vec3(offset))
    if moving:
        shown = "; ".join(moving[:3]) + (f"; and {len(moving) - 3} more" if len(moving) > 3 else "")
        logger.warning("%s: %d position channel(s) of non-root joints move (%s); a Clip keeps one fixed offset per "
                       "bone, so each uses its mean", clip_name or "BVH", len(moving), shown)
    return offsets


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
    prof, root, kept, doc = _fit_profile(doc, profile)
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
    parents = [-1]
    for n, j in enumerate(kept[1:], start=1):
        between = _dropped_between(doc, j, new_index)
        parents.append(new_index[doc.joints[between[0]].parent if between else doc.joints[j].parent])
        if between:  # dropped joints above j: their motion goes into j's rotation and offset
            quats[:, n], offsets[n] = _fold(doc, between, j, local[:, n + ancestors], name)
    end_sites = tuple((new_index[j], end) for j in kept if (end := doc.joints[j].end_site) is not None)
    skeleton = Skeleton.build(
        [doc.joints[j].name for j in kept], parents, offsets, profile=prof, end_sites=end_sites
    )
    if frames:
        # Sign continuity over time so finite differences and interpolation behave.
        quats = quat_make_continuous(quat_normalize(quats), dim=0)
    return Clip(
        skeleton=skeleton,
        rotations=quats.to(dtype),
        root_positions=pos.to(dtype),
        fps=fps_from_frame_time(doc.frame_time),
        name=name,
    )


def _dropped_between(doc: BvhDocument, joint: int, kept: Mapping[int, int]) -> list[int]:
    """The dropped joints between ``joint`` and its nearest kept ancestor, top first."""
    chain = []
    parent = doc.joints[joint].parent
    while parent not in kept:
        chain.append(parent)
        parent = doc.joints[parent].parent
    return chain[::-1]


def _fold(doc: BvhDocument, dropped: Sequence[int], joint: int, rotation: torch.Tensor,
          clip_name: str) -> tuple[torch.Tensor, Vec3]:
    """``joint``'s rotation ``[T, 4]`` and fixed offset once the ``dropped`` joints above it are folded in.

    The rotation is exact. The offset (the dropped chain's translation, turned by its rotations)
    is fixed per bone, so it is the mean over frames, with a warning when a dropped joint with a
    bone below it rotates enough to move it (a helper joint that moves is better kept).
    """
    local = _local_rotations(doc, dropped)
    pos = torch.zeros(doc.num_frames, 3, dtype=torch.float64)
    rot = quat_identity((doc.num_frames,), torch.float64)
    for n, d in enumerate(dropped):
        pos = pos + quat_rotate(rot, _local_translation(doc, d))
        rot = quat_mul(rot, local[:, n])
    pos = pos + quat_rotate(rot, _local_translation(doc, joint))
    if not doc.num_frames:
        return rotation, doc.joints[joint].offset
    mean = pos.mean(dim=0)
    deviation = float((pos - mean).norm(dim=-1).max())
    if deviation > BONE_TRANSLATION_TOLERANCE:
        logger.warning("%s: dropping %s moves joint %s by up to %.4g from its mean offset; keep the dropped "
                       "joint(s) in the profile to keep that motion", clip_name or "BVH",
                       ", ".join(doc.joints[d].name for d in dropped), doc.joints[joint].name, deviation)
    return quat_mul(rot, rotation), tuple(mean.tolist())


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
