"""Motion matching over a :class:`~model.retrieval.database.MotionDatabase`: each row's features, and an exact
nearest-row search.

A row's features, in the frame of its own facing (facing +Z, root over the origin):

* ``pose``: the key joints (:func:`key_joints`: hips, head, both hands, both ankles, both toes) relative to the root;
* ``velocity``: their velocity at that frame (cm/s, from the frame before it);
* ``trajectory``: where the root is ``TRAJECTORY`` frames later (x, z);
* ``facing``: the facing then, relative to now (sin, cos).

A query has the same groups: the current pose and the one before it, and where the root should be and face at those
times (a live character's: towards its target). Each feature is standardised by its spread over the database and
each group weighted (a group's weight spread over its dimensions), as in :mod:`model.evaluation.motion_matching`.

The search is exact, in torch: the distance to every row is one matrix product against the stored features and
their norms (``|f|^2 - 2 q.f + |q|^2``). At the sizes a bundle carries (tens of thousands of rows, 60 features) that
is one GEMV of a few megaflops, about a millisecond on one CPU thread (``rsmt bench`` prints it); faiss's flat
index computes the same product, and an approximate index would trade exactness for speed this size does not need.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from model.motion.features import facing_yaw
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_rotate, yaw_quat
from model.motion.skeleton import Skeleton
from model.retrieval.database import MotionDatabase

Tensor = torch.Tensor
TRAJECTORY = (10, 20, 30)
GROUP_WEIGHTS = {"pose": 1.0, "velocity": 1.0, "trajectory": 2.0, "facing": 1.0}
QUERY_CHUNK = 64


def key_joints(skeleton: Skeleton) -> list[int]:
    """Hips, head, the two hands (the arm chains' ends below the shoulders), the two ankles and toes."""
    r = skeleton.roles

    def chain_end(j: int) -> int:
        while True:
            children = [c for c, p in enumerate(skeleton.parents) if p == j]
            if not children:
                return j
            j = children[0]

    return [r.root, r.head, chain_end(r.left_shoulder), chain_end(r.right_shoulder), *r.left_foot, *r.right_foot]


def _in_frame(p: Tensor, yaw: Tensor, origin: Tensor) -> Tensor:
    """Points ``[B, K, 3]`` into the frame facing +Z at ``yaw [B]`` over ``origin [B, 3]``'s ground point (y kept)."""
    q = yaw_quat(-yaw).unsqueeze(1).expand(-1, p.shape[1], -1)
    ground = origin * torch.tensor([1.0, 0.0, 1.0], dtype=origin.dtype)
    return quat_rotate(q, p - ground.unsqueeze(1))


def feature_groups(now: Tensor, before: Tensor, future_root: Tensor, future_yaw: Tensor, skeleton: Skeleton,
                   fps: float) -> dict[str, Tensor]:
    """The feature groups of poses ``now [B, J, 3]`` (global positions), the frame ``before`` them, and the root's
    global positions ``future_root [B, K, 3]`` and facings ``future_yaw [B, K]`` at the ``TRAJECTORY`` frames."""
    keys = key_joints(skeleton)
    root = skeleton.roles.root
    yaw = facing_yaw(now, skeleton)
    origin = now[:, root]
    pose = _in_frame(now[:, keys], yaw, origin)  # relative to the root's ground point: the root's x, z are 0
    velocity = (pose - _in_frame(before[:, keys], yaw, origin)) * fps
    trajectory = _in_frame(future_root, yaw, origin)[..., [0, 2]]
    turn = future_yaw - yaw.unsqueeze(1)
    facing = torch.stack([torch.sin(turn), torch.cos(turn)], -1) * 100.0
    return {"pose": pose.flatten(1), "velocity": velocity.flatten(1), "trajectory": trajectory.flatten(1),
            "facing": facing.flatten(1)}


def _stack(groups: dict[str, Tensor]) -> Tensor:
    return torch.cat([groups[k] * (w / groups[k].shape[1] ** 0.5) for k, w in GROUP_WEIGHTS.items()], dim=1)


@dataclass
class Match:
    """The best row for each query ``[B]`` and its cost (the weighted squared distance) ``[B]``."""

    rows: Tensor
    cost: Tensor


class MatchIndex:
    """The standardised features of every row of a database that has a frame before it and ``TRAJECTORY[-1]``
    frames after it in its segment (``valid``), and the search over them."""

    def __init__(self, db: MotionDatabase) -> None:
        self.db = db
        sk = db.skeleton
        self.positions, _ = forward_kinematics(db.local_rotations(), db.root_positions(), sk.offsets_tensor(),
                                               sk.parents)
        self.yaw = facing_yaw(self.positions, sk)
        segment = db.segment_of_rows()
        row = torch.arange(db.frames)
        end = (db.starts + db.lengths).long()[segment]  # one past each row's segment
        horizon = TRAJECTORY[-1]
        self.valid = (row > db.starts.long()[segment]) & (row + horizon < end)
        ahead = torch.tensor(TRAJECTORY)
        future = (row.unsqueeze(1) + ahead).clamp(max=end.unsqueeze(1) - 1)  # [N, K]
        groups = feature_groups(self.positions, self.positions[(row - 1).clamp_min(0)],
                                self.positions[future, sk.roles.root], self.yaw[future], sk, db.fps)
        raw = _stack(groups)
        usable = raw[self.valid]
        if len(usable) == 0:
            raise ValueError(f"no database row has a frame before it and {horizon} after it in its segment")
        self.mean, self.std = usable.mean(0), usable.std(0).clamp_min(1e-3)
        self.features = ((raw - self.mean) / self.std).contiguous()
        self.norms = self.features.square().sum(1)

    def standardised(self, groups: dict[str, Tensor]) -> Tensor:
        return (_stack(groups) - self.mean) / self.std

    def search(self, groups: dict[str, Tensor], allowed: Tensor | None = None) -> Match:
        """The valid row nearest each query (``groups`` as :func:`feature_groups` gives them), among the rows
        ``allowed [N]`` (a mask; None: all); a query with no allowed row gets row -1 and cost inf."""
        q = self.standardised(groups)
        ok = self.valid if allowed is None else self.valid & allowed
        penalty = torch.where(ok, 0.0, float("inf"))
        rows, costs = [], []
        for lo in range(0, len(q), QUERY_CHUNK):
            part = q[lo:lo + QUERY_CHUNK]
            dist = self.norms - 2.0 * (part @ self.features.T) + part.square().sum(1, keepdim=True) + penalty
            cost, best = dist.min(1)
            rows.append(torch.where(torch.isfinite(cost), best, -1))
            costs.append(cost)
        return Match(torch.cat(rows), torch.cat(costs))

    def row_groups(self, rows: Tensor) -> dict[str, Tensor]:
        """The feature groups of database ``rows`` (valid ones), as a query would give them."""
        sk = self.db.skeleton
        future = rows.unsqueeze(1) + torch.tensor(TRAJECTORY)
        return feature_groups(self.positions[rows], self.positions[rows - 1], self.positions[future, sk.roles.root],
                              self.yaw[future], sk, self.db.fps)
