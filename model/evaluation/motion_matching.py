"""Motion matching with blending: the retrieval baseline games ship, built from the training split alone.

For each request (a context and a target ``N`` frames later), the database is every window of ``N + 1``
frames of the training takes. A window's features, taken in the canonical frame of its first frame
(facing +Z, root over the origin), are:

* the first frame's pose: :func:`key_joints` (8: hips, head, both hands, both ankles, both toes)
  relative to the root;
* their velocity at that frame (cm/s, from the frame before it);
* where the window ends: the last frame's root position, its facing (sin, cos of the yaw relative
  to the first frame) and its pose (the key joints relative to its root, in its own facing frame).

The query is the same features of the case: the last context frame (and the one before it) and the
(changed) target. Each feature is standardised by its spread over the database and each group
weighted equally (a group's weight spread over its dimensions), and the nearest window is played
from the last context frame: moved and turned onto it, with the **start offset** (last context pose
minus the window's first pose: root position, root and joint rotations) blended out and the **end
offset** (target minus the window's last pose) blended in by ``w = smoothstep(k / N)``, so frame ``N``
is the target exactly. It keeps the context's style (it ignores the style clip) and knows only the
takes it was given: the training split's. Its features and search are the product's matching source's
(:mod:`model.retrieval.windows`), over every training take instead of a bundle's database.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from model.data.preprocessed import MotionCache
from model.evaluation.cases import LAST_CONTEXT, CaseSet
from model.evaluation.methods import Method, Request
from model.motion.features import facing_yaw
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_conjugate, quat_identity, quat_mul, quat_normalize, quat_rotate, quat_slerp, yaw_quat
from model.retrieval.matching import key_joints
from model.retrieval.windows import smoothstep, stack_groups
from model.retrieval.windows import window_features as features

Tensor = torch.Tensor

QUERY_CHUNK = 64


class MotionMatchingMethod(Method):
    """Nearest training window by the last context frame and the target, blended onto both (module docstring)."""

    name = "motion matching"
    kind = "baseline (motion matching + blending, training split only)"

    def __init__(self, cache: MotionCache, takes: Sequence[int], stride: int = 1) -> None:
        if not takes:
            raise ValueError("motion matching needs at least one training take")
        self.takes = list(takes)
        self.stride = stride
        self.fps = cache.fps
        self.skeleton = cache.skeleton(self.takes[0])
        rots, roots, pos, owner, frame = [], [], [], [], []
        for i in self.takes:
            rot = quat_normalize(cache.rotations(i).float())
            root = cache.root_positions(i).float()
            sk = cache.skeleton(i)
            p, _ = forward_kinematics(rot, root, sk.offsets_tensor().float(), sk.parents)
            rots.append(rot)
            roots.append(root)
            pos.append(p)
            owner.append(torch.full((len(rot),), i, dtype=torch.long))
            frame.append(torch.arange(len(rot)))
        self.rotations = torch.cat(rots)
        self.roots = torch.cat(roots)
        self.positions = torch.cat(pos)
        self.owner = torch.cat(owner)
        self.frame = torch.cat(frame)
        self._databases: dict[int, tuple[Tensor, Tensor, Tensor, Tensor]] = {}
        self.last_choice: list[tuple[int, int]] = []  # (take, first frame) of each case's window, last request

    def describe(self) -> dict:
        d = super().describe()
        d.update(database_takes=len(self.takes), database_frames=int(len(self.frame)), key_joints=len(key_joints(self.skeleton)))
        return d

    def _database(self, n: int) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """Window starts (rows), standardised features, their mean and spread, for windows of ``n + 1`` frames."""
        if n not in self._databases:
            t = len(self.frame)
            start = torch.arange(1, t - n)
            ok = (self.owner[start - 1] == self.owner[start]) & (self.owner[start] == self.owner[start + n])
            start = start[ok][:: self.stride]
            if len(start) == 0:
                raise ValueError(f"no training window of {n + 1} frames")
            f = self._stack(features(self.positions[start], self.positions[start - 1], self.positions[start + n],
                                     self.skeleton, self.fps))
            mean, std = f.mean(0), f.std(0).clamp_min(1e-3)
            self._databases[n] = (start, (f - mean) / std, mean, std)
        return self._databases[n]

    @staticmethod
    def _stack(groups: dict[str, Tensor]) -> Tensor:
        return stack_groups(groups)

    def generate(self, cases: CaseSet, request: Request, progress: bool = False) -> tuple[Tensor, Tensor]:
        v = request.variant
        n = v.frames
        start, db, mean, std = self._database(n)
        target_rot, target_root = cases.targets(v, 1)
        target_rot, target_root = target_rot[:, -1], target_root[:, -1]
        target_pos = cases.target_positions(v)
        q = self._stack(features(cases.positions[:, LAST_CONTEXT], cases.positions[:, LAST_CONTEXT - 1], target_pos,
                                 cases.skeleton, cases.fps))
        q = (q - mean) / std
        best = torch.cat([torch.cdist(q[lo:lo + QUERY_CHUNK], db).argmin(1) for lo in range(0, len(q), QUERY_CHUNK)])
        rows = start[best]
        self.last_choice = [(int(self.owner[r]), int(self.frame[r])) for r in rows]
        return self.play(rows, cases.rotations[:, LAST_CONTEXT], cases.roots[:, LAST_CONTEXT],
                         cases.positions[:, LAST_CONTEXT], target_rot, target_root, n)

    def play(self, rows: Tensor, ctx_rot: Tensor, ctx_root: Tensor, ctx_pos: Tensor, target_rot: Tensor,
             target_root: Tensor, n: int) -> tuple[Tensor, Tensor]:
        """Frames ``1..n`` of the windows starting at database ``rows``, moved onto the context and blended onto the target."""
        idx = rows.unsqueeze(1) + torch.arange(n + 1).unsqueeze(0)  # [B, n+1]
        rot = self.rotations[idx].clone()  # [B, n+1, J, 4] local
        root = self.roots[idx].clone()  # [B, n+1, 3]
        sk = self.skeleton
        r = sk.roles.root
        # Move and turn the window so that its first frame stands where the last context frame stands.
        turn = facing_yaw(ctx_pos, sk) - facing_yaw(self.positions[rows], sk)  # [B]
        qt = yaw_quat(turn)
        o_db = root[:, 0].clone()
        o_db[:, 1] = 0.0
        o_q = ctx_root.clone()
        o_q[:, 1] = 0.0
        k = n + 1
        root = quat_rotate(qt.unsqueeze(1).expand(-1, k, -1), root - o_db.unsqueeze(1)) + o_q.unsqueeze(1)
        rot[:, :, r] = quat_mul(qt.unsqueeze(1).expand(-1, k, -1), rot[:, :, r])
        rot = quat_normalize(rot)
        # Offsets at the two ends, blended out and in.
        w = smoothstep(torch.arange(k, dtype=root.dtype) / n).view(1, k, 1)  # 0 at frame 0, 1 at frame n
        d0 = ctx_root - root[:, 0]
        d1 = target_root - root[:, -1]
        root = root + (1.0 - w) * d0.unsqueeze(1) + w * d1.unsqueeze(1)

        def offset(a: Tensor, b: Tensor) -> Tensor:  # the rotation taking b onto a, on a's hemisphere
            o = quat_normalize(quat_mul(a, quat_conjugate(b)))
            return torch.where(o[..., 3:] < 0, -o, o)

        o0 = offset(ctx_rot, rot[:, 0]).unsqueeze(1).expand(-1, k, -1, -1)  # [B, k, J, 4]
        o1 = offset(target_rot, rot[:, -1]).unsqueeze(1).expand(-1, k, -1, -1)
        ident = quat_identity(o0.shape[:-1], dtype=rot.dtype)
        wj = w.unsqueeze(-1)
        blend = quat_mul(quat_slerp(ident, o1, wj), quat_slerp(ident, o0, 1.0 - wj))
        rot = quat_normalize(quat_mul(blend, rot))
        rot[:, -1] = target_rot
        root[:, -1] = target_root
        return rot[:, 1:], root[:, 1:]
