"""Transition windows: the database window of ``n + 1`` frames that best starts where a character stands and ends
where its target is, and that window played from the character's pose onto the target.

A window's features, taken in the frame of its first frame's facing (facing +Z, root over the origin), are the
first frame's key joints (:func:`model.retrieval.matching.key_joints`) relative to the root, their velocity there
(cm/s), where the window ends (the last frame's root, its facing relative to the first as sin and cos, and its key
joints relative to its root in its own facing frame). A request gives the same from its last context frame, the
frame before it and its target. Each feature is standardised by its spread over the database's windows of that
length and each group weighted (:data:`GROUP_WEIGHTS`); the search is exact (:mod:`model.retrieval.matching`).

Playing a window (:func:`play`) turns and moves it onto the character's last pose, then blends the start offset
(that pose minus the window's first) out and the end offset (the target minus the window's last) in with
``w = smoothstep(k / n)``, joint by joint in global positions and rotations, so frame ``n`` is the target's pose.
:class:`model.evaluation.motion_matching.MotionMatchingMethod` is the same search over a training split.
"""

from __future__ import annotations

from collections import OrderedDict

import torch

from model.motion.features import facing_yaw
from model.motion.rotations import quat_conjugate, quat_identity, quat_mul, quat_normalize, quat_rotate, quat_slerp, yaw_quat
from model.motion.skeleton import Skeleton
from model.retrieval.matching import _in_frame, key_joints

Tensor = torch.Tensor
GROUP_WEIGHTS = {"pose": 1.0, "velocity": 1.0, "place": 2.0, "facing": 1.0, "target_pose": 1.0}
CACHED_LENGTHS = 8


