"""Both legs of a skeleton as two-bone chains: their world poses, and bending them onto ankle targets.

What the output steps that move feet share (the foot lock and the stride warp,
:mod:`model.inference.output.pipeline`): the chains from the root to each ankle, their forward kinematics
through one :class:`~model.motion.kinematics.ChainKinematics` (so floor contact, the stride warp and
the lock can read one computation), and a two-bone IK that keeps each foot's world rotation.
"""

from __future__ import annotations

import torch

from model.motion.kinematics import ChainKinematics, feet_kinematics, two_bone_ik
from model.motion.rotations import quat_conjugate, quat_mul
from model.motion.skeleton import Skeleton

Tensor = torch.Tensor


class LegChains:
    """The legs of one skeleton (Y up), both computed in one pass with no per-row branches."""

    def __init__(self, skeleton: Skeleton, kinematics: ChainKinematics | None = None) -> None:
        """``kinematics``: the feet's chains (:func:`model.motion.kinematics.feet_kinematics`) to use,
        e.g. the one floor contact uses, so that the frame output computes them once for all steps."""
        sk = skeleton
        chains = [sk.chain_to(ankle) for _, _, ankle in sk.legs]  # root ... hip, knee, ankle of each leg
        for chain in chains:
            if len(chain) < 4:  # the hip's parent turns its new world rotation into a local one
                raise ValueError(f"the ankle {sk.names[chain[-1]]!r} has no two-bone leg below the root")
        if len(chains[0]) != len(chains[1]):
            raise ValueError("moving the feet needs legs of the same depth below the root")
        self.chain = torch.tensor(chains).T  # [depth, 2]: joint of each leg at each depth
        self.kinematics = feet_kinematics(sk) if kinematics is None else kinematics
        self.depth = len(chains[0])
        self._chain_joints = self.chain.reshape(-1).tolist()  # depth-major: both legs' joints at each depth
        self.kinematics.columns(self._chain_joints)  # a ValueError when it does not reach both legs
        self.leg_joints = self.chain[-3:].reshape(-1)  # hips, knees, ankles: the joints a bend rewrites

    def poses(self, rotations: Tensor, roots: Tensor,
              chains: tuple[Tensor, Tensor] | None = None) -> tuple[Tensor, Tensor]:
        """World positions ``[N, depth, 2, 3]`` and rotations ``[N, depth, 2, 4]`` along both legs' chains
        for local ``rotations [N, J, 4]`` and ``roots [N, 3]``; ``chains``: :attr:`kinematics`' results
        for these rotations and roots, where already computed."""
        pos, rot = self.kinematics(rotations, roots) if chains is None else chains
        shape = (*pos.shape[:-2], self.depth, 2)
        return (self.kinematics.pick(pos, self._chain_joints).view(*shape, 3),
                self.kinematics.pick(rot, self._chain_joints).view(*shape, 4))

    def bend(self, rotations: Tensor, pos: Tensor, grot: Tensor, targets: Tensor, move: Tensor) -> Tensor:
        """Local ``rotations [N, J, 4]`` with each leg where ``move [N, 2]`` is set bent by two-bone IK so
        its ankle goes to ``targets [N, 2, 3]`` (as far as the bones reach); ``pos``, ``grot``: the legs'
        world poses (:meth:`poses`) for ``rotations``. The feet keep their world rotations (stay flat)."""
        hip_w, knee_w, ankle_w = grot[:, -3], grot[:, -2], grot[:, -1]
        new_hip, new_knee = two_bone_ik(pos[:, -3], pos[:, -2], pos[:, -1], hip_w, knee_w, targets)
        parents_w = torch.cat([grot[:, -4], new_hip, new_knee], 1)  # [N, 6, 4]: parents of hips, knees, ankles
        local = quat_mul(quat_conjugate(parents_w), torch.cat([new_hip, new_knee, ankle_w], 1))
        # cat, not repeat: the same [N, 6] mask, and repeat costs 5 us at batch 1 against cat's 1.7.
        moved = torch.where(torch.cat([move, move, move], 1).unsqueeze(-1), local,
                            rotations.index_select(1, self.leg_joints))
        # index_copy rather than indexed assignment: a traced graph keeps it generic in the batch size.
        return rotations.index_copy(1, self.leg_joints, moved)