def smoothstep(x: Tensor) -> Tensor:
    x = x.clamp(0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def window_features(first: Tensor, before: Tensor, last: Tensor, skeleton: Skeleton, fps: float) -> dict[str, Tensor]:
    """Feature groups of windows from global positions of their first frame ``[B, J, 3]``, the frame before it
    and their last frame (the module's notes)."""
    keys = key_joints(skeleton)
    root = skeleton.roles.root
    yaw0 = facing_yaw(first, skeleton)
    o0 = first[:, root]
    pose = _in_frame(first[:, keys], yaw0, o0) - _in_frame(first[:, [root]], yaw0, o0)
    vel = (_in_frame(first[:, keys], yaw0, o0) - _in_frame(before[:, keys], yaw0, o0)) * fps
    end_root = _in_frame(last[:, [root]], yaw0, o0)[:, 0]
    yaw1 = facing_yaw(last, skeleton)
    turn = yaw1 - yaw0
    target_pose = _in_frame(last[:, keys], yaw1, last[:, root]) - _in_frame(last[:, [root]], yaw1, last[:, root])
    return {"pose": pose.flatten(1), "velocity": vel.flatten(1), "place": end_root,
            "facing": torch.stack([torch.sin(turn), torch.cos(turn)], -1) * 100.0, "target_pose": target_pose.flatten(1)}


def stack_groups(groups: dict[str, Tensor]) -> Tensor:
    return torch.cat([groups[k] * (w / groups[k].shape[1] ** 0.5) for k, w in GROUP_WEIGHTS.items()], dim=1)


def window_starts(segment: Tensor, n: int) -> Tensor:
    """The first rows of the windows of ``n + 1`` frames that have a frame before them, all in one ``segment [N]``
    (a segment below 0 holds no window)."""
    start = torch.arange(1, max(1, len(segment) - n))
    same = (segment[start - 1] == segment[start]) & (segment[start] == segment[start + n]) & (segment[start] >= 0)
    return start[same]


class WindowSearch:
    """Windows of every length over rows of global positions ``positions [N, J, 3]`` whose segment is ``segment
    [N]``: the standardised features of each length's windows, kept for the last :data:`CACHED_LENGTHS` lengths."""

    def __init__(self, positions: Tensor, segment: Tensor, skeleton: Skeleton, fps: float) -> None:
        self.positions, self.segment, self.skeleton, self.fps = positions, segment, skeleton, fps
        self._lengths: OrderedDict[int, tuple[Tensor, Tensor, Tensor, Tensor, Tensor]] = OrderedDict()

    def windows(self, n: int) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        """``(first rows [W], standardised features [W, D], their squared norms [W], mean [D], spread [D])`` of the
        windows of ``n + 1`` frames that have a frame before them, all in one segment."""
        if n in self._lengths:
            self._lengths.move_to_end(n)
            return self._lengths[n]
        start = window_starts(self.segment, n)
        if len(start) == 0:
            raise ValueError(f"no database window of {n + 1} frames")
        raw = self._raw(self.positions, start, n)
        mean, std = raw.mean(0), raw.std(0).clamp_min(1e-3)
        features = ((raw - mean) / std).contiguous()
        self._lengths[n] = (start, features, features.square().sum(1), mean, std)
        if len(self._lengths) > CACHED_LENGTHS:
            self._lengths.popitem(last=False)
        return self._lengths[n]

    def _raw(self, positions: Tensor, start: Tensor, n: int) -> Tensor:
        p = positions
        return stack_groups(window_features(p[start], p[start - 1], p[start + n], self.skeleton, self.fps))

    def search_in(self, positions: Tensor, segment: Tensor, owner: Tensor, now: Tensor, before: Tensor,
                  target: Tensor, n: int) -> tuple[Tensor, Tensor]:
        """As :meth:`search`, among the windows of other rows of global ``positions [M, J, 3]`` in ``segment [M]``
        (style clips' frames; a segment below 0 holds none), request ``b`` among the rows whose ``owner [M]`` is
        ``b``; standardised as the database's windows of that length, so that the costs compare. The first rows
        ``[B]`` and costs ``[B]`` (infinite where a request has no such window)."""
        start = window_starts(segment, n)
        if len(start) == 0:
            return now.new_zeros(now.shape[0], dtype=torch.long), now.new_full((now.shape[0],), float("inf"))
        _, _, _, mean, std = self.windows(n)
        clip = (self._raw(positions, start, n) - mean) / std
        q = (stack_groups(window_features(now, before, target, self.skeleton, self.fps)) - mean) / std
        dist = torch.cdist(q, clip).square()  # [B, W]
        dist = dist.masked_fill(owner[start].unsqueeze(0) != torch.arange(now.shape[0]).unsqueeze(1), float("inf"))
        cost, best = dist.min(1)
        return start[best], cost

    def search(self, now: Tensor, before: Tensor, target: Tensor, n: int,
               allowed: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """The first rows ``[B]`` of the windows of ``n + 1`` frames nearest each request (global positions of its
        current pose ``now [B, J, 3]``, the one ``before`` it and its ``target``), among windows starting at rows
        ``allowed [B, N]`` (None: all; a request with none allowed searches all), and their costs ``[B]``."""
        start, db, norms, mean, std = self.windows(n)
        q = (stack_groups(window_features(now, before, target, self.skeleton, self.fps)) - mean) / std
        dist = torch.addmm(norms + q.square().sum(1, keepdim=True), q, db.T, alpha=-2.0)  # [B, W]
        if allowed is not None:
            ok = allowed[:, start]
            ok = ok | ~ok.any(1, keepdim=True)  # a style with no window of this length: every window
            dist = dist.masked_fill(~ok, float("inf"))
        cost, best = dist.min(1)
        return start[best], cost


def play(rows: Tensor, n: int, positions: Tensor, rotations: Tensor, skeleton: Skeleton, now_pos: Tensor,
         now_rot: Tensor, target_pos: Tensor, target_rot: Tensor) -> tuple[Tensor, Tensor]:
    """Frames ``0..n`` of the windows starting at ``rows [B]`` of global ``positions [N, J, 3]`` and
    ``rotations [N, J, 4]``, turned and moved onto the pose ``now_pos [B, J, 3]`` / ``now_rot [B, J, 4]``
    and blended onto ``target_pos`` / ``target_rot`` (the module's notes): ``([B, n+1, J, 3], [B, n+1, J, 4])``."""
    k = n + 1
    idx = rows.unsqueeze(1) + torch.arange(k).unsqueeze(0)  # [B, k]
    pos, rot = positions[idx], rotations[idx]
    r = skeleton.roles.root
    turn = yaw_quat(facing_yaw(now_pos, skeleton) - facing_yaw(pos[:, 0], skeleton))  # [B, 4]
    ground = torch.tensor([1.0, 0.0, 1.0])
    qt = turn.view(-1, 1, 1, 4)
    pos = quat_rotate(qt, pos - (pos[:, :1, r:r + 1] * ground)) + (now_pos[:, None, r:r + 1] * ground)
    rot = quat_normalize(quat_mul(qt.expand_as(rot), rot))
    w = smoothstep(torch.arange(k, dtype=pos.dtype) / max(n, 1)).view(1, k, 1, 1)  # 0 at frame 0, 1 at frame n
    pos = pos + (1.0 - w) * (now_pos - pos[:, 0]).unsqueeze(1) + w * (target_pos - pos[:, -1]).unsqueeze(1)

    def offset(a: Tensor, b: Tensor) -> Tensor:  # the rotation taking b onto a, on a's hemisphere
        o = quat_normalize(quat_mul(a, quat_conjugate(b)))
        return torch.where(o[..., 3:] < 0, -o, o)

    o0 = offset(now_rot, rot[:, 0]).unsqueeze(1).expand_as(rot)
    o1 = offset(target_rot, rot[:, -1]).unsqueeze(1).expand_as(rot)
    ident = quat_identity(rot.shape[:-1], dtype=rot.dtype)
    rot = quat_normalize(quat_mul(quat_mul(quat_slerp(ident, o1, w), quat_slerp(ident, o0, 1.0 - w)), rot))
    return pos, rot
